"""The check of a 4 Hz joint path before it may be played: every sample against the scene.

Per sample k: every entry finite; every joint within the arm's limits; the rigid arm at q_k no
nearer than the collision checker's safety margin to the workspace or to itself (the
pre-simulator's scene). Then the finite-difference acceleration and jerk (and velocity, given
a velocity limit) of the path as the plant receives it (the committed history in front, the
last pose held after) against the smoother's limits. :func:`validate_joint_path` returns the
violations; :func:`validation_report` returns them with the closest distance per sample and
the finite-difference statistics (:class:`ValidationReport`), as an offline plan
(:mod:`~telesmooth.diagrams.offline_planning`) carries them.

What is *not* checked: the robot's motion between two 4 Hz samples (its interpolator ramps
linearly in joint space over one tick) and the flexible links' deflection; only the path's
samples themselves are validated, as the pre-simulator does online.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from telesmooth.arms.collision import ArmCollisionModel
from telesmooth.arms.joint_vectors import as_per_joint, check_finite_per_joint
from telesmooth.diagrams.scenario import Scenario
from telesmooth.smoothing.metrics import VIOLATION_RTOL, finite_differences, limit_statistics
from telesmooth.smoothing.offline import HISTORY_LENGTH, with_rest_history

__all__ = [
    "PERIOD_RTOL",
    "VIOLATION_KINDS",
    "ValidationReport",
    "Violation",
    "describe_violations",
    "validate_joint_path",
    "validation_report",
]

VIOLATION_KINDS = ("non_finite", "joint_limit", "collision", "fd_velocity", "fd_acceleration",
                   "fd_jerk")
"""What a :class:`Violation` can be about."""

PERIOD_RTOL = 1e-9
"""Relative tolerance on "t_s is uniform with the uplink period" (and on a plan's period)."""

# At most this many violations are quoted in an error message.
_QUOTED_VIOLATIONS = 5


@dataclasses.dataclass(frozen=True)
class Violation:
    """One sample of a joint path that breaks a safety or smoothness limit.

    Attributes:
        kind: One of :data:`VIOLATION_KINDS`.
        sample: Index k of the offending sample in the path (for a finite difference, the
            newest sample it involves, clipped to the last sample for the held tail).
        time_s: t_k, s.
        value: The offending value: the joint angle (rad), the signed distance (m) or the
            finite difference (rad/s, rad/s², rad/s³); NaN/inf for ``non_finite``.
        limit: The limit broken: the joint bound (rad), the safety margin (m) or the
            finite-difference limit; NaN for ``non_finite``.
        joint: The joint's name (every kind except ``collision``), else "".
        body_a, body_b: The closest pair of a ``collision`` (arm body nearer the base first,
            workspace boxes last, as :class:`~telesmooth.arms.collision.CollisionQuery`).
    """

    kind: str
    sample: int
    time_s: float
    value: float
    limit: float
    joint: str = ""
    body_a: str = ""
    body_b: str = ""

    def __str__(self) -> str:
        where = f"sample {self.sample} (t = {self.time_s:.3f} s)"
        if self.kind == "collision":
            return (f"{where}: collision {self.body_a}/{self.body_b}: signed distance "
                    f"{self.value:.4f} m < safety margin {self.limit:.4f} m")
        if self.kind == "joint_limit":
            return (f"{where}: joint {self.joint!r} = {self.value:.4f} rad is beyond its limit "
                    f"{self.limit:.4f} rad")
        if self.kind == "non_finite":
            return f"{where}: joint {self.joint!r} = {self.value!r} is not finite"
        unit = {"fd_velocity": "rad/s", "fd_acceleration": "rad/s²", "fd_jerk": "rad/s³"}[
            self.kind]
        return (f"{where}: {self.kind} of joint {self.joint!r} = {self.value:.6g} {unit}, "
                f"|value| > limit {self.limit:.6g} {unit}")


@dataclasses.dataclass(frozen=True, eq=False)
class ValidationReport:
    """The check of every sample of a planned path.

    Attributes:
        checked: False when no path was checked (the solve failed).
        violations: Every violation found, ordered by kind then sample.
        min_distance_m: Signed distance of the closest pair per sample, m, (N,) (at most the
            collision model's horizon; NaN where the sample was not finite).
        closest_pairs: The (body_a, body_b) of that pair per sample ("" beyond the horizon).
        fd_limits: smoothing.metrics.limit_statistics of the finite differences of the path as
            the plant receives it (committed history in front, last pose held after), keyed
            "fd_velocity" (only with a velocity limit), "fd_acceleration", "fd_jerk".
        fd_limits_enforced: Whether finite-difference excesses count as violations.
    """

    checked: bool
    violations: tuple
    min_distance_m: np.ndarray
    closest_pairs: tuple
    fd_limits: dict
    fd_limits_enforced: bool

    @property
    def passed(self) -> bool:
        return self.checked and not self.violations


def describe_violations(violations) -> str:
    """The count of the violations and the first few of them, for an error message ("" for
    none)."""
    if not violations:
        return ""
    quoted = "; ".join(str(v) for v in violations[:_QUOTED_VIOLATIONS])
    more = len(violations) - _QUOTED_VIOLATIONS
    return (f"{len(violations)} violation(s): {quoted}"
            + (f"; and {more} more" if more > 0 else ""))


def _check_path(q, t_s, scenario: Scenario):
    n = scenario.arm_description.num_joints
    try:
        q = np.asarray(q, dtype=float)
        t = np.asarray(t_s, dtype=float)
    except (TypeError, ValueError):
        raise ValueError("q and t_s must be numeric arrays") from None
    if q.ndim != 2 or q.shape[1] != n or q.shape[0] < 1:
        raise ValueError(f"q has shape {q.shape}; expected (N >= 1, {n}) for the joints "
                         f"{scenario.arm_description.joint_names!r}")
    if t.shape != (q.shape[0],) or not np.all(np.isfinite(t)):
        raise ValueError(f"t_s has shape {t.shape}; expected ({q.shape[0]},) finite times")
    period = scenario.uplink.period_s
    if t.size > 1 and not np.allclose(np.diff(t), period, rtol=PERIOD_RTOL, atol=0.0):
        raise ValueError(f"t_s must be uniform with the uplink period {period!r} s; got steps "
                         f"from {np.diff(t).min()!r} to {np.diff(t).max()!r}")
    return q, t


def validation_report(q, t_s, scenario: Scenario, *, start_position=None, check_fd_limits=True,
                      max_velocity=None, collision_model: ArmCollisionModel | None = None
                      ) -> ValidationReport:
    """The check of :func:`validate_joint_path` (same arguments and errors), as a
    :class:`ValidationReport`: the violations with the closest distance and pair per sample
    and the finite-difference statistics."""
    q, t = _check_path(q, t_s, scenario)
    arm = scenario.arm_description
    names = arm.joint_names
    lower, upper = np.asarray(arm.joint_lower_rad), np.asarray(arm.joint_upper_rad)
    checker = scenario.collision_checker
    if collision_model is None:
        collision_model = ArmCollisionModel(arm, scenario.workspace_or_default,
                                            distance_horizon_m=checker.distance_horizon_m)
    start = q[0] if start_position is None else check_finite_per_joint(
        "start_position", start_position, arm.num_joints, names)
    non_finite, limits, collisions = [], [], []
    distances = np.full(q.shape[0], np.nan)
    pairs = []
    for k, sample in enumerate(q):
        finite = np.isfinite(sample)
        for j in np.flatnonzero(~finite):
            non_finite.append(Violation("non_finite", k, float(t[k]), float(sample[j]),
                                        math.nan, joint=names[j]))
        for j in np.flatnonzero(finite & ((sample < lower) | (sample > upper))):
            bound = lower[j] if sample[j] < lower[j] else upper[j]
            limits.append(Violation("joint_limit", k, float(t[k]), float(sample[j]),
                                    float(bound), joint=names[j]))
        if not finite.all():
            pairs.append(("", ""))
            continue
        query = collision_model.query(sample)
        distances[k] = query.min_distance_m
        pairs.append((query.body_a, query.body_b))
        if query.in_collision(checker.safety_margin_m):
            collisions.append(Violation("collision", k, float(t[k]), query.min_distance_m,
                                        checker.safety_margin_m, body_a=query.body_a,
                                        body_b=query.body_b))

    # Finite differences of what the plant receives: history in front, last pose held after.
    extended = with_rest_history(q, start)
    period = scenario.uplink.period_s
    smoother = scenario.smoother
    limits_by_order = {
        2: ("fd_acceleration", as_per_joint("max_acceleration_rad_per_s2",
                                            smoother.max_acceleration_rad_per_s2,
                                            arm.num_joints, names, allow_inf=True)),
        3: ("fd_jerk", as_per_joint("max_jerk_rad_per_s3", smoother.max_jerk_rad_per_s3,
                                    arm.num_joints, names, allow_inf=True)),
    }
    if max_velocity is not None:
        limits_by_order[1] = ("fd_velocity", as_per_joint(
            "max_velocity_rad_per_s", max_velocity, arm.num_joints, names, allow_inf=True))
    fd_stats, fd_violations = {}, []
    for order in sorted(limits_by_order):
        kind, limit = limits_by_order[order]
        values = finite_differences(extended, period, order)
        fd_stats[kind] = limit_statistics(values, limit)
        if not check_fd_limits:
            continue
        over = np.abs(values) > limit * (1.0 + VIOLATION_RTOL)
        for row, j in zip(*np.nonzero(over)):
            # Row i spans extended samples i … i+order; name the newest real sample.
            k = min(max(row + order - HISTORY_LENGTH, 0), q.shape[0] - 1)
            fd_violations.append(Violation(kind, int(k), float(t[k]), float(values[row, j]),
                                           float(limit[j]), joint=names[j]))
    return ValidationReport(
        checked=True,
        violations=tuple(non_finite + limits + collisions + fd_violations),
        min_distance_m=distances, closest_pairs=tuple(pairs), fd_limits=fd_stats,
        fd_limits_enforced=bool(check_fd_limits))


def validate_joint_path(q, t_s, scenario: Scenario, *, start_position=None,
                        check_fd_limits: bool = True, max_velocity=None,
                        collision_model: ArmCollisionModel | None = None) -> list:
    """Checks every sample of a 4 Hz joint path as the offline pipeline does.

    Per sample k: every entry finite; every joint within ``scenario.arm_description``'s limits;
    the rigid arm at q_k no nearer than ``scenario.collision_checker.safety_margin_m`` to the
    workspace (``scenario.workspace_or_default``) or itself. Then, if ``check_fd_limits``, the
    finite-difference acceleration and jerk (and velocity, with ``max_velocity``) of
    [start × 3, q_0 … q_{N−1}, q_{N−1} × 3] against the scenario smoother's a_max and j_max,
    with the relative tolerance of :mod:`telesmooth.smoothing.metrics`.

    Args:
        q: The path, rad, (N, J) in the arm's joint order.
        t_s: Its times, s, (N,), uniform with the uplink period.
        scenario: The arm, workspace, margin and limits.
        start_position: The pose before the path (the robot at rest), rad, (J,); default q_0.
        check_fd_limits: Whether finite-difference excesses are violations.
        max_velocity: v_max per joint, rad/s, or None (velocity unchecked).
        collision_model: A prebuilt model of the same arm and workspace (saves its build).

    Returns:
        The violations (empty when the path passes), non-finite first, then joint limits,
        collisions and finite differences, each in sample order.

    Raises:
        ValueError: If the shapes do not match the arm, or t_s is not uniform at the uplink
            period.
    """
    return list(validation_report(q, t_s, scenario, start_position=start_position,
                                  check_fd_limits=check_fd_limits, max_velocity=max_velocity,
                                  collision_model=collision_model).violations)
