"""Jerk-limited collision stop: the optional alternative to the immediate hold (issue 6 part 2).

On a pre-simulator collision the paper's policy (SPEC §5.2, "hold") re-sends the last sent
command: the robot stops with a velocity step and the finite-difference (FD) acceleration and
jerk limits are knowingly broken for a few ticks. The stop planned here instead brings the
*sent* command sequence to rest from the FD motion it actually had (velocity and acceleration
of the last three sent packets), with every FD acceleration and jerk within the smoother's
limits (and the velocity limit if one is given), and then holds at the rest pose.

This module is the pure core (numpy and the hard-limited online core; no
``pydrake.systems``): :class:`CollisionStopPlanner` turns the sent history into a
:class:`CollisionStopPlan`; :class:`~telesmooth.systems.delay_fifo.DelayFifo` (with
``on_collision = "stop"``) plays the plan out one command per tick.

How the plan is made (all from :mod:`telesmooth.smoothing.online_hard`):

1. From the sent history p_{k−3}, p_{k−2}, p_{k−1} (p_{k−1} = q_hold, what the hold would
   keep) the FD state is v = (p_{k−1} − p_{k−2})/Δt, a = (p_{k−1} − 2p_{k−2} + p_{k−3})/Δt².
2. If (v, a) is not in the stoppable set S of every joint (``stoppable_polygon``, for the
   limits shrunk by the limiter's margin), no admissible braking exists from what was sent
   (the Online-CKS smoother meets the limits only approximately): outcome
   ``"hold-not-stoppable"``.
3. Otherwise an :class:`~telesmooth.smoothing.online_hard.OnlineHardLimiter` is started from
   that moving state and stepped with the constant target r = F(p_{k−1}, v, a) (the
   time-optimal continuous stop point, ``stop_position``). Inside S every step keeps
   |a| ≤ a_max, |jerk| ≤ j_max (and |v| ≤ v_max) — the limiter's invariance proof — and with
   a constant target it comes to rest (three equal commands) at r, a few ticks after the
   continuous-time stop time. More than ``max_ticks`` commands: ``"hold-too-long"``.
4. Every command of the plan is checked with ``pose_is_safe`` (the pre-simulator's collision
   model and the joint limits); one rejected pose: ``"hold-pose-rejected"``.
5. Per joint, the braking distance d is the planned excursion p − q_hold of largest magnitude
   (signed). Every planned command satisfies |p − q_hold| ≤ |d| by construction; a plan that
   also moves a joint to the *other* side of q_hold (a stop that must reverse first, because
   the sent motion was already decelerating hard) is refused: ``"hold-reverses"``, so the
   stop never leaves the segment [q_hold, q_hold + d] of any joint (up to
   ``SAME_SIDE_TOLERANCE_RAD``).

A refused plan falls back to the immediate hold (the single command q_hold): nothing that was
not checked reaches the plant, and when in doubt the robot holds.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable

import numpy as np

from telesmooth.smoothing.online_hard import (
    DEFAULT_MARGIN,
    HISTORY_LENGTH,
    OnlineHardLimiter,
    stop_position,
)
from telesmooth.smoothing.validation import as_per_joint

__all__ = [
    "STOP_OUTCOMES",
    "SAME_SIDE_TOLERANCE_RAD",
    "CollisionStopPlan",
    "CollisionStopPlanner",
    "MakeCollisionStopPlanner",
    "PreSimulatorPoseCheck",
    "STOPPABLE_ROUNDING_TOLERANCE",
    "finite_smoother_limits",
    "nudge_into_stoppable_set",
    "start_limiter_moving",
]

STOP_OUTCOMES = (
    "none",                 # no collision handled yet
    "stop",                 # jerk-limited stop planned and accepted
    "hold",                 # on_collision = "hold": the paper's immediate hold
    "hold-not-stoppable",   # the sent FD state is outside the stoppable set
    "hold-pose-rejected",   # a braking command is a pose the pre-simulator rejects
    "hold-reverses",        # the only admissible stop first moves back past q_hold
    "hold-too-long",        # the stop needs more than max_ticks commands
)
"""Outcome names; the DelayFifo's ``stop_status`` port carries the index in this tuple."""

SAME_SIDE_TOLERANCE_RAD = 1e-12
"""How far a planned command may lie on the wrong side of q_hold (rounding), rad."""

