"""The onboard link guard as a pure state machine: ``guard_step(params, state, inputs)``.

The guard sits between the onboard receiver (the last accepted 4 Hz uplink command) and the
robot. It is the robot's own line of defence: whatever the ground sends, and whether or not
it sends anything, every command the guard issues keeps the finite-difference (FD)
velocity, acceleration and jerk of the command *sequence* within the limits (Δt = period_s),
and a stream that is itself within the limits passes bit for bit.

Modes (:class:`GuardMode`)
--------------------------
- ``TRACK``: following the stream. Each accepted packet that directly follows the one the
  last command used is commanded at once (in the poll it is accepted, keeping the stream's
  timing); a packet after a gap (lost or held back by the link, a burst accepted in one
  poll, a new ground session) at the next guard tick. Either way the command is the
  limiter's step towards the packet (:func:`~telesmooth.safety.limiter.limiter_step`, rule
  ``"braking"``, continuing from the nominal FD state of the last commands), which keeps
  the FD velocity, acceleration and jerk within the limits whatever the packet is (the
  limiter's feasibility proof). On a stream that is itself within the limits the limiter
  reproduces the packet: it is then commanded bit for bit (a command that misses it by
  rounding only, ``PASS_ROUNDING_RAD``, is replaced by the packet when the packet is within
  the limits after the last three commands and leaves a stoppable state,
  :func:`passes_within_limits`). A packet that steps too far (0.3 rad in one tick, a skipped
  sample, a ground stream that breaks the limits) is followed as closely as the limits
  allow, and the distance to the stream is reported (``stream_distance_rad``), not hidden.
- ``STOPPING``: the uplink fell silent (no packet for ``timeout_s``): the jerk-limited stop
  :func:`~telesmooth.safety.stop.plan_stop` from the last three commands is played out, one
  command per guard tick, then ``HELD``. If no such stop exists (a braking pose the
  pre-simulator's model rejects, a stop longer than ``max_stop_ticks``), the guard holds at
  once (``HELD``, the paper's hold; reported in ``stop_outcome``).
- ``HELD``: at rest (after a stop or a hold, and before the first packet).
- ``RESUMING``: packets are back after a stop or a hold (or the first packets): each packet
  is followed exactly as in TRACK (the limiter leads the robot onto the stream). The guard
  returns to TRACK once ``resume_match_ticks`` consecutive commands each lie within
  ``rejoin_tolerance_rad`` of their packet (every joint): then the last three commands are
  within that tolerance of three packets, so the robot's FD velocity and acceleration are
  within 2·tol/Δt and 4·tol/Δt² of the stream's and it follows it within the limits. This
  is a convergence test, not bit-for-bit equality: a stream that breaks the limits is
  re-joined as soon as the limited command is close to it. Catching up takes as long as the
  limits need: on the ``Defaults`` Online-CKS stream (the operator moves near the limits)
  the hand-over came 0.5–15 s after 1 s of silence (median 8 s; measured on its packets).

Timing (polls i = round(t/poll_period_s), P = period_s/poll_period_s, T =
⌈timeout_s/poll_period_s⌉): a *guard tick* is a poll with i − i_cmd ≥ P (i_cmd: the poll of
the last command), so the guard's own commands (stop, re-join, a packet after a gap) are at
least period_s apart; a packet that directly follows the last one used is commanded at once.
Silence is i − i_pkt ≥ T with no packet pending.

Defaults and why: ``timeout_s`` = 0.625 s = 2.5 periods. A packet is due every 0.25 s; the
ramp-down must not start for a packet that is merely late — a loaded ground or onboard
process delays packets (with one CPU-bound process beside the two processes on 2 cores,
packets arrived up to 0.38 s apart, 0.13 s late: a 0.3 s timeout fires on them) — nor for
one packet the link lost (the next one is 0.5 s after the last). 2.5 periods tolerate one
lost packet plus half a period of lateness, or one packet 1.5 periods late, while a link
that is really down still starts the ramp-down 0.375 s after the first packet that did not
come. ``rejoin_tolerance_rad`` = 1e-3 rad (about 1 mm at 1 m).

Pure core: :func:`guard_params` validates once; :func:`guard_initial_state`;
:func:`guard_step` returns a new :class:`GuardState` and the command (no argument is
changed). :class:`~telesmooth.systems.link_guard.LinkGuard` keeps the state in a Drake
Context.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from typing import NamedTuple

import numpy as np

from telesmooth.arms.joint_vectors import (
    as_per_joint,
    check_joint_limits,
    check_joint_vector,
)
from telesmooth.labelled_enum import LabelledEnum
from telesmooth.safety.limiter import (
    DEFAULT_MARGIN,
    HISTORY_LENGTH,
    LimiterOutcome,
    LimiterParams,
    LimiterState,
    limiter_params,
    limiter_step,
)
from telesmooth.safety.stop import (
    STOPPABLE_ROUNDING_TOLERANCE,
    StopOutcome,
    StopParams,
    fd_state,
    plan_stop,
    stop_params,
)

__all__ = [
    "FdLimitRatios",
    "GuardInputs",
    "GuardMode",
    "GuardParams",
    "GuardState",
    "LinkGuardConfig",
    "fd_limits_ratio",
    "guard_initial_state",
    "guard_params",
    "guard_step",
    "passes_within_limits",
]

PASS_ROUNDING_RAD = 1e-12
"""Relative (to max(1, |r|)) difference below which a limiter command that missed its packet
is taken as the packet itself, when the packet is within the limits after the history: the
limiter reproduces a stream within the limits up to the rounding of its nominal state, and
such a stream must pass bit for bit."""


class GuardMode(LabelledEnum):
    """The guard's mode (the value is what the ``guard_mode`` port and the telemetry carry)."""

    TRACK = 0
    STOPPING = 1
    HELD = 2
    RESUMING = 3


