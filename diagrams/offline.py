"""The offline mode: plan a recorded session with Offline-CKS, validate it, then play it back.

Pipeline (docs/method.md §2.5/§2.6 for the smoother, §5.1 for the 4 Hz sampling):

    recorded operator session (make_haptic_recording)
      └─▶ inverse kinematics at the haptic rate (the ground station's own IK system)
            └─▶ one joint sample per uplink tick t_k = k·Δt (the latest IK target, or the
                period mean when ``scenario.period_mean``) ─────────────────▶ q_raw (N, J)
                  └─▶ Offline-CKS over the whole session (Drake MathematicalProgram),
                      committed history = the robot's start pose, rest at the end ─▶ q_planned
                        └─▶ validation of EVERY sample against the pre-simulator's scene:
                            finite values, joint limits, collision (safety margin), and the
                            finite-difference velocity/acceleration/jerk limits
                              └─▶ playback (only if valid): 4 Hz source → Uplink → robot

Sampling convention. The planning diagram logs the IK target at the uplink period; a logger
row at t_k shows the state before the updates at t_k (Drake's publish-before-update order), which
is exactly what the online chain's FIFO samples at t_k. So ``q_raw[k]`` equals the online chain's
z_k, and the offline and online smoothers see the same data.

Playback timing. The source holds ``q_planned[k]`` on [t_k, t_{k+1}) and the last row afterwards;
the uplink's tick at t_k samples it, so packet k carries ``q_planned[k]`` exactly (a logger at
t_k still shows packet k−1). The uplink and the robot start at ``plan.q_start``, the committed
history the solver assumed, so the finite-difference limits hold across the start for what the
plant actually receives; after the last packet the uplink keeps re-sending the last (rest) pose.
There is no delay FIFO and no online smoother in playback: the plan is already smoothed and
checked, and the robot executes it from t = 0.

What is *not* checked: the robot's motion between two 4 Hz samples (its interpolator ramps
linearly in joint space over one tick) and the flexible links' deflection; only the planned
samples themselves are validated, as the pre-simulator does online.
"""

from __future__ import annotations

import dataclasses
import math
import time

import numpy as np
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import LogVectorOutput

from telesmooth.arms.collision import ArmCollisionModel
from telesmooth.arms.joint_vectors import as_per_joint, check_finite_per_joint
from telesmooth.diagrams.scenario import Scenario, initial_position, make_haptic_recording
from telesmooth.diagrams.teleoperation import (
    AddOnboardRobot,
    AddOperatorTargets,
    add_onboard_loggers,
    connect_uplink_to_robot,
    scenario_smoother_config,
)
from telesmooth.smoothing.kalman import start_prior
from telesmooth.smoothing.metrics import VIOLATION_RTOL, finite_differences, limit_statistics
from telesmooth.smoothing.model import JerkModel
from telesmooth.smoothing.offline import (
    HISTORY_LENGTH,
    OFFLINE_CONSTRAINTS,
    OfflineCksResult,
    solve_offline_cks,
    with_rest_history,
)
from telesmooth.systems.flexible_arm import FlexibleJointArm
from telesmooth.systems.laser_tracker import tracker_record
from telesmooth.systems.planned_path_source import PlannedPathSource
from telesmooth.systems.uplink import Uplink

__all__ = [
    "AddPathPlayback",
    "MakeOfflinePlaybackDiagram",
    "OfflinePlan",
    "OfflinePlaybackHandles",
    "PlannedPathSource",
    "SignalLog",
    "ValidationReport",
    "VIOLATION_KINDS",
    "Violation",
    "copy_logs",
    "joint_targets_at_uplink_rate",
    "plan_offline",
    "recording_ticks",
    "run_offline",
    "validate_joint_path",
]

VIOLATION_KINDS = ("non_finite", "joint_limit", "collision", "fd_velocity", "fd_acceleration",
                   "fd_jerk")
"""What a :class:`Violation` can be about."""

# Relative tolerance on "t_s is uniform with the uplink period".
_PERIOD_RTOL = 1e-9
# Added to t / Δt before flooring, so that a tick time computed as k·Δt selects row k.
_TICK_INDEX_EPSILON = 1e-9
# At most this many violations are quoted in an error message.
_QUOTED_VIOLATIONS = 5


# -- records --------------------------------------------------------------------------------


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