SENT_HISTORY_LENGTH = HISTORY_LENGTH
"""The planner needs the last three sent commands p_{k−3}, p_{k−2}, p_{k−1}."""


@dataclasses.dataclass(frozen=True, eq=False)
class CollisionStopPlan:
    """What to send from the collision tick on.

    Attributes:
        outcome: One of :data:`STOP_OUTCOMES` (``"stop"`` or a ``"hold-…"`` fallback).
        commands: (N, J) rad: the commands for the collision tick and the N − 1 ticks after
            it; the last three (with the history) are equal, i.e. the stop ends at rest, and
            the last one is the rest pose held afterwards. A fallback is the single row q_hold.
        hold_position: q_hold, the last sent command (what the hold keeps), (J,) rad.
        braking_distance: Per joint, the signed excursion p − q_hold of largest magnitude
            over ``commands``, (J,) rad; zeros for a fallback.
        rejected_command: Index into the braking commands of the first pose the pre-simulator
            rejected (``"hold-pose-rejected"`` only), else −1.
    """

    outcome: str
    commands: np.ndarray
    hold_position: np.ndarray
    braking_distance: np.ndarray
    rejected_command: int = -1

    @property
    def is_stop(self) -> bool:
        """True when the jerk-limited stop is used (not a hold fallback)."""
        return self.outcome == "stop"

    @property
    def rest_position(self) -> np.ndarray:
        """The pose the robot holds after the stop, (J,) rad."""
        return self.commands[-1].copy()

    @property
    def ticks_to_rest(self) -> int:
        """N, the number of planned commands: with the history, the last three are equal, so
        the FD velocity and acceleration are 0 from the N-th command on (the rest pose itself
        is first commanded two commands earlier, or at once for a history at rest)."""
        return int(self.commands.shape[0])


class PreSimulatorPoseCheck:
    """Whether the pre-simulator accepts a pose: within the joint limits and no collision.

    The same test as :class:`~telesmooth.systems.collision_checker.CollisionChecker` (smallest
    signed distance ≥ ``safety_margin_m``) plus the joint limits the onboard receiver enforces.
    Holds a collision model (a kinematics scratch context, fully overwritten per query).

    Args:
        collision_model: An :class:`~telesmooth.arms.collision.ArmCollisionModel` (anything
            with ``query(q).in_collision(margin)``).
        safety_margin_m: The checker's margin, m.
        lower_rad, upper_rad: Joint limits, (J,) rad.
    """

    def __init__(self, collision_model, *, safety_margin_m: float, lower_rad, upper_rad):
        self._model = collision_model
        self._margin = float(safety_margin_m)
        self._lower = np.asarray(lower_rad, dtype=float)
        self._upper = np.asarray(upper_rad, dtype=float)

    def __call__(self, q) -> bool:
        q = np.asarray(q, dtype=float)
        if q.shape != self._lower.shape or not np.all(np.isfinite(q)):
            return False
        if np.any(q < self._lower) or np.any(q > self._upper):
            return False
        return not self._model.query(q).in_collision(self._margin)


def start_limiter_moving(limiter: OnlineHardLimiter, sent_history: np.ndarray,
                         target: np.ndarray) -> None:
    """Puts ``limiter`` just after the sent commands ``sent_history`` (3, J), oldest first:
    nominal (p, v, a) = their FD values, target history r_{k−2} = r_{k−1} = ``target``.

    ``OnlineHardLimiter.reset`` only starts at rest; its state vector
    [p, v, a, p_{k−3} … p_k, r_{k−2}, r_{k−1}, held, ticks] starts it moving. p_{k−3} of the
    limiter (one before our oldest) only enters the jerk of the tick already sent.
    """
    dt = limiter.dt_s
    h = np.asarray(sent_history, dtype=float)
    velocity = (h[2] - h[1]) / dt
    acceleration = (h[2] - 2.0 * h[1] + h[0]) / dt**2
    limiter.set_state_vector(np.concatenate([
        h[2], velocity, acceleration, h[0], h[0], h[1], h[2], target, target,
        np.zeros_like(target), [0.0]]))


STOPPABLE_ROUNDING_TOLERANCE = 1e-11
"""How far (relative, in the gauge of the stoppable set) an FD state recomputed from sent
floats may lie outside the set and still count as inside: see
:func:`nudge_into_stoppable_set`."""