@dataclasses.dataclass(frozen=True)
class LinkGuardConfig:
    """Settings of the link guard.

    Attributes:
        timeout_s: Silence since the last accepted packet after which the ramp-down starts, s
            (> 0). Default 0.625 s (2.5 periods; module docstring says why). Rounded up to
            whole polls.
        period_s: Spacing of the guard's own commands (stop and re-join), s (> 0); the uplink
            period, and the Δt of every FD limit (0.25 s at 4 Hz).
        poll_period_s: How often the inputs are examined, s (> 0, ≤ period_s, and period_s
            must be a whole number of polls so that the guard's commands are exactly
            period_s apart).
        max_stop_ticks: Most commands a stop may take (≥ 1); a longer stop falls back to the
            hold. Sizes the state that stores the plan. 400 = 100 s at 4 Hz.
        resume_match_ticks: Consecutive re-join commands within ``rejoin_tolerance_rad`` of
            their packets before the guard reports TRACK again (≥ 1).
        rejoin_tolerance_rad: How close (every joint) a re-join command must be to its packet
            to count towards ``resume_match_ticks``, rad (≥ 0; 0 = bit for bit).
    """

    timeout_s: float = 0.625
    period_s: float = 0.25
    poll_period_s: float = 0.01
    max_stop_ticks: int = 400
    resume_match_ticks: int = 3
    rejoin_tolerance_rad: float = 1e-3

    def __post_init__(self) -> None:
        for field in ("timeout_s", "period_s", "poll_period_s", "rejoin_tolerance_rad"):
            value = getattr(self, field)
            if isinstance(value, bool) or not isinstance(value, (int, float, np.integer,
                                                                 np.floating)):
                raise ValueError(f"LinkGuardConfig.{field} = {value!r} must be a number")
            positive = field != "rejoin_tolerance_rad"
            if not (math.isfinite(value) and (value > 0.0 if positive else value >= 0.0)):
                raise ValueError(f"LinkGuardConfig.{field} = {value!r} must be finite and "
                                 + ("> 0" if positive else ">= 0"))
        if self.poll_period_s > self.period_s:
            raise ValueError(f"LinkGuardConfig.poll_period_s = {self.poll_period_s!r} must be "
                             f"<= period_s = {self.period_s!r}")
        ratio = self.period_s / self.poll_period_s
        if abs(ratio - round(ratio)) > 1e-9 * ratio:
            raise ValueError(f"LinkGuardConfig.period_s = {self.period_s!r} must be a whole "
                             f"number of poll_period_s = {self.poll_period_s!r} "
                             f"(period_s/poll_period_s = {ratio!r})")
        for field in ("max_stop_ticks", "resume_match_ticks"):
            value = getattr(self, field)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
                raise ValueError(f"LinkGuardConfig.{field} = {value!r} must be an integer >= 1")

    @property
    def period_polls(self) -> int:
        """period_s in polls (a whole number, checked)."""
        return int(round(self.period_s / self.poll_period_s))

    @property
    def timeout_polls(self) -> int:
        """timeout_s in polls, rounded up: the silence counts as a timeout from this poll."""
        return max(1, math.ceil(self.timeout_s / self.poll_period_s - 1e-9))


