"""The jerk-limited stop: from the FD motion the sent commands had, to rest within the limits.

On a pre-simulator collision (the ground's ``DelayFifo`` with ``on_collision = "stop"``) and
when the uplink falls silent (the onboard ``LinkGuard``), the robot must come to rest. The
paper's hold (docs/method.md §5.2) re-sends the last command: the robot stops with a velocity step
and the finite-difference (FD) acceleration and jerk limits are knowingly broken. The stop
planned here instead brings the *sent* command sequence to rest from the FD motion it
actually had (velocity and acceleration of the last three sent commands), with every FD
acceleration and jerk within the limits (and the velocity limit if one is given), and then
holds at the rest pose.

Pure core: :func:`plan_stop` ``(params, history, max_ticks) -> StopPlan``, over the immutable
:class:`StopParams` (the limits, the pose check, the policy) — no Drake systems.

How the plan is made (from :mod:`telesmooth.safety.limiter`):

1. From the sent history p_{k−3}, p_{k−2}, p_{k−1} (p_{k−1} = q_hold, what the hold would
   keep) the FD state is v = (p_{k−1} − p_{k−2})/Δt, a = (p_{k−1} − 2p_{k−2} + p_{k−3})/Δt².
   With a ``rounding_tolerance`` > 0 a history that only rounding puts outside the
   stoppable set is first moved inside (:func:`nudge_into_stoppable_set`).
2. If (v, a) is not in the stoppable set S of every joint (``stoppable_polygon``, for the
   limits shrunk by the limiter's margin), no admissible braking exists from what was sent
   (e.g. the Online-CKS smoother meets the limits only approximately): outcome
   ``HOLD_NOT_STOPPABLE``.
3. Otherwise the limiter is started from that moving state and stepped with the constant
   target r = F(p_{k−1}, v, a) (the time-optimal continuous stop point, ``stop_position``).
   Inside S every step keeps |a| ≤ a_max, |jerk| ≤ j_max (and |v| ≤ v_max) — the limiter's
   invariance proof — and with a constant target it comes to rest (three equal commands)
   at r, a few ticks after the continuous-time stop time. More than ``max_ticks`` commands:
   ``HOLD_TOO_LONG``.
4. Every command of the plan is checked with ``pose_is_safe`` (the pre-simulator's collision
   model and the joint limits); one rejected pose: ``HOLD_POSE_REJECTED``.
5. Per joint, the braking distance d is the planned excursion p − q_hold of largest magnitude
   (signed). Unless ``allow_reverse``, a plan that also moves a joint to the *other* side of
   q_hold (a stop that must reverse first, because the sent motion was already decelerating
   hard) is refused: ``HOLD_REVERSES``, so the stop never leaves the segment
   [q_hold, q_hold + d] of any joint (up to ``SAME_SIDE_TOLERANCE_RAD``).

A refused plan falls back to the immediate hold (the single command q_hold): nothing that was
not checked reaches the plant, and when in doubt the robot holds.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from telesmooth.labelled_enum import LabelledEnum
from telesmooth.safety.finite_differences import fd_state
from telesmooth.safety.limiter import (
    DEFAULT_MARGIN,
    HISTORY_LENGTH,
    LimiterParams,
    limiter_moving_state,
    limiter_params,
    limiter_step,
    stop_position,
)

__all__ = [
    "SAME_SIDE_TOLERANCE_RAD",
    "STOPPABLE_ROUNDING_TOLERANCE",
    "STOP_OUTCOMES",
    "StopOutcome",
    "StopParams",
    "StopPlan",
    "fd_state",
    "is_stoppable",
    "nudge_into_stoppable_set",
    "plan_stop",
    "stop_params",
]


class StopOutcome(LabelledEnum):
    """What a stop plan is (the values are the indices logged on the ``stop_status`` and
    ``stop_outcome`` ports)."""

    NONE = 0
    """No stop planned yet."""
    STOP = 1
    """The jerk-limited stop was planned and accepted."""
    HOLD = 2
    """The paper's immediate hold (``on_collision = "hold"``)."""
    HOLD_NOT_STOPPABLE = 3
    """Fallback: the sent FD state is outside the stoppable set."""
    HOLD_POSE_REJECTED = 4
    """Fallback: a braking command is a pose the pre-simulator rejects."""
    HOLD_REVERSES = 5
    """Fallback: the only admissible stop first moves a joint back past q_hold."""
    HOLD_TOO_LONG = 6
    """Fallback: the stop needs more than ``max_ticks`` commands."""