@dataclasses.dataclass(frozen=True, eq=False)
class OfflinePlan:
    """A smoothed, validated plan of a recorded session, sampled at the uplink period.

    Attributes:
        scenario: The scenario it was planned (and validated) for.
        joint_names: Joint order of every array, (J,).
        period_s: Δt, the uplink period, s.
        t_s: t_k = k·Δt, s, (N,).
        q_start: The robot's pose before the plan (the solver's committed history), rad, (J,).
        q_raw: The unsmoothed joint samples z_k (IK targets as the FIFO would sample them),
            rad, (N, J).
        q_planned: The smoothed positions to send, rad, (N, J); NaN if the solve failed.
        states_planned: The smoothed states [q, q̇, q̈, q⃛] per joint, (N, J, 4).
        ik_failures: Haptic samples at which the IK rejected the command and held, count.
        solver: What the Offline-CKS solve returned
            (:class:`~telesmooth.smoothing.offline.OfflineCksResult`: success, results, solver,
            objective, times, tolerances; its ``states`` are ``states_planned``).
        constraint: The solve's constraint mode (``"state"`` or ``"trajectory"``); always with
            the rest at the end.
        max_velocity_rad_per_s: The velocity limit per joint of the solve, rad/s (J,) or None.
        validation: The check of every sample of ``q_planned``.
        timings_s: Wall-clock time of each planning stage, s ("inverse_kinematics", "solve",
            "validation", "total").
    """

    scenario: Scenario
    joint_names: tuple
    period_s: float
    t_s: np.ndarray
    q_start: np.ndarray
    q_raw: np.ndarray
    q_planned: np.ndarray
    states_planned: np.ndarray
    ik_failures: int
    solver: OfflineCksResult
    constraint: str
    max_velocity_rad_per_s: np.ndarray | None
    validation: ValidationReport
    timings_s: dict

    @property
    def is_valid(self) -> bool:
        """True when the solve succeeded and every sample passed validation."""
        return self.solver.is_success and self.validation.passed

    @property
    def violations(self) -> tuple:
        return self.validation.violations

    @property
    def reason(self) -> str:
        """Why the plan is not valid ("" when it is)."""
        if not self.solver.is_success:
            failed = [f"{name!r}: {result}" + (f" (violated: {list(names)})" if names else "")
                      for name, result, names in zip(self.joint_names,
                                                     self.solver.solution_results,
                                                     self.solver.infeasible_constraints)
                      if result != "kSolutionFound"]
            return "Offline-CKS failed for joint " + "; ".join(failed)
        return _describe_violations(self.validation.violations)


@dataclasses.dataclass(frozen=True)
class SignalLog:
    """A copied VectorLog: sample times t_s (M,), s, and values (M, size)."""

    t_s: np.ndarray
    values: np.ndarray


def _describe_violations(violations) -> str:
    if not violations:
        return ""
    quoted = "; ".join(str(v) for v in violations[:_QUOTED_VIOLATIONS])
    more = len(violations) - _QUOTED_VIOLATIONS
    return (f"{len(violations)} violation(s): {quoted}"
            + (f"; and {more} more" if more > 0 else ""))


# -- planning ---------------------------------------------------------------------------------


def recording_ticks(scenario: Scenario, recording) -> int:
    """Uplink ticks that cover a recording: ceil((T_rec + p_haptic) / Δt) + 1, so the last one
    samples the IK target of the recording's last pose."""
    duration = float(recording.t_s[-1] - recording.t_s[0])
    return math.ceil((duration + scenario.haptic.period_s) / scenario.uplink.period_s
                     - _TICK_INDEX_EPSILON) + 1