class FdLimitRatios(NamedTuple):
    """Largest |FD quantity| / limit over a command sequence (0 where there is no limit or
    too few samples)."""

    velocity: float
    acceleration: float
    jerk: float


def fd_limits_ratio(commands, period_s: float, max_acceleration, max_jerk,
                    max_velocity=None) -> FdLimitRatios:
    """How close a command sequence comes to its FD limits.

    With Δt = ``period_s`` and p_k the rows of ``commands``:
    v_k = (p_k − p_{k−1})/Δt, a_k = (p_k − 2p_{k−1} + p_{k−2})/Δt²,
    u_k = (p_k − 3p_{k−1} + 3p_{k−2} − p_{k−3})/Δt³; the result is
    (max |v|/v_max, max |a|/a_max, max |u|/j_max) over every k and joint.

    Args:
        commands: (N, J) rad, in sending order (include the history before the part of
            interest: the first differences need the samples before it).
        period_s: Δt, s.
        max_acceleration, max_jerk: a_max, j_max, scalar or (J,).
        max_velocity: v_max, scalar or (J,), or None (ratio 0).

    Returns:
        FdLimitRatios; a value ≤ 1 means within the limit.
    """
    p = np.asarray(commands, dtype=float)
    if p.ndim != 2:
        raise ValueError(f"commands must have shape (N, J); got shape {p.shape}")
    dt = float(period_s)

    def worst(order, limit):
        if limit is None or p.shape[0] <= order:
            return 0.0
        values = np.diff(p, order, axis=0) / dt**order
        return float(np.max(np.abs(values) / np.asarray(limit, dtype=float)))

    return FdLimitRatios(worst(1, max_velocity), worst(2, max_acceleration),
                         worst(3, max_jerk))


@dataclasses.dataclass(frozen=True, eq=False)
class GuardParams:
    """Everything the guard's steps depend on besides its state (immutable).

    Attributes:
        config: The timing, sizes and tolerance.
        joint_names: The robot's joints, in command order.
        lower_rad, upper_rad: Joint limits, (J,) rad.
        initial_position_rad: Where the robot rests before the first packet, (J,) rad.
        limiter: The limits (rule ``"braking"``, Δt = period_s).
        stop: The stop parameters (the same limits, :meth:`pose_is_safe`, reversing allowed,
            the rounding tolerance).
        user_pose_check: The caller's pose predicate, or None.
    """

    config: LinkGuardConfig
    joint_names: tuple[str, ...]
    lower_rad: np.ndarray
    upper_rad: np.ndarray
    initial_position_rad: np.ndarray
    limiter: LimiterParams
    stop: StopParams
    user_pose_check: Callable[[np.ndarray], bool] | None = None

    @property
    def num_joints(self) -> int:
        return len(self.joint_names)

    def pose_is_within_limits(self, q) -> bool:
        """Finite and within [lower_rad, upper_rad] (what the receiver guarantees)."""
        q = np.asarray(q, dtype=float)
        return bool(q.shape == self.lower_rad.shape and np.all(np.isfinite(q))
                    and np.all(q >= self.lower_rad) and np.all(q <= self.upper_rad))

    def pose_is_safe(self, q) -> bool:
        """Whether the guard may command ``q`` (J,) itself: finite, within the joint limits,
        and accepted by the user's check if one was given."""
        if not self.pose_is_within_limits(q):
            return False
        return self.user_pose_check is None or bool(self.user_pose_check(
            np.asarray(q, dtype=float)))