STOP_OUTCOMES = tuple(outcome.label for outcome in StopOutcome)
"""Outcome labels by index (``"none"``, ``"stop"``, ``"hold"``, ``"hold-not-stoppable"``, …)."""

SAME_SIDE_TOLERANCE_RAD = 1e-12
"""How far a planned command may lie on the wrong side of q_hold (rounding), rad."""

STOPPABLE_ROUNDING_TOLERANCE = 1e-11
"""How far (relative, in the gauge of the stoppable set) an FD state recomputed from sent
floats may lie outside the set and still count as inside: see
:func:`nudge_into_stoppable_set`."""


@dataclass(frozen=True, eq=False)
class StopPlan:
    """What to send from the stop's first tick on.

    Attributes:
        outcome: :attr:`StopOutcome.STOP` or a ``HOLD_…`` fallback.
        commands: (N, J) rad: the commands for the first tick and the N − 1 ticks after it;
            the last three (with the history) are equal, i.e. the stop ends at rest, and the
            last one is the rest pose held afterwards. A fallback is the single row q_hold.
        hold_position: q_hold, the last sent command (what the hold keeps), (J,) rad.
        braking_distance: Per joint, the signed excursion p − q_hold of largest magnitude
            over ``commands``, (J,) rad; zeros for a fallback.
        rejected_command: Index into the braking commands of the first pose the pre-simulator
            rejected (``HOLD_POSE_REJECTED`` only), else −1.
        velocities, accelerations: The limiter's nominal FD velocity and acceleration after
            each command, (N, J) (zeros for a fallback: at rest). The FD values recomputed
            from the commands equal them up to rounding; a caller that continues from a
            command of the plan (the link guard re-joining mid-stop) starts from these, so
            that rounding never accumulates.
    """

    outcome: StopOutcome
    commands: np.ndarray
    hold_position: np.ndarray
    braking_distance: np.ndarray
    rejected_command: int = -1
    velocities: np.ndarray | None = None
    accelerations: np.ndarray | None = None

    @property
    def is_stop(self) -> bool:
        """True when the jerk-limited stop is used (not a hold fallback)."""
        return self.outcome == StopOutcome.STOP

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


@dataclass(frozen=True, eq=False)
class StopParams:
    """Everything a stop plan depends on besides the history (immutable).

    Attributes:
        limiter: The limits (:class:`~telesmooth.safety.limiter.LimiterParams`, rule
            ``"braking"``); their period is the stop's Δt.
        pose_is_safe: Callable (J,) → bool: whether a pose may be commanded (e.g. the
            pre-simulator's :class:`~telesmooth.systems.collision_stop.PreSimulatorPoseCheck`).
            A query, not a state: it answers the same for the same pose.
        allow_reverse: Plan a stop that first moves a joint back past q_hold like any other
            (every pose is still checked); False refuses it (``HOLD_REVERSES``), which the
            collision stop needs for its one-sided bound |p − q_hold| ≤ |d|. The onboard
            link guard allows it: a joint that is just finishing an approach when the link
            goes silent otherwise forces a hold, i.e. a velocity step on every other joint.
        rounding_tolerance: If > 0, a history whose FD state lies outside a joint's stoppable
            set by at most this much (relative gauge: rounding of the sent floats) is first
            moved inside (:func:`nudge_into_stoppable_set`) instead of refused as
            ``HOLD_NOT_STOPPABLE``.
    """

    limiter: LimiterParams
    pose_is_safe: Callable[[np.ndarray], bool]
    allow_reverse: bool = False
    rounding_tolerance: float = 0.0

    @property
    def dt_s(self) -> float:
        return self.limiter.dt_s

    @property
    def num_joints(self) -> int:
        return self.limiter.num_joints

    @property
    def joint_names(self) -> tuple[str, ...] | None:
        return self.limiter.joint_names

    @property
    def max_acceleration(self) -> np.ndarray:
        return self.limiter.max_acceleration

    @property
    def max_jerk(self) -> np.ndarray:
        return self.limiter.max_jerk

    @property
    def max_velocity(self) -> np.ndarray:
        return self.limiter.max_velocity

    def plan(self, sent_history, *, max_ticks: int) -> StopPlan:
        """:func:`plan_stop` with these parameters."""
        return plan_stop(self, sent_history, max_ticks=max_ticks)