def joint_targets_at_uplink_rate(scenario: Scenario, *, num_ticks: int | None = None):
    """Runs the scenario's recording through the ground station's IK; one sample per tick.

    Builds the ground station's operator stages (``AddOperatorTargets``: haptic source → IK →
    period mean when ``scenario.period_mean``)
    and logs the stream the FIFO would read at the uplink period, so row k is the FIFO's z_k.

    Args:
        scenario: Its recording, IK settings, arm, start pose and periods are used.
        num_ticks: N, samples to produce; default enough to include the IK target of the
            recording's last pose: ceil((T_rec + p_haptic) / Δt) + 1.

    Returns:
        (t_s (N,), z (N, J) rad, q_start (J,) rad, ik_failures): the tick times, the samples,
        the robot's start pose (the IK's initial target) and the number of haptic samples whose
        command the IK rejected.

    Raises:
        ValueError: If the scenario has no recording (``haptic.source = 'lcm'``) or
            ``num_ticks`` < 2.
    """
    recording = make_haptic_recording(scenario)
    if recording is None:
        raise ValueError("offline planning needs a recorded session; haptic.source = 'lcm' "
                         "is a live device")
    q0 = initial_position(scenario, recording)
    haptic_period = scenario.haptic.period_s
    tick = scenario.uplink.period_s
    if num_ticks is None:
        num_ticks = recording_ticks(scenario, recording)
    if isinstance(num_ticks, bool) or not isinstance(num_ticks, (int, np.integer)) \
            or num_ticks < 2:
        raise ValueError(f"num_ticks = {num_ticks!r} must be an integer >= 2")

    builder = DiagramBuilder()
    operator = AddOperatorTargets(builder, scenario, recording=recording,
                                  initial_position_rad=q0)
    ik, sampled = operator.inverse_kinematics, operator.q_sampled
    samples_log = LogVectorOutput(sampled, builder, tick)
    failed_log = LogVectorOutput(ik.get_ik_failed_output_port(), builder, haptic_period)
    diagram = builder.Build()
    diagram.set_name("offline_inverse_kinematics")
    simulator = Simulator(diagram)
    end = (num_ticks - 1) * tick
    simulator.AdvanceTo(end)
    context = simulator.get_context()
    log = samples_log.FindLog(context)
    times, values = log.sample_times(), log.data().T
    # One row per tick: k·Δt (the first tick may be logged twice: initialization + period).
    t_s = tick * np.arange(num_ticks)
    rows = np.searchsorted(times, t_s - 1e-9 * tick, side="left")
    if rows[-1] >= times.size or not np.allclose(times[rows], t_s, rtol=0.0, atol=1e-9):
        raise RuntimeError(  # an internal invariant of Drake's logging, not user input
            f"the tick logger did not sample at k·{tick} s: {times[:5]}…")
    z = values[rows]
    # One logger row per haptic update (each shows the flag of the update before it).
    ik_failures = int(np.count_nonzero(failed_log.FindLog(context).data()[0] > 0.5))
    return t_s, z, q0, ik_failures


def plan_offline(scenario: Scenario, *, constraint: str = "trajectory", max_velocity=None,
                 num_ticks: int | None = None) -> OfflinePlan:
    """Plans a recorded session: IK → 4 Hz samples → Offline-CKS → validation of every sample.

    Offline-CKS uses the scenario's smoother σ (per joint allowed), r (divided by the samples
    per period when ``scenario.period_mean``), a_max and j_max, the robot's start pose as the
    committed history, and rest at the end. Finite-difference excesses count as violations in
    the "trajectory" and "both" modes (the solver promises those limits); in "state" and "none"
    they are reported in ``validation.fd_limits`` only (the paper's limits are on the state).
    The online smoother's ``method`` and reduced-Q settings do not apply offline.

    Args:
        scenario: The session, arm, workspace, smoother limits and periods.
        constraint: Offline-CKS constraint mode: "trajectory" (default), "state", "both",
            "none".
        max_velocity: v_max per joint, rad/s (scalar or per joint), or None.
        num_ticks: Samples to plan; default covers the recording (see
            :func:`joint_targets_at_uplink_rate`).

    Returns:
        The plan. A failed solve or a failed check is an expected outcome: ``is_valid`` is then
        False and ``reason`` says why; nothing is raised.

    Raises:
        ValueError: Invalid input only: an unknown ``constraint``, a bad ``max_velocity``, a
            scenario without a recording.
    """
    start = time.perf_counter()
    if constraint not in OFFLINE_CONSTRAINTS:
        raise ValueError(f"constraint = {constraint!r} must be one of {OFFLINE_CONSTRAINTS}")
    arm = scenario.arm_description
    names = arm.joint_names
    n = arm.num_joints
    velocity = None if max_velocity is None else as_per_joint(
        "max_velocity_rad_per_s", max_velocity, n, names, allow_inf=True)

    # Stage 1: the operator's session through the ground station's IK, sampled at 4 Hz.
    t_s, z, q_start, ik_failures = joint_targets_at_uplink_rate(scenario, num_ticks=num_ticks)
    after_ik = time.perf_counter()

    # Stage 2: Offline-CKS over the whole session (docs/method.md §2.5/§2.6).
    smoother = scenario_smoother_config(scenario)
    model = JerkModel.make(scenario.uplink.period_s, smoother.sigma, smoother.r, num_joints=n,
                           joint_names=names)
    result = solve_offline_cks(
        z, model, max_acceleration=smoother.max_acceleration_rad_per_s2,
        max_jerk=smoother.max_jerk_rad_per_s3, max_velocity=velocity, constraint=constraint,
        rest_at_end=True, start_position=q_start, joint_names=names,
        prior=start_prior(smoother.start_prior, q_start, model))
    after_solve = time.perf_counter()

    # Stage 3: the pre-simulator's check of every planned sample.
    q_planned = result.states[:, :, 0].copy()
    if result.is_success:
        report = _validate(q_planned, t_s, scenario, start_position=q_start,
                           check_fd_limits=constraint in ("trajectory", "both"),
                           max_velocity=velocity)
    else:
        report = ValidationReport(checked=False, violations=(),
                                  min_distance_m=np.full(len(t_s), np.nan),
                                  closest_pairs=(), fd_limits={}, fd_limits_enforced=False)
    end = time.perf_counter()
    return OfflinePlan(
        scenario=scenario, joint_names=names, period_s=scenario.uplink.period_s, t_s=t_s,
        q_start=q_start, q_raw=z, q_planned=q_planned, states_planned=result.states,
        ik_failures=ik_failures, solver=result, constraint=constraint,
        max_velocity_rad_per_s=velocity, validation=report,
        timings_s={"inverse_kinematics": after_ik - start, "solve": after_solve - after_ik,
                   "validation": end - after_solve, "total": end - start})