def _check_names(joint_names) -> tuple[str, ...]:
    if isinstance(joint_names, str):
        raise ValueError(f"joint_names = {joint_names!r} must be a sequence of names, "
                         "not one string")
    try:
        names = tuple(str(name) for name in joint_names)
    except TypeError:
        raise ValueError(f"joint_names = {joint_names!r} must be a sequence of names") \
            from None
    if not names:
        raise ValueError("joint_names = () must name at least one joint")
    duplicates = sorted({name for name in names if names.count(name) > 1})
    if duplicates:
        raise ValueError(f"joint_names = {list(names)!r} repeats {duplicates!r}")
    return names


def guard_params(config: LinkGuardConfig = LinkGuardConfig(), *, joint_names, lower_rad,
                 upper_rad, initial_position_rad, max_acceleration, max_jerk,
                 max_velocity=None,
                 pose_is_safe: Callable[[np.ndarray], bool] | None = None) -> GuardParams:
    """Validates the guard's settings once.

    Args:
        config: Timeout, periods, sizes and the re-join tolerance.
        joint_names: The robot's joints, in command order (unique, at least one).
        lower_rad, upper_rad: Joint limits, rad, (J,); finite, lower < upper.
        initial_position_rad: Where the robot rests before the first packet, rad, (J,);
            within the limits.
        max_acceleration: a_max, rad/s², scalar, (J,) or {joint: value}; finite, > 0.
        max_jerk: j_max, rad/s³; finite, > 0.
        max_velocity: v_max, rad/s, or None (no velocity limit); > 0, may be inf.
        pose_is_safe: Optional callable (J,) → bool, e.g.
            :class:`~telesmooth.systems.collision_stop.PreSimulatorPoseCheck`; the joint
            limits are checked in addition.

    Raises:
        ValueError: naming the field, the value and (where relevant) the joint.
    """
    if not isinstance(config, LinkGuardConfig):
        raise ValueError(f"config = {config!r} must be a LinkGuardConfig")
    names = _check_names(joint_names)
    n = len(names)
    lower, upper = check_joint_limits(lower_rad, upper_rad, names)
    q0 = check_joint_vector("initial_position_rad", initial_position_rad, names, lower=lower,
                            upper=upper)
    for array in (lower, upper, q0):
        array.flags.writeable = False
    a_max = as_per_joint("max_acceleration", max_acceleration, n, names)
    j_max = as_per_joint("max_jerk", max_jerk, n, names)
    v_max = None if max_velocity is None else as_per_joint(
        "max_velocity", max_velocity, n, names, allow_inf=True)
    if pose_is_safe is not None and not callable(pose_is_safe):
        raise ValueError(f"pose_is_safe = {pose_is_safe!r} must be None or callable "
                         "(q) -> bool")
    limits = limiter_params(dt_s=config.period_s, max_acceleration=a_max, max_jerk=j_max,
                            max_velocity=v_max, joint_names=names, rule="braking",
                            margin=DEFAULT_MARGIN)
    params = GuardParams(config=config, joint_names=names, lower_rad=lower, upper_rad=upper,
                         initial_position_rad=q0, limiter=limits, stop=None,
                         user_pose_check=pose_is_safe)
    # Reversing joints are allowed: every braking pose is still checked, and a hold would
    # step every other joint's velocity to zero (safety.stop).
    stop = stop_params(dt_s=config.period_s, max_acceleration=a_max, max_jerk=j_max,
                       max_velocity=v_max, pose_is_safe=params.pose_is_safe,
                       joint_names=names, margin=DEFAULT_MARGIN, allow_reverse=True,
                       rounding_tolerance=STOPPABLE_ROUNDING_TOLERANCE)
    return dataclasses.replace(params, stop=stop)


class GuardInputs(NamedTuple):
    """What the guard reads at one poll.

    Attributes:
        poll: i = round(t/poll_period_s).
        accepted_count: packets the receiver accepted so far (an increase = a new packet; a
            decrease = a restarted receiver, which only re-baselines the count).
        q_accepted: the receiver's last accepted command (held), (J,) rad.
        packet_id: (seq, session) of that packet, or None when unknown (then every single
            new packet counts as consecutive).
    """

    poll: int
    accepted_count: float
    q_accepted: np.ndarray
    packet_id: tuple[float, float] | None = None