def stop_params(*, dt_s: float, max_acceleration, max_jerk, max_velocity=None,
                pose_is_safe: Callable[[np.ndarray], bool], joint_names,
                margin: float = DEFAULT_MARGIN, allow_reverse: bool = False,
                rounding_tolerance: float = 0.0) -> StopParams:
    """Validates and builds :class:`StopParams`.

    Args:
        dt_s: Δt, the command period, s.
        max_acceleration: a_max, rad/s² (scalar, per joint or {joint: value}); finite > 0.
        max_jerk: j_max, rad/s³; finite > 0.
        max_velocity: v_max, rad/s, or None (no velocity limit).
        pose_is_safe: Callable (J,) → bool. Required: an unchecked stop is never sent.
        joint_names: The joints (labels for errors).
        margin: The limiter's relative shrink of the limits (default 1e-9).
        allow_reverse, rounding_tolerance: see :class:`StopParams`.

    Raises:
        ValueError: Limits that are not finite and positive (naming the field, value and
            joint), a bad ``dt_s``, ``margin`` or ``rounding_tolerance``, or a
            ``pose_is_safe`` that is not callable.
    """
    if not callable(pose_is_safe):
        raise ValueError(f"pose_is_safe = {pose_is_safe!r} must be callable (q) -> bool")
    names = tuple(str(name) for name in joint_names)
    if not names:
        raise ValueError("joint_names must name at least one joint")
    if not (math.isfinite(rounding_tolerance) and 0.0 <= rounding_tolerance < 1e-6):
        raise ValueError(f"rounding_tolerance = {rounding_tolerance!r} must be in [0, 1e-6)")
    limits = limiter_params(dt_s=dt_s, max_acceleration=max_acceleration, max_jerk=max_jerk,
                            max_velocity=max_velocity, joint_names=names, rule="braking",
                            margin=margin)
    return StopParams(limiter=limits, pose_is_safe=pose_is_safe,
                      allow_reverse=bool(allow_reverse),
                      rounding_tolerance=float(rounding_tolerance))