def nudge_into_stoppable_set(history, stoppable_sets, dt_s: float, *,
                             tolerance: float = STOPPABLE_ROUNDING_TOLERANCE) -> np.ndarray:
    """The command history, moved by a few ulps where only rounding puts it outside S.

    The stop planner accepts a history only if its FD state (v, a) lies in the stoppable set
    S of every joint, checked exactly (gauge max_i g_i · (v, a) ≤ 1). A sequence made by an
    :class:`~telesmooth.smoothing.online_hard.OnlineHardLimiter` that brakes or accelerates
    at its limit keeps its *nominal* state on the boundary of S, and the FD state recomputed
    from the sent floats then lies outside S by rounding (gauge up to ~3e-14 above 1 for
    |p| ≲ 5 rad; about a quarter of such ticks). Planning a stop from it would fall back to
    the hold although the motion is stoppable. For every joint whose gauge g satisfies
    1 < g ≤ 1 + ``tolerance``, this returns the history with (v, a) scaled by
    (1 − tolerance)/g:

        p_{k−2}' = p_{k−1} − v' Δt,   p_{k−3}' = p_{k−1} − 2 v' Δt + a' Δt²

    (p_{k−1}, the commanded pose, is unchanged). The change is ≲ 2·tolerance·(|v| Δt +
    |a| Δt²) rad, so the FD values of the *actual* sequence followed by a stop planned from
    the nudged history differ from the planned ones by ~1e-11 of the limits, far inside the
    limiter's margin (1e-9). Joints inside S, or farther outside than ``tolerance`` (really
    not stoppable), are returned bit for bit.

    Args:
        history: (3, J) rad, p_{k−3}, p_{k−2}, p_{k−1}, oldest first.
        stoppable_sets: Per joint, the :class:`~telesmooth.smoothing.online_hard.StoppablePolygon`
            the planner checks (``OnlineHardLimiter.stoppable_sets`` with the same limits and
            margin).
        dt_s: Δt, s.
        tolerance: Largest relative excess treated as rounding.

    Returns:
        A (3, J) array (a copy).
    """
    h = np.array(history, dtype=float)
    dt = float(dt_s)
    velocity = (h[2] - h[1]) / dt
    acceleration = (h[2] - 2.0 * h[1] + h[0]) / dt**2
    for joint, stoppable in enumerate(stoppable_sets):
        gauge = float(np.max(stoppable.facets[:, 0] * velocity[joint]
                             + stoppable.facets[:, 1] * acceleration[joint]))
        if 1.0 < gauge <= 1.0 + tolerance:
            scale = (1.0 - tolerance) / gauge
            v, a = velocity[joint] * scale, acceleration[joint] * scale
            h[1, joint] = h[2, joint] - v * dt
            h[0, joint] = h[2, joint] - 2.0 * v * dt + a * dt**2
    return h