class GuardState(NamedTuple):
    """The guard between polls (immutable; :func:`guard_step` returns a new one).

    Attributes:
        mode: The current :class:`GuardMode`.
        history: The last three commands p_{k−3}, p_{k−2}, p_{k−1}, oldest first, (3, J);
            the last row is what the robot is commanded now.
        velocity, acceleration: The nominal FD state of the history, (J,) each: what the
            limiter (or the stop) that made the last command keeps, equal to the FD values of
            the floats up to rounding (recomputed from the floats after a packet that passed
            unchanged; zeros at rest). The limiter and the stop continue from it, so rounding
            never accumulates (:mod:`telesmooth.safety.limiter`, Floating point).
        command_count: Commands issued so far.
        last_command_poll: i_cmd.
        count_seen: The receiver's count at the last poll.
        count_consumed: The count when the last packet was used by a command.
        pending: A valid packet was accepted that no command has used yet.
        last_packet_poll: i_pkt, the poll of the newest valid packet.
        used_seq, used_session: (seq, session) of the packet the last command used (NaN
            before the first, after an ignored packet and after a receiver restart).
        stream: The newest valid accepted packet, (J,); ``has_stream``: whether there is one.
        targets: The packets the last two commands followed (r_{k−2}, r_{k−1}), (2, J);
            ``targets_valid``: how many of them belong to the current run of consecutive
            packets (0–2; the braking rule's target FD state uses only those).
        plan: The stop being played, (max_stop_ticks, J); ``plan_length`` rows used, the next
            is ``plan_index``; ``plan_velocity``, ``plan_acceleration``: its nominal FD state
            after each command, (max_stop_ticks, J).
        matches: Consecutive re-join commands within the tolerance.
        stop_outcome: The outcome of the last stop plan (NONE before any).
        braking_distance: Its signed braking distance per joint, (J,) rad.
        stream_distance_rad: max over joints of |p_{k−1} − stream| after this poll (0 before
            the first packet): how far the robot's command is from the accepted stream.
        limited_count: Commands that followed a packet but differ from it (the limits).
    """

    mode: GuardMode
    history: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray
    command_count: int
    last_command_poll: int
    count_seen: float
    count_consumed: float
    pending: bool
    last_packet_poll: int
    used_seq: float
    used_session: float
    stream: np.ndarray
    has_stream: bool
    targets: np.ndarray
    targets_valid: int
    plan: np.ndarray
    plan_velocity: np.ndarray
    plan_acceleration: np.ndarray
    plan_length: int
    plan_index: int
    matches: int
    stop_outcome: StopOutcome
    braking_distance: np.ndarray
    stream_distance_rad: float
    limited_count: int

    @property
    def command(self) -> np.ndarray:
        """What the robot is commanded now, p_{k−1}, (J,) rad."""
        return self.history[-1]


def guard_initial_state(params: GuardParams) -> GuardState:
    """HELD at ``initial_position_rad`` with a history at rest there; the first guard tick may
    come at once (the "last command" is one period back)."""
    q0 = np.array(params.initial_position_rad, dtype=float)
    n, config = params.num_joints, params.config
    return GuardState(
        mode=GuardMode.HELD, history=np.tile(q0, (HISTORY_LENGTH, 1)), velocity=np.zeros(n),
        acceleration=np.zeros(n), command_count=0,
        last_command_poll=-config.period_polls, count_seen=0.0, count_consumed=0.0,
        pending=False, last_packet_poll=0, used_seq=math.nan, used_session=math.nan,
        stream=q0.copy(), has_stream=False, targets=np.tile(q0, (2, 1)), targets_valid=0,
        plan=np.zeros((config.max_stop_ticks, n)),
        plan_velocity=np.zeros((config.max_stop_ticks, n)),
        plan_acceleration=np.zeros((config.max_stop_ticks, n)), plan_length=0, plan_index=0,
        matches=0,
        stop_outcome=StopOutcome.NONE, braking_distance=np.zeros(n), stream_distance_rad=0.0,
        limited_count=0)


def _consecutive(s: dict, count: float, packet_id) -> bool:
    """Whether the pending packet directly follows the packet the last command used."""
    if count - s["count_consumed"] != 1.0:
        return False
    if packet_id is None:
        return True
    seq, session = packet_id
    return session == s["used_session"] and seq == s["used_seq"] + 1.0