# -- validation -------------------------------------------------------------------------------


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
    if t.size > 1 and not np.allclose(np.diff(t), period, rtol=_PERIOD_RTOL, atol=0.0):
        raise ValueError(f"t_s must be uniform with the uplink period {period!r} s; got steps "
                         f"from {np.diff(t).min()!r} to {np.diff(t).max()!r}")
    return q, t


def _validate(q, t_s, scenario: Scenario, *, start_position=None, check_fd_limits=True,
              max_velocity=None, collision_model: ArmCollisionModel | None = None
              ) -> ValidationReport:
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
    return list(_validate(q, t_s, scenario, start_position=start_position,
                          check_fd_limits=check_fd_limits, max_velocity=max_velocity,
                          collision_model=collision_model).violations)


# -- playback ---------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class OfflinePlaybackHandles:
    """A built playback diagram with its stages and loggers (name → VectorLogSink).

    Attributes:
        diagram: The diagram.
        source: The planned-path source.
        uplink: The 4 Hz uplink (same system as the online chain's).
        robot: The flexible-joint arm.
        logs: "sequence_number", "send_time", "q_sent", "state_sent" at the uplink period
            (a row at t_k shows packet k−1) and the robot's "tracker" (its samples with their
            measurement times) and "command_rejected" at the tracker period.
        plan: The plan played.
        duration_s: Suggested simulated time: the last packet plus ``scenario.settle_s``
            (and at least one tick more, so the loggers see the last packet), or
            ``scenario.simulation_duration_s`` if that is longer.
    """

    diagram: object
    source: PlannedPathSource
    uplink: Uplink
    robot: FlexibleJointArm
    logs: dict
    plan: OfflinePlan
    duration_s: float


def AddPathPlayback(builder: DiagramBuilder, scenario: Scenario, positions, *, q_start,
                    states=None):
    """Adds a 4 Hz joint path → the scenario's Uplink → the onboard robot, with loggers.

    No check is made here: callers that command a real or a safety-relevant plant validate
    the path first (:func:`MakeOfflinePlaybackDiagram` does). Row k of ``positions`` is
    packet k, sent at t_k = k·Δt; the uplink and the robot start at rest at ``q_start``.

    Args:
        builder: The builder to add to.
        scenario: The uplink period, arm and onboard settings.
        positions: The path, rad, (N, J).
        q_start: The robot's start pose, rad, (J,).
        states: Optional [q, q̇, q̈, q⃛] per row, (N, J, 4), sent with the packets.

    Returns:
        (source, uplink, robot, logs): ``logs`` as :class:`OfflinePlaybackHandles`.
    """
    arm = scenario.arm_description
    period = scenario.uplink.period_s
    # Stage 1: the path, one row per uplink tick.
    source = builder.AddNamedSystem("planned_path_source", PlannedPathSource(
        positions, period_s=period, states=states))
    # Stage 2: the same 4 Hz uplink as the online chain, starting at the committed pose.
    uplink = builder.AddNamedSystem("uplink", Uplink(
        scenario.uplink, num_joints=arm.num_joints, initial_position_rad=q_start))
    builder.Connect(source.get_q_planned_output_port(), uplink.get_q_smoothed_input_port())
    builder.Connect(source.get_state_planned_output_port(),
                    uplink.get_state_smoothed_input_port())
    # Stage 3: the onboard robot, at rest at the committed pose.
    robot = AddOnboardRobot(builder, scenario, initial_position_rad=q_start,
                            command_period_s=period)
    connect_uplink_to_robot(builder, uplink, robot)
    logs = {
        "sequence_number": LogVectorOutput(uplink.get_sequence_number_output_port(), builder,
                                           period),
        "send_time": LogVectorOutput(uplink.get_send_time_output_port(), builder, period),
        "q_sent": LogVectorOutput(uplink.get_q_sent_output_port(), builder, period),
        "state_sent": LogVectorOutput(uplink.get_state_sent_output_port(), builder, period),
    }
    logs.update(add_onboard_loggers(builder, robot, scenario.onboard.tracker.period_s))
    return source, uplink, robot, logs