class CollisionStopPlanner:
    """Plans the jerk-limited stop from the sent history (see the module docstring).

    Args:
        dt_s: Δt, the uplink period, s.
        max_acceleration: a_max, rad/s² (scalar, per joint or {joint: value}); finite > 0.
        max_jerk: j_max, rad/s³; finite > 0.
        max_velocity: v_max, rad/s, or None (no velocity limit).
        pose_is_safe: Callable (J,) → bool: whether the pre-simulator accepts a pose
            (e.g. :class:`PreSimulatorPoseCheck`). Required: an unchecked stop is never sent.
        joint_names: Labels for errors.
        margin: The limiter's relative shrink of the limits (default 1e-9).
        allow_reverse: If True, a stop that first moves a joint back past q_hold is planned
            like any other (every pose is still checked); the default False refuses it
            (``"hold-reverses"``), which the collision stop needs for its bound
            |p − q_hold| ≤ |d| on one side. The onboard link guard allows it: a joint that is
            just finishing an approach when the link goes silent otherwise forces a hold, i.e.
            a velocity step on every other joint.
        rounding_tolerance: If > 0, a history whose FD state lies outside a joint's
            stoppable set by at most this much (relative gauge; rounding of the sent floats)
            is first moved inside (:func:`nudge_into_stoppable_set`) instead of refused as
            ``"hold-not-stoppable"``. Default 0: the exact check (the collision stop); the
            onboard link guard uses :data:`STOPPABLE_ROUNDING_TOLERANCE`.

    Raises:
        ValueError: Limits that are not finite and positive (naming the field, value and
            joint), a bad ``dt_s`` or ``margin``, or a ``pose_is_safe`` that is not callable.
    """

    def __init__(self, *, dt_s: float, max_acceleration, max_jerk, max_velocity=None,
                 pose_is_safe: Callable[[np.ndarray], bool], joint_names,
                 margin: float = DEFAULT_MARGIN, allow_reverse: bool = False,
                 rounding_tolerance: float = 0.0):
        if not callable(pose_is_safe):
            raise ValueError(f"pose_is_safe = {pose_is_safe!r} must be callable (q) -> bool")
        self._joint_names = tuple(str(name) for name in joint_names)
        n = len(self._joint_names)
        if n == 0:
            raise ValueError("joint_names must name at least one joint")
        self._limiter_arguments = dict(
            dt_s=dt_s, max_acceleration=max_acceleration, max_jerk=max_jerk,
            max_velocity=max_velocity, joint_names=self._joint_names, rule="braking",
            margin=margin)
        # Validates every argument once (naming field, value and joint).
        probe = OnlineHardLimiter(q_start=np.zeros(n), **self._limiter_arguments)
        self._dt = probe.dt_s
        self._pose_is_safe = pose_is_safe
        self._margin = float(margin)
        self._allow_reverse = bool(allow_reverse)
        if not (math.isfinite(rounding_tolerance) and 0.0 <= rounding_tolerance < 1e-6):
            raise ValueError(f"rounding_tolerance = {rounding_tolerance!r} must be in [0, 1e-6)")
        self._rounding_tolerance = float(rounding_tolerance)
        self.max_acceleration = probe.max_acceleration
        self.max_jerk = probe.max_jerk
        self.max_velocity = probe.max_velocity

    @property
    def dt_s(self) -> float:
        return self._dt

    @property
    def joint_names(self) -> tuple[str, ...]:
        return self._joint_names

    @property
    def num_joints(self) -> int:
        return len(self._joint_names)

    def fd_state(self, sent_history) -> tuple[np.ndarray, np.ndarray]:
        """(v, a) of the sent history (3, J), oldest first: rad/s, rad/s²."""
        h = self._check_history(sent_history)
        return (h[2] - h[1]) / self._dt, (h[2] - 2.0 * h[1] + h[0]) / self._dt**2

    def _check_history(self, sent_history) -> np.ndarray:
        h = np.asarray(sent_history, dtype=float)
        n = self.num_joints
        if h.shape != (SENT_HISTORY_LENGTH, n):
            raise ValueError(f"sent_history has shape {h.shape}; expected "
                             f"({SENT_HISTORY_LENGTH}, {n}) (p_(k-3), p_(k-2), p_(k-1))")
        if not np.all(np.isfinite(h)):
            raise ValueError(f"sent_history = {h.tolist()!r} must be finite")
        return h

    def _fallback(self, outcome: str, q_hold: np.ndarray, rejected: int = -1):
        return CollisionStopPlan(outcome=outcome, commands=q_hold[None, :].copy(),
                                 hold_position=q_hold.copy(),
                                 braking_distance=np.zeros_like(q_hold),
                                 rejected_command=rejected)

    def plan(self, sent_history, *, max_ticks: int) -> CollisionStopPlan:
        """The stop after the sent commands ``sent_history`` (3, J) [p_{k−3}, p_{k−2}, p_{k−1}].

        Args:
            sent_history: The last three sent commands, oldest first, rad.
            max_ticks: Most commands a stop may take (≥ 1); longer stops fall back to hold.

        Returns:
            The plan; ``outcome`` says whether it is the stop or which fallback.

        Raises:
            ValueError: A wrong shape or non-finite history, or ``max_ticks`` < 1.
        """
        if isinstance(max_ticks, bool) or not isinstance(max_ticks, (int, np.integer)) or (
                max_ticks < 1):
            raise ValueError(f"max_ticks = {max_ticks!r} must be a positive integer")
        history = self._check_history(sent_history)
        q_hold = history[2].copy()
        limiter = OnlineHardLimiter(q_start=q_hold, **self._limiter_arguments)
        if self._rounding_tolerance > 0.0:
            history = nudge_into_stoppable_set(history, limiter.stoppable_sets, self._dt,
                                               tolerance=self._rounding_tolerance)
        velocity, acceleration = self.fd_state(history)
        # Strictly inside S of the (shrunk) internal limits: then the limiter's nominal state
        # is the sent FD state and no projection moves it.
        stoppable = all(bool(s.contains(velocity[i], acceleration[i]))
                        for i, s in enumerate(limiter.stoppable_sets))
        if not stoppable:
            return self._fallback("hold-not-stoppable", q_hold)
        shrink = 1.0 - self._margin
        target = stop_position(q_hold, velocity, acceleration, self.max_acceleration * shrink,
                               self.max_jerk * shrink)
        start_limiter_moving(limiter, history, target)
        sent = [row for row in history]
        commands = []
        while not (np.array_equal(sent[-1], sent[-2]) and np.array_equal(sent[-2], sent[-3])
                   and commands):
            if len(commands) >= max_ticks:
                return self._fallback("hold-too-long", q_hold)
            command = limiter.step(target)
            commands.append(command)
            sent.append(command)
        commands = np.array(commands)
        for index, command in enumerate(commands):
            if not self._pose_is_safe(command):
                return self._fallback("hold-pose-rejected", q_hold, index)
        excursion = commands - q_hold
        farthest = np.argmax(np.abs(excursion), axis=0)
        distance = excursion[farthest, np.arange(self.num_joints)]
        # distance = 0 means the joint never moves (its largest excursion is 0).
        if not self._allow_reverse and np.any(
                excursion * np.sign(distance) < -SAME_SIDE_TOLERANCE_RAD):
            return self._fallback("hold-reverses", q_hold)
        return CollisionStopPlan(outcome="stop", commands=commands, hold_position=q_hold,
                                 braking_distance=distance)