def nudge_into_stoppable_set(history, stoppable_sets, dt_s: float, *,
                             tolerance: float = STOPPABLE_ROUNDING_TOLERANCE) -> np.ndarray:
    """The command history, moved by a few ulps where only rounding puts it outside S.

    A plan accepts a history only if its FD state (v, a) lies in the stoppable set S of every
    joint, checked exactly (gauge max_i g_i · (v, a) ≤ 1). A sequence made by the limiter
    that brakes or accelerates at its limit keeps its *nominal* state on the boundary of S,
    and the FD state recomputed from the sent floats then lies outside S by rounding (gauge
    up to ~3e-14 above 1 for |p| ≲ 5 rad; about a quarter of such ticks). Planning a stop
    from it would fall back to the hold although the motion is stoppable. For every joint
    whose gauge g satisfies 1 < g ≤ 1 + ``tolerance``, this returns the history with (v, a)
    scaled by (1 − tolerance)/g:

        p_{k−2}' = p_{k−1} − v' Δt,   p_{k−3}' = p_{k−1} − 2 v' Δt + a' Δt²

    (p_{k−1}, the commanded pose, is unchanged). The change is ≲ 2·tolerance·(|v| Δt +
    |a| Δt²) rad, so the FD values of the *actual* sequence followed by commands planned from
    the nudged history differ from the planned ones by ~1e-11 of the limits, far inside the
    limiter's margin (1e-9). Joints inside S, or farther outside than ``tolerance`` (really
    not stoppable), are returned bit for bit.

    Args:
        history: (3, J) rad, p_{k−3}, p_{k−2}, p_{k−1}, oldest first.
        stoppable_sets: Per joint, the :class:`~telesmooth.safety.limiter.StoppablePolygon`
            the plan checks (``LimiterParams.stoppable_sets``).
        dt_s: Δt, s.
        tolerance: Largest relative excess treated as rounding.

    Returns:
        A (3, J) array (a copy).
    """
    h = np.array(history, dtype=float)
    dt = float(dt_s)
    velocity, acceleration = fd_state(h, dt)
    for joint, stoppable in enumerate(stoppable_sets):
        gauge = float(np.max(stoppable.facets[:, 0] * velocity[joint]
                             + stoppable.facets[:, 1] * acceleration[joint]))
        if 1.0 < gauge <= 1.0 + tolerance:
            scale = (1.0 - tolerance) / gauge
            v, a = velocity[joint] * scale, acceleration[joint] * scale
            h[1, joint] = h[2, joint] - v * dt
            h[0, joint] = h[2, joint] - 2.0 * v * dt + a * dt**2
    return h


def is_stoppable(params: LimiterParams, history) -> bool:
    """Whether the FD state of ``history`` (3, J) lies in every joint's stoppable set (exact
    check, no tolerance)."""
    velocity, acceleration = fd_state(history, params.dt_s)
    return all(bool(s.contains(velocity[i], acceleration[i]))
               for i, s in enumerate(params.stoppable_sets))


def _fallback(outcome: StopOutcome, q_hold: np.ndarray, rejected: int = -1) -> StopPlan:
    zeros = np.zeros((1, q_hold.size))
    return StopPlan(outcome=outcome, commands=q_hold[None, :].copy(), hold_position=q_hold.copy(),
                    braking_distance=np.zeros_like(q_hold), rejected_command=rejected,
                    velocities=zeros, accelerations=zeros.copy())


def _nudge_state(params: LimiterParams, velocity, acceleration, tolerance: float):
    """(v, a) scaled by (1 − tolerance)/g for every joint whose gauge g is in
    (1, 1 + tolerance] (the state form of :func:`nudge_into_stoppable_set`)."""
    v, a = np.array(velocity, dtype=float), np.array(acceleration, dtype=float)
    for joint, stoppable in enumerate(params.stoppable_sets):
        gauge = float(np.max(stoppable.facets[:, 0] * v[joint]
                             + stoppable.facets[:, 1] * a[joint]))
        if 1.0 < gauge <= 1.0 + tolerance:
            scale = (1.0 - tolerance) / gauge
            v[joint], a[joint] = v[joint] * scale, a[joint] * scale
    return v, a