def _use_packet(s: dict, count: float, packet_id) -> None:
    s["pending"] = False
    s["count_consumed"] = count
    s["used_seq"], s["used_session"] = (math.nan, math.nan) if packet_id is None else (
        float(packet_id[0]), float(packet_id[1]))


def _issue(s: dict, q: np.ndarray, poll: int, velocity, acceleration) -> None:
    s["history"] = np.vstack([s["history"][1:], np.asarray(q, dtype=float)[None, :]])
    s["velocity"] = np.array(velocity, dtype=float)
    s["acceleration"] = np.array(acceleration, dtype=float)
    s["last_command_poll"] = poll
    s["command_count"] += 1


def _start_stop(params: GuardParams, s: dict) -> None:
    plan = plan_stop(params.stop, s["history"], max_ticks=params.config.max_stop_ticks,
                     velocity=s["velocity"], acceleration=s["acceleration"])
    s["stop_outcome"] = plan.outcome
    s["braking_distance"] = np.array(plan.braking_distance, dtype=float)
    s["matches"] = 0
    s["plan_index"] = 0
    s["targets_valid"] = 0
    if plan.is_stop:
        s["mode"] = GuardMode.STOPPING
        s["plan_length"] = plan.ticks_to_rest
        for field, rows in (("plan", plan.commands), ("plan_velocity", plan.velocities),
                            ("plan_acceleration", plan.accelerations)):
            stored = np.zeros_like(s[field])
            stored[:plan.ticks_to_rest] = rows
            s[field] = stored
    else:
        # The hold: keep p_{k−1} and command nothing new. From now on the robot rests there,
        # so the history is p_{k−1} three times (the step happened here).
        s["mode"] = GuardMode.HELD
        s["plan_length"] = 0
        s["history"] = np.tile(s["history"][-1], (HISTORY_LENGTH, 1))
        s["velocity"] = np.zeros_like(s["velocity"])
        s["acceleration"] = np.zeros_like(s["acceleration"])


def _stop_tick(s: dict, poll: int) -> None:
    i = s["plan_index"]
    _issue(s, s["plan"][i], poll, s["plan_velocity"][i], s["plan_acceleration"][i])
    s["plan_index"] += 1
    if s["plan_index"] >= s["plan_length"]:
        s["mode"] = GuardMode.HELD  # at rest at the plan's last command


def passes_within_limits(params: GuardParams, history, target) -> bool:
    """Whether ``target`` may be commanded unchanged after ``history`` (3, J): the FD
    velocity, acceleration and jerk of [p_{k−3}, p_{k−2}, p_{k−1}, r] within the limits, and
    the FD state it leaves inside every joint's stoppable set up to rounding (so that the
    limiter, or a stop, can always continue from it)."""
    limits = params.limiter
    h = np.vstack([history[1:], np.asarray(target, dtype=float)[None, :]])
    dt = limits.dt_s
    jerk = (h[2] - 3.0 * h[1] + 3.0 * h[0] - history[0]) / dt**3
    velocity, acceleration = fd_state(h, dt)
    if np.any(np.abs(jerk) > limits.max_jerk) or np.any(
            np.abs(acceleration) > limits.max_acceleration) or np.any(
            np.abs(velocity) > limits.max_velocity):
        return False
    gauge = (limits.facet_velocity * velocity[:, None]
             + limits.facet_acceleration * acceleration[:, None]).max(axis=1)
    return bool(np.all(gauge <= 1.0 + STOPPABLE_ROUNDING_TOLERANCE))


def _limiter_state(s: dict, targets: np.ndarray) -> LimiterState:
    """The limiter just after the commanded history, from its nominal FD state."""
    h = s["history"]
    return LimiterState(position=h[2].copy(), velocity=s["velocity"],
                        acceleration=s["acceleration"], sent=np.vstack([h[0], h]),
                        targets=targets, held=np.zeros(h.shape[1], dtype=bool), ticks=0,
                        outcome=LimiterOutcome.EXACT)