def finite_smoother_limits(smoother_config, joint_names, *, purpose: str) -> dict:
    """{field: per-joint values} of the smoother's a_max and j_max, which must be finite.

    Raises:
        ValueError: naming the field, its value and ``purpose`` (what needs them finite).
    """
    names = tuple(joint_names)
    limits = {}
    for field in ("max_acceleration_rad_per_s2", "max_jerk_rad_per_s3"):
        values = as_per_joint(field, getattr(smoother_config, field), len(names), names,
                              allow_inf=True)
        if not np.all(np.isfinite(values)):
            raise ValueError(f"smoother.{field} = {getattr(smoother_config, field)!r} must be "
                             f"finite for {purpose}")
        limits[field] = values
    return limits


def MakeCollisionStopPlanner(*, period_s: float, smoother_config, arm, collision_model,
                             safety_margin_m: float, max_velocity=None) -> CollisionStopPlanner:
    """The planner of the ground station: the smoother's limits, the pre-simulator's check,
    and the rounding tolerance :data:`STOPPABLE_ROUNDING_TOLERANCE`.

    Args:
        period_s: The uplink period, s.
        smoother_config: A ``ReducedQSmootherConfig`` (its a_max and j_max are the limits).
        arm: The ``ArmDescription`` (joint names and limits).
        collision_model: The pre-simulator's ``ArmCollisionModel`` (e.g.
            ``CollisionChecker.collision_model``).
        safety_margin_m: The checker's ``safety_margin_m``.
        max_velocity: Optional v_max, rad/s.

    Raises:
        ValueError: An infinite a_max or j_max (the stop needs finite limits), naming the field.
    """
    names = tuple(arm.joint_names)
    limits = finite_smoother_limits(smoother_config, names,
                                    purpose="fifo.on_collision = 'stop' (the stop brakes "
                                            "within these limits)")
    check = PreSimulatorPoseCheck(collision_model, safety_margin_m=safety_margin_m,
                                  lower_rad=arm.joint_lower_rad, upper_rad=arm.joint_upper_rad)
    return CollisionStopPlanner(
        dt_s=period_s, max_acceleration=limits["max_acceleration_rad_per_s2"],
        max_jerk=limits["max_jerk_rad_per_s3"], max_velocity=max_velocity,
        pose_is_safe=check, joint_names=names,
        # A sent stream the online-hard limiter kept inside the stoppable set can land a few
        # ulps outside it when its FD state is recomputed from the sent floats; that is not
        # a reason to fall back to the hold's velocity step (the onboard guard does the same).
        rounding_tolerance=STOPPABLE_ROUNDING_TOLERANCE)