def plan_stop(params: StopParams, history, *, max_ticks: int, velocity=None,
              acceleration=None) -> StopPlan:
    """The stop after the sent commands ``history`` = [p_{k−3}, p_{k−2}, p_{k−1}] (3, J).

    Args:
        params: The limits, the pose check and the policy (:func:`stop_params`).
        history: The last three sent commands, oldest first, rad.
        max_ticks: Most commands a stop may take (≥ 1); longer stops fall back to hold.
        velocity, acceleration: Optional nominal FD state of the history, (J,) each (what a
            limiter that made the history kept: equal to the FD values of the floats up to
            rounding). Given, the plan starts from it instead of recomputing it from the
            floats (a ``rounding_tolerance`` then applies to it in the same way).

    Returns:
        The plan; ``outcome`` says whether it is the stop or which fallback.

    Raises:
        ValueError: A wrong shape or non-finite history, or ``max_ticks`` < 1.
    """
    if isinstance(max_ticks, bool) or not isinstance(max_ticks, (int, np.integer)) or (
            max_ticks < 1):
        raise ValueError(f"max_ticks = {max_ticks!r} must be a positive integer")
    limits = params.limiter
    h = np.asarray(history, dtype=float)
    n = limits.num_joints
    if h.shape != (HISTORY_LENGTH, n):
        raise ValueError(f"sent_history has shape {h.shape}; expected "
                         f"({HISTORY_LENGTH}, {n}) (p_(k-3), p_(k-2), p_(k-1))")
    if not np.all(np.isfinite(h)):
        raise ValueError(f"sent_history = {h.tolist()!r} must be finite")
    q_hold = h[2].copy()
    given = velocity is not None or acceleration is not None
    if given:
        velocity, acceleration = (np.array(x, dtype=float) for x in (velocity, acceleration))
        if velocity.shape != (n,) or acceleration.shape != (n,):
            raise ValueError(f"velocity, acceleration have shapes {velocity.shape}, "
                             f"{acceleration.shape}; expected ({n},) each")
        if params.rounding_tolerance > 0.0:
            velocity, acceleration = _nudge_state(limits, velocity, acceleration,
                                                  params.rounding_tolerance)
    elif params.rounding_tolerance > 0.0:
        h = nudge_into_stoppable_set(h, limits.stoppable_sets, limits.dt_s,
                                     tolerance=params.rounding_tolerance)
    if not given:
        velocity, acceleration = fd_state(h, limits.dt_s)
    # Strictly inside S of the (shrunk) internal limits: then the limiter's nominal state is
    # the sent FD state and no projection moves it.
    if not all(bool(s.contains(velocity[i], acceleration[i]))
               for i, s in enumerate(limits.stoppable_sets)):
        return _fallback(StopOutcome.HOLD_NOT_STOPPABLE, q_hold)
    target = stop_position(q_hold, velocity, acceleration, limits.acceleration_internal,
                           limits.jerk_internal)
    state = limiter_moving_state(limits, h, target)
    if given:
        state = state._replace(velocity=velocity, acceleration=acceleration)
    sent = [row for row in h]
    commands, velocities, accelerations = [], [], []
    while not (np.array_equal(sent[-1], sent[-2]) and np.array_equal(sent[-2], sent[-3])
               and commands):
        if len(commands) >= max_ticks:
            return _fallback(StopOutcome.HOLD_TOO_LONG, q_hold)
        state, command = limiter_step(limits, state, target)
        commands.append(command)
        velocities.append(state.velocity)
        accelerations.append(state.acceleration)
        sent.append(command)
    commands = np.array(commands)
    for index, command in enumerate(commands):
        if not params.pose_is_safe(command):
            return _fallback(StopOutcome.HOLD_POSE_REJECTED, q_hold, index)
    excursion = commands - q_hold
    farthest = np.argmax(np.abs(excursion), axis=0)
    distance = excursion[farthest, np.arange(n)]
    # distance = 0 means the joint never moves (its largest excursion is 0).
    if not params.allow_reverse and np.any(
            excursion * np.sign(distance) < -SAME_SIDE_TOLERANCE_RAD):
        return _fallback(StopOutcome.HOLD_REVERSES, q_hold)
    return StopPlan(outcome=StopOutcome.STOP, commands=commands, hold_position=q_hold,
                    braking_distance=distance, velocities=np.array(velocities),
                    accelerations=np.array(accelerations))