def _follow(params: GuardParams, s: dict, poll: int, count: float, r: np.ndarray,
            packet_id, consecutive: bool) -> None:
    """One command that follows the pending packet ``r`` (TRACK's rule, also re-joining)."""
    # The braking rule's target history (r_{k−2}, r_{k−1}): the packets the last two
    # commands followed when they belong to this run of consecutive packets; from HELD the
    # robot's rest (a stream that starts from rest where the robot rests is then reproduced
    # exactly); after a gap or a stop a target at rest at r.
    valid = s["targets_valid"] if consecutive else 0
    targets = s["targets"]
    if valid == 0:
        targets = s["history"][1:] if s["mode"] == GuardMode.HELD else np.vstack([r, r])
    elif valid == 1:
        targets = np.vstack([targets[1], targets[1]])
    _use_packet(s, count, packet_id)
    limiter, command = limiter_step(params.limiter, _limiter_state(s, targets), r)
    velocity, acceleration = limiter.velocity, limiter.acceleration
    if limiter.outcome != LimiterOutcome.EXACT and np.all(
            np.abs(command - r) <= PASS_ROUNDING_RAD * np.maximum(1.0, np.abs(r))) and (
            passes_within_limits(params, s["history"], r)):
        command = r.copy()    # the limiter missed the packet by rounding only
    if not np.array_equal(command, r):
        if not params.pose_is_safe(command):
            # Never issued: stop from what was commanded (checked pose by pose) or hold.
            _start_stop(params, s)
            if s["mode"] == GuardMode.STOPPING:
                _stop_tick(s, poll)
            return
        s["limited_count"] += 1
    _issue(s, command, poll, velocity, acceleration)
    s["targets"] = np.vstack([s["targets"][1], r])
    s["targets_valid"] = min(valid + 1, 2)
    if s["mode"] != GuardMode.TRACK:
        close = float(np.max(np.abs(command - r))) <= params.config.rejoin_tolerance_rad
        s["matches"] = s["matches"] + 1 if close else 0
        if s["matches"] >= params.config.resume_match_ticks:
            s["mode"], s["matches"] = GuardMode.TRACK, 0
        else:
            s["mode"] = GuardMode.RESUMING


def guard_step(params: GuardParams, state: GuardState,
               inputs: GuardInputs) -> tuple[GuardState, np.ndarray]:
    """One poll of the guard (the rules of the module docstring).

    Args:
        params: :func:`guard_params`.
        state: The state after the previous poll (:func:`guard_initial_state` at first).
        inputs: This poll's :class:`GuardInputs`.

    Returns:
        (the new state, the command the robot is driven to after this poll, (J,) rad); a new
        command was issued at this poll when ``command_count`` increased.
    """
    config = params.config
    s = state._asdict()
    poll, count = int(inputs.poll), float(inputs.accepted_count)
    r = np.array(inputs.q_accepted, dtype=float)
    packet_id = inputs.packet_id
    if count < s["count_seen"]:  # a restarted receiver: re-baseline, nothing new
        s["count_seen"] = s["count_consumed"] = count
        # q_accepted is now the new receiver's (its initial pose until its first packet):
        # nothing pending may steer toward it, and its next packet is a gap.
        s["pending"] = False
        s["used_seq"] = s["used_session"] = math.nan
    elif count > s["count_seen"]:
        s["count_seen"] = count
        if params.pose_is_within_limits(r):
            s["last_packet_poll"] = poll
            s["pending"] = True
            s["stream"], s["has_stream"] = r.copy(), True
        else:  # never commanded; as if lost (the receiver never passes one)
            s["count_consumed"] = count
            s["pending"] = False  # q_accepted no longer holds the earlier packet
            s["used_seq"] = s["used_session"] = math.nan  # the next packet follows a gap
    guard_tick = poll - s["last_command_poll"] >= config.period_polls
    if s["pending"]:
        consecutive = _consecutive(s, count, packet_id)
        following = s["mode"] in (GuardMode.TRACK, GuardMode.RESUMING)
        if (following and consecutive) or guard_tick:
            _follow(params, s, poll, count, r, packet_id, consecutive)
    else:
        silent = poll - s["last_packet_poll"] >= config.timeout_polls
        if s["mode"] in (GuardMode.TRACK, GuardMode.RESUMING) and silent:
            _start_stop(params, s)
        if s["mode"] == GuardMode.STOPPING and guard_tick:
            _stop_tick(s, poll)
    s["stream_distance_rad"] = (float(np.max(np.abs(s["history"][-1] - s["stream"])))
                                if s["has_stream"] else 0.0)
    new_state = GuardState(**s)
    return new_state, new_state.command.copy()