def MakeOfflinePlaybackDiagram(scenario: Scenario, plan: OfflinePlan) -> OfflinePlaybackHandles:
    """Playback of a valid plan: 4 Hz planned-path source → Uplink → onboard robot.

    The plan is checked again against ``scenario`` (its arm, workspace, margin and limits),
    so a plan made for one scene cannot be played in another where it is unsafe.

    Raises:
        ValueError: If the plan is not valid (the message gives the reason and the first
            violations), fails the check against ``scenario``, or does not match its arm or
            uplink period. Nothing is built then.
    """
    if not isinstance(plan, OfflinePlan):
        raise ValueError(f"plan = {type(plan).__name__} object; expected an OfflinePlan")
    arm = scenario.arm_description
    if tuple(plan.joint_names) != arm.joint_names:
        raise ValueError(f"the plan's joints {plan.joint_names!r} are not the scenario arm's "
                         f"{arm.joint_names!r}")
    period = scenario.uplink.period_s
    if abs(plan.period_s - period) > _PERIOD_RTOL * period:
        raise ValueError(f"the plan's period {plan.period_s!r} s differs from the uplink "
                         f"period {period!r} s")
    if not plan.is_valid:
        raise ValueError("refusing to play back an invalid offline plan: " + plan.reason)
    # The plan was validated against its own scenario; re-check only against another one.
    recheck = None if scenario is plan.scenario else _validate(
        plan.q_planned, plan.t_s, scenario, start_position=plan.q_start,
        check_fd_limits=plan.validation.fd_limits_enforced,
        max_velocity=plan.max_velocity_rad_per_s)
    if recheck is not None and recheck.violations:
        raise ValueError("refusing to play back an offline plan that fails the check against "
                         "this scenario: " + _describe_violations(recheck.violations))

    builder = DiagramBuilder()
    source, uplink, robot, logs = AddPathPlayback(
        builder, scenario, plan.q_planned, states=plan.states_planned, q_start=plan.q_start)
    diagram = builder.Build()
    diagram.set_name("offline_playback")
    last_packet = float(plan.t_s[-1])
    duration = max(last_packet + max(scenario.settle_s, period),
                   scenario.simulation_duration_s or 0.0)
    return OfflinePlaybackHandles(diagram=diagram, source=source, uplink=uplink, robot=robot,
                                  logs=logs, plan=plan, duration_s=duration)


def run_offline(scenario: Scenario, *, constraint: str = "trajectory", max_velocity=None,
                duration_s: float | None = None):
    """Plans, validates and, if the plan is valid, plays it back.

    Args:
        scenario: The session and the set-up.
        constraint, max_velocity: As :func:`plan_offline`.
        duration_s: Simulated playback time, s; default the handles' ``duration_s``.

    Returns:
        (plan, logs): ``logs`` maps each logger name of :class:`OfflinePlaybackHandles` to a
        :class:`SignalLog` copy; it is None when the plan is not valid (nothing is played).

    Raises:
        ValueError: As :func:`plan_offline` for invalid input.
    """
    plan = plan_offline(scenario, constraint=constraint, max_velocity=max_velocity)
    if not plan.is_valid:
        return plan, None
    handles = MakeOfflinePlaybackDiagram(scenario, plan)
    simulator = Simulator(handles.diagram)
    simulator.AdvanceTo(handles.duration_s if duration_s is None else float(duration_s))
    return plan, copy_logs(handles.logs, simulator.get_context())


def copy_logs(loggers: dict, root_context) -> dict:
    """Copies each VectorLogSink's log out of a root context: name → :class:`SignalLog`,
    except "tracker" (:func:`add_onboard_loggers`), which becomes a
    :class:`~telesmooth.systems.laser_tracker.TrackerRecord`: each sample at the time it
    was measured, not the time it was logged."""
    copies = {}
    for name, logger in loggers.items():
        log = logger.FindLog(root_context)
        if name == "tracker":
            copies[name] = tracker_record(log.data().T)
        else:
            copies[name] = SignalLog(t_s=log.sample_times().copy(), values=log.data().T.copy())
    return copies
