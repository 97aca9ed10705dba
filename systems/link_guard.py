"""Onboard link guard: a jerk-limited ramp-down when the uplink goes silent, and a seamless
re-join when it comes back.

Sits between the :class:`~telesmooth.systems.joint_command_receiver.JointCommandReceiver`
(the last accepted 4 Hz command, held) and the robot's command interpolator. While packets
arrive it passes them through unchanged. When they stop (link loss, the ground process was
killed) the receiver alone would hold the last command, i.e. stop the robot with a velocity
step; the guard instead brings the commanded sequence to rest within the finite-difference
(FD) acceleration and jerk limits, with the collision stop planner
(:class:`~telesmooth.systems.collision_stop.CollisionStopPlanner`). When packets come back it
joins the stream again through an
:class:`~telesmooth.smoothing.online_hard.OnlineHardLimiter`, so the re-join is within the
limits too, and hands over to pass-through once the limiter reproduces the stream exactly.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from typing import NamedTuple

import numpy as np
from pydrake.systems.framework import LeafSystem

from telesmooth.smoothing.online_hard import DEFAULT_MARGIN, OnlineHardLimiter
from telesmooth.smoothing.validation import _joint_label, as_per_joint
from telesmooth.systems.collision_stop import (
    SENT_HISTORY_LENGTH,
    STOP_OUTCOMES,
    STOPPABLE_ROUNDING_TOLERANCE,
    CollisionStopPlan,
    CollisionStopPlanner,
    nudge_into_stoppable_set,
    start_limiter_moving,
)

__all__ = [
    "GUARD_MODES",
    "MODE_HELD",
    "MODE_RESUMING",
    "MODE_STOPPING",
    "MODE_TRACK",
    "STOPPABLE_ROUNDING_TOLERANCE",
    "FdLimitRatios",
    "LinkGuard",
    "LinkGuardConfig",
    "fd_limits_ratio",
    "nudge_into_stoppable_set",
]

MODE_TRACK = 0
"""Packets pass through unchanged."""
MODE_STOPPING = 1
"""The uplink is silent: the planned jerk-limited stop is being played out."""
MODE_HELD = 2
"""At rest (after a stop, a hold fallback, or before the first packet): nothing is sent."""
MODE_RESUMING = 3
"""Packets are back: the limiter leads the commands onto the stream."""

GUARD_MODES = ("track", "stopping", "held", "resuming")
"""Mode names; the ``guard_mode`` output carries the index in this tuple."""

_COMMAND_HISTORY_LENGTH = SENT_HISTORY_LENGTH  # p_{k−3}, p_{k−2}, p_{k−1}
# Layout of the bookkeeping state vector.
(_COUNT_SEEN, _COUNT_CONSUMED, _PENDING, _LAST_PACKET_POLL, _LAST_COMMAND_POLL, _PLAN_LENGTH,
 _PLAN_INDEX, _MATCHES, _COMMAND_COUNT, _USED_SEQ, _USED_SESSION) = range(11)
_BOOKKEEPING_SIZE = 11


@dataclasses.dataclass(frozen=True)
class LinkGuardConfig:
    """Settings of the link guard.

    Attributes:
        timeout_s: Silence since the last accepted packet after which the ramp-down starts, s
            (> 0). Default 0.3 s: one uplink period plus 50 ms of grace. Rounded up to whole
            polls.
        period_s: Spacing of the guard's own commands (stop and re-join), s (> 0); the uplink
            period, and the Δt of every FD limit (0.25 s at 4 Hz).
        poll_period_s: How often the inputs are examined, s (> 0, ≤ period_s, and period_s
            must be a whole number of polls so that the guard's commands are exactly
            period_s apart).
        max_stop_ticks: Most commands a stop may take (≥ 1); a longer stop falls back to the
            hold. Sizes the state that stores the plan. 400 = 100 s at 4 Hz.
        resume_match_ticks: Consecutive re-join ticks on which the limiter must output
            exactly the newest packet before pass-through resumes (≥ 1). With 3, the last
            three commands equal three consecutive packets, so the FD state of what was
            commanded is the stream's own.
    """

    timeout_s: float = 0.3
    period_s: float = 0.25
    poll_period_s: float = 0.01
    max_stop_ticks: int = 400
    resume_match_ticks: int = 3

    def __post_init__(self) -> None:
        for field in ("timeout_s", "period_s", "poll_period_s"):
            value = getattr(self, field)
            if isinstance(value, bool) or not isinstance(value, (int, float, np.integer,
                                                                 np.floating)):
                raise ValueError(f"LinkGuardConfig.{field} = {value!r} must be a number of "
                                 "seconds")
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f"LinkGuardConfig.{field} = {value!r} must be finite and > 0")
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


@dataclasses.dataclass
class _GuardState:
    """The guard's Context state, unpacked for one poll (see LinkGuard's docstring)."""

    q: np.ndarray                 # (J,) the last commanded pose p_{k−1}
    older: np.ndarray             # (2, J) p_{k−3}, p_{k−2}
    mode: int
    braking_distance: np.ndarray  # (J,)
    outcome: int
    count_seen: float
    count_consumed: float
    pending: bool
    last_packet_poll: int
    last_command_poll: int
    plan: np.ndarray              # (max_stop_ticks, J)
    plan_length: int
    plan_index: int
    matches: int
    command_count: int
    limiter: np.ndarray           # OnlineHardLimiter state vector
    used_seq: float               # (seq, session) of the packet the last command used
    used_session: float           # (NaN: none, or a packet that was ignored)

    @property
    def history(self) -> np.ndarray:
        """The last three commanded poses, oldest first, (3, J)."""
        return np.vstack([self.older, self.q[None, :]])


class LinkGuard(LeafSystem):
    r"""Pass-through of the accepted uplink commands, with a jerk-limited ramp-down when the
    uplink goes silent and a limited re-join when it comes back.

    .. pydrake_system::

        name: LinkGuard
        input_ports:
        - q_accepted
        - accepted_count
        - command_seq (optional)
        - command_session (optional)
        output_ports:
        - q_commanded
        - guard_mode
        - braking_distance
        - stop_outcome
        - command_count

    Ports (J = number of joints):

    - ``q_accepted``: the receiver's last accepted command (held), rad, (J,)
      (``JointCommandReceiver.q_commanded``). Read only when ``accepted_count`` increases.
    - ``accepted_count``: packets accepted so far, (1,) (``JointCommandReceiver.accepted_count``;
      0 before the first). Any increase means "a new command was accepted"; a decrease (a
      restarted receiver) only re-baselines the count.
    - ``command_seq``, ``command_session``: optional, (1,) each: the sequence number and
      session of the packet on ``q_accepted`` (``JointCommandReceiver.last_command_seq`` and
      ``last_command_session``). When connected, a packet is *consecutive* only if it is the
      next seq of the same session as the packet the last command used; unconnected, every
      single new packet counts as consecutive (the count alone cannot see a packet the link
      lost or reordered before the receiver).
    - ``q_commanded``: the command for the robot, rad, (J,).
    - ``guard_mode``: (1,), the index in :data:`GUARD_MODES`: 0 track, 1 stopping, 2 held,
      3 resuming.
    - ``braking_distance``: per joint, the signed braking distance of the last stop plan
      (``CollisionStopPlan.braking_distance``: every stop command lies between the pose the
      stop started from, q_last, and q_last + braking_distance), rad, (J,); zeros before the
      first plan and after a hold fallback.
    - ``stop_outcome``: (1,), the index in
      :data:`~telesmooth.systems.collision_stop.STOP_OUTCOMES` of the last stop plan (0
      ``"none"`` before any, 1 ``"stop"``, 3…6 the hold fallbacks).
    - ``command_count``: (1,), the number of commands the guard has issued (pass-through and
      its own); it increases by one at each poll that issues one. ``q_commanded`` sampled
      where it increases is the command *sequence* whose FD values the limits are about
      (a held pose is not re-issued: at rest it repeats implicitly).

    All outputs are state outputs (no direct feedthrough): at a poll they show the state
    *before* that poll's update (Drake's x⁻), i.e. a command issued at poll i appears on the
    outputs from t_i⁺ on.

    **Timing.** One periodic discrete update every ``poll_period_s`` (offset 0), and all
    times are counted in polls i = round(t/poll_period_s): P = period_s/poll_period_s
    (whole), T = ⌈timeout_s/poll_period_s⌉. In a diagram with the receiver (an unrestricted
    update on the same poll grid) the guard sees a packet in the same poll in which the
    receiver accepts it (Drake runs unrestricted updates before discrete ones). Let i_pkt be
    the poll of the last accepted packet, i_cmd that of the last command the guard issued,
    and "pending" mean a packet was accepted that no command has used yet. The guard's own
    commands (stop and re-join) are issued only at polls with i − i_cmd ≥ P, so they are at
    least period_s apart in time as well as one Δt apart in the FD sequence; in the normal
    case they are exactly P polls apart. Pass-through keeps the stream's own timing.
    Re-join steps are driven by packets (one step per guard tick that has a pending
    packet, never a step without one) rather than by a free-running timer: a timer tick
    lands before or after a jittered packet by chance (and then uses a stale target and
    never matches), and a burst of late packets cannot make the guard's commands come
    faster than one per period_s. A packet that is missing for T polls is a timeout, as in
    TRACK.

    **Rules per poll** (p_{k−3}, p_{k−2}, p_{k−1} = the last three commanded poses,
    r = ``q_accepted``):

    - TRACK: a pending packet that is *consecutive* (exactly one packet accepted since the
      packet the last command used and, with ``command_seq`` connected, the next seq of the
      same session) is commanded unchanged, p_k = r, at once. A pending packet after a gap
      (a packet lost or held back by the link while the rest arrive in time, two packets
      accepted in one poll, a new session) is not: passing it through would skip a sample
      of the stream, a step in acceleration and jerk. It is joined like a re-join from
      STOPPING (below) at the next guard tick. Else, if i − i_pkt ≥ T: a stop is planned
      (below).
    - Planning a stop: plan = CollisionStopPlanner(Δt = period_s, the limits,
      ``pose_is_safe``, allow_reverse = True, rounding_tolerance =
      STOPPABLE_ROUNDING_TOLERANCE).plan([p_{k−3}, p_{k−2}, p_{k−1}], max_ticks =
      max_stop_ticks); the planner first applies :func:`nudge_into_stoppable_set`, which
      changes nothing for a history strictly inside the stoppable set. ``stop_outcome`` and ``braking_distance`` report it. If
      ``plan.is_stop``: STOPPING, and plan.commands[0], [1], … are issued one per guard tick
      (the first at once when i − i_cmd ≥ P, as after a timeout ≥ period_s); after the last
      one (the rest pose; with the history, the last three commands are equal) → HELD.
      Otherwise (the FD state of what was commanded is not stoppable — e.g. the ground's
      own stream broke the limits —, a braking pose is rejected, the stop would reverse, or
      it is too long): HELD at p_{k−1} at once, the paper's hold; nothing new is commanded,
      and the history becomes p_{k−1} three times (the robot rests there from now on).
    - STOPPING, HELD or RESUMING with a pending packet, at a guard tick (i − i_cmd ≥ P):
      one re-join tick. The limiter (rule "braking", the same limits, Δt = period_s) is
      started, from HELD, at rest at p_{k−1} (``reset``); from STOPPING or TRACK, moving with the FD
      state of [p_{k−3}, p_{k−2}, p_{k−1}] and target history r, r; in RESUMING it continues
      from its state in the Context. Then p_k = limiter.step(r) (the newest packet, which
      the tick consumes). Mode RESUMING; m ← m + 1 if p_k = r exactly (bit for bit) and
      r is consecutive to the packet the previous command used (as in TRACK), else
      m ← 0; when m = ``resume_match_ticks`` → TRACK. Then the last three commands are
      three consecutive packets, so the FD state of what was commanded is the stream's own
      and pass-through adds no step. (The limiter reproduces a stream that is itself within
      the margin-shrunk limits exactly once its state is the stream's.) From HELD the first
      step is normally at once; from STOPPING it takes the place of the next stop command.
    - RESUMING without a pending packet: if i − i_pkt ≥ T, a stop is planned from the last
      three commands (→ STOPPING or HELD as above).
    - Any command the guard makes itself (stop or re-join) must pass ``pose_is_safe``; the
      planner checks every stop pose (``"hold-pose-rejected"``). A rejected re-join command
      is never issued: a stop is planned from the last three commands instead (itself
      checked pose by pose, so when it is rejected too the guard holds at p_{k−1}), and
      the packet counts as used.

    Before the first packet the guard is HELD at ``initial_position_rad`` with a history
    at rest there: silence does nothing, and the first packet is joined through RESUMING,
    which reproduces a stream that starts from rest at that pose exactly (so such a stream
    passes through bit for bit from its first packet) and limits one that does not. A
    packet whose ``q_accepted`` is not finite or outside [lower_rad, upper_rad] (the receiver
    never passes one) is ignored as if lost.

    **Guarantees** (FD values of the command sequence, Δt = period_s, ≤ limit·(1 + ~1e-10)):
    the stop (from a history inside the stoppable set), the re-join and the hand-over back to
    TRACK obey |a| ≤ a_max, |u| ≤ j_max (and |v| ≤ v_max when given), history included; the
    stop comes to rest and never leaves [q_last, q_last + braking_distance] per joint. The
    exceptions are the hold fallbacks (a velocity step, reported in ``stop_outcome``) and
    what the ground itself sends in TRACK. Note that on a stream within the limits the
    planner still refuses a stop when *one* joint would move back behind q_last
    (``"hold-reverses"``), which happens when that joint is just finishing an approach
    (|v| ~ 1e-4 rad/s, braking) as the link goes silent: then the other joints stop with the
    hold's velocity step.

    **State** (all in the Context; the limiter on ``self`` is scratch, fully overwritten
    from the Context at every use, and the planner keeps no state): discrete groups
    ``q_commanded`` (J), ``guard_mode`` (1), ``braking_distance`` (J), ``stop_outcome`` (1),
    ``command_count`` (1), the two commands before the last (2J, oldest first), the bookkeeping
    [count seen, count used by the last command, pending, i_pkt, i_cmd, plan length N, next
    plan index, m, command count, seq and session of the packet the last command used (NaN
    before the first packet, after an ignored packet and after a receiver restart: the next
    packet is then not consecutive)], the plan (max_stop_ticks·J, the first N rows used) and
    the limiter's state vector (``OnlineHardLimiter.get_state_vector``, 10J + 1).

    With ``command_seq`` connected the first packet is never consecutive (there is no packet
    before it), so the hand-over to TRACK takes one re-join tick more than without.
    """

    modes = GUARD_MODES
    MODE_TRACK = MODE_TRACK
    MODE_STOPPING = MODE_STOPPING
    MODE_HELD = MODE_HELD
    MODE_RESUMING = MODE_RESUMING

    def __init__(self, config: LinkGuardConfig = LinkGuardConfig(), *, joint_names, lower_rad,
                 upper_rad, initial_position_rad, max_acceleration, max_jerk,
                 max_velocity=None,
                 pose_is_safe: Callable[[np.ndarray], bool] | None = None):
        """Validates, then declares ports, state and the poll.

        Args:
            config: Timeout, periods and sizes.
            joint_names: The robot's joints, in command order (unique, at least one).
            lower_rad, upper_rad: Joint limits, rad, (J,); finite, lower < upper.
            initial_position_rad: Where the robot rests before the first packet, rad, (J,);
                within the limits.
            max_acceleration: a_max, rad/s², scalar, (J,) or {joint: value}; finite, > 0.
            max_jerk: j_max, rad/s³; finite, > 0.
            max_velocity: v_max, rad/s, or None (no velocity limit); > 0, may be inf.
            pose_is_safe: Optional callable (J,) → bool, e.g.
                :class:`~telesmooth.systems.collision_stop.PreSimulatorPoseCheck`; the joint
                limits are checked in addition. Default: finite and within the limits.

        Raises:
            ValueError: naming the field, the value and (where relevant) the joint.
        """
        super().__init__()
        if not isinstance(config, LinkGuardConfig):
            raise ValueError(f"config = {config!r} must be a LinkGuardConfig")
        self._config = config
        names = self._check_names(joint_names)
        n = len(names)
        self._joint_names = names
        self._lower = self._joint_vector("lower_rad", lower_rad, n)
        self._upper = self._joint_vector("upper_rad", upper_rad, n)
        for i in range(n):
            if not self._lower[i] < self._upper[i]:
                raise ValueError(
                    f"lower_rad[{i}] = {float(self._lower[i])!r} must be < upper_rad[{i}] = "
                    f"{float(self._upper[i])!r} for {_joint_label(i, names)}")
        q0 = self._joint_vector("initial_position_rad", initial_position_rad, n)
        for i in range(n):
            if not self._lower[i] <= q0[i] <= self._upper[i]:
                raise ValueError(
                    f"initial_position_rad[{i}] = {float(q0[i])!r} for {_joint_label(i, names)} "
                    f"must be within [{float(self._lower[i])!r}, {float(self._upper[i])!r}]")
        self.max_acceleration = as_per_joint("max_acceleration", max_acceleration, n, names)
        self.max_jerk = as_per_joint("max_jerk", max_jerk, n, names)
        self.max_velocity = None if max_velocity is None else as_per_joint(
            "max_velocity", max_velocity, n, names, allow_inf=True)
        if pose_is_safe is not None and not callable(pose_is_safe):
            raise ValueError(f"pose_is_safe = {pose_is_safe!r} must be None or callable "
                             "(q) -> bool")
        self._user_pose_check = pose_is_safe

        # Scratch objects (their state is loaded from the Context at every use).
        limits = dict(dt_s=config.period_s, max_acceleration=self.max_acceleration,
                      max_jerk=self.max_jerk, max_velocity=self.max_velocity,
                      joint_names=names)
        self._limiter = OnlineHardLimiter(q_start=q0, rule="braking", margin=DEFAULT_MARGIN,
                                          **limits)
        # Reversing joints are allowed: every braking pose is still checked, and a hold
        # would step every other joint's velocity to zero (collision_stop docstring).
        self._planner = CollisionStopPlanner(
            pose_is_safe=self.pose_is_safe, margin=DEFAULT_MARGIN, allow_reverse=True,
            rounding_tolerance=STOPPABLE_ROUNDING_TOLERANCE, **limits)

        self._q_accepted_input = self.DeclareVectorInputPort("q_accepted", n)
        self._accepted_count_input = self.DeclareVectorInputPort("accepted_count", 1)
        self._command_seq_input = self.DeclareVectorInputPort("command_seq", 1)
        self._command_session_input = self.DeclareVectorInputPort("command_session", 1)

        self._q_state = self.DeclareDiscreteState(q0)
        self._mode_state = self.DeclareDiscreteState([float(MODE_HELD)])
        self._braking_state = self.DeclareDiscreteState(np.zeros(n))
        self._outcome_state = self.DeclareDiscreteState([0.0])
        self._command_count_state = self.DeclareDiscreteState([0.0])
        self._older_state = self.DeclareDiscreteState(np.tile(q0, _COMMAND_HISTORY_LENGTH - 1))
        bookkeeping = np.zeros(_BOOKKEEPING_SIZE)
        # The first re-join tick may come at once: the "last command" is one period back.
        bookkeeping[_LAST_COMMAND_POLL] = -config.period_polls
        bookkeeping[[_USED_SEQ, _USED_SESSION]] = math.nan  # no packet used yet
        self._bookkeeping_state = self.DeclareDiscreteState(bookkeeping)
        self._plan_state = self.DeclareDiscreteState(np.zeros(config.max_stop_ticks * n))
        self._limiter_state = self.DeclareDiscreteState(self._limiter.get_state_vector())

        self.DeclarePeriodicDiscreteUpdateEvent(config.poll_period_s, 0.0, self._update_guard)
        self.DeclareForcedDiscreteUpdateEvent(self._update_guard)

        self._q_commanded_output = self.DeclareStateOutputPort("q_commanded", self._q_state)
        self._guard_mode_output = self.DeclareStateOutputPort("guard_mode", self._mode_state)
        self._braking_distance_output = self.DeclareStateOutputPort(
            "braking_distance", self._braking_state)
        self._stop_outcome_output = self.DeclareStateOutputPort(
            "stop_outcome", self._outcome_state)
        self._command_count_output = self.DeclareStateOutputPort(
            "command_count", self._command_count_state)

    # -- validation -----------------------------------------------------------------------

    @staticmethod
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

    def _joint_vector(self, field: str, value, n: int) -> np.ndarray:
        try:
            array = np.array(value, dtype=float)
        except (TypeError, ValueError):
            raise ValueError(f"{field} = {value!r} must be {n} numbers") from None
        if array.shape != (n,):
            raise ValueError(f"{field} = {np.ravel(array).tolist()!r} must have {n} values "
                             f"(one per joint of {list(self._joint_names)!r})")
        for i, entry in enumerate(array):
            if not math.isfinite(entry):
                raise ValueError(f"{field}[{i}] = {float(entry)!r} for "
                                 f"{_joint_label(i, self._joint_names)} must be finite")
        return array

    # -- accessors ------------------------------------------------------------------------

    @property
    def config(self) -> LinkGuardConfig:
        return self._config

    @property
    def joint_names(self) -> tuple[str, ...]:
        return self._joint_names

    @property
    def lower_rad(self) -> np.ndarray:
        return self._lower.copy()

    @property
    def upper_rad(self) -> np.ndarray:
        return self._upper.copy()

    def pose_is_safe(self, q) -> bool:
        """Whether the guard may command ``q`` (J,): finite, within [lower_rad, upper_rad],
        and accepted by the user's ``pose_is_safe`` if one was given."""
        q = np.asarray(q, dtype=float)
        if q.shape != self._lower.shape or not np.all(np.isfinite(q)):
            return False
        if np.any(q < self._lower) or np.any(q > self._upper):
            return False
        return self._user_pose_check is None or bool(self._user_pose_check(q))

    def get_q_accepted_input_port(self):
        return self._q_accepted_input

    def get_accepted_count_input_port(self):
        return self._accepted_count_input

    def get_command_seq_input_port(self):
        return self._command_seq_input

    def get_command_session_input_port(self):
        return self._command_session_input

    def get_q_commanded_output_port(self):
        return self._q_commanded_output

    def get_guard_mode_output_port(self):
        return self._guard_mode_output

    def get_braking_distance_output_port(self):
        return self._braking_distance_output

    def get_stop_outcome_output_port(self):
        return self._stop_outcome_output

    def get_command_count_output_port(self):
        return self._command_count_output

    # -- the poll -------------------------------------------------------------------------

    def _update_guard(self, context, discrete_state):
        state = self._unpack(context)
        poll = int(round(context.get_time() / self._config.poll_period_s))
        count = float(self._accepted_count_input.Eval(context)[0])
        q_accepted = np.array(self._q_accepted_input.Eval(context), dtype=float)
        identity = None
        if self._command_seq_input.HasValue(context):
            session = (float(self._command_session_input.Eval(context)[0])
                       if self._command_session_input.HasValue(context) else 0.0)
            identity = (float(self._command_seq_input.Eval(context)[0]), session)
        self._poll(state, poll, count, q_accepted, identity)
        self._pack(state, discrete_state)

    def _unpack(self, context) -> _GuardState:
        def get(index):
            return context.get_discrete_state(index).get_value()

        n = len(self._joint_names)
        book = get(self._bookkeeping_state)
        return _GuardState(
            q=get(self._q_state).copy(),
            older=get(self._older_state).reshape(_COMMAND_HISTORY_LENGTH - 1, n).copy(),
            mode=int(get(self._mode_state)[0]),
            braking_distance=get(self._braking_state).copy(),
            outcome=int(get(self._outcome_state)[0]),
            count_seen=float(book[_COUNT_SEEN]),
            count_consumed=float(book[_COUNT_CONSUMED]),
            pending=bool(book[_PENDING] > 0.5),
            last_packet_poll=int(book[_LAST_PACKET_POLL]),
            last_command_poll=int(book[_LAST_COMMAND_POLL]),
            plan=get(self._plan_state).reshape(self._config.max_stop_ticks, n).copy(),
            plan_length=int(book[_PLAN_LENGTH]),
            plan_index=int(book[_PLAN_INDEX]),
            matches=int(book[_MATCHES]),
            command_count=int(book[_COMMAND_COUNT]),
            limiter=get(self._limiter_state).copy(),
            used_seq=float(book[_USED_SEQ]),
            used_session=float(book[_USED_SESSION]),
        )

    def _pack(self, s: _GuardState, discrete_state) -> None:
        def put(index, value):
            discrete_state.get_mutable_vector(index).SetFromVector(np.ravel(value))

        book = np.zeros(_BOOKKEEPING_SIZE)
        book[[_COUNT_SEEN, _COUNT_CONSUMED, _PENDING, _LAST_PACKET_POLL, _LAST_COMMAND_POLL,
              _PLAN_LENGTH, _PLAN_INDEX, _MATCHES, _COMMAND_COUNT, _USED_SEQ,
              _USED_SESSION]] = [
            s.count_seen, s.count_consumed, float(s.pending), s.last_packet_poll,
            s.last_command_poll, s.plan_length, s.plan_index, s.matches, s.command_count,
            s.used_seq, s.used_session]
        put(self._q_state, s.q)
        put(self._older_state, s.older)
        put(self._mode_state, [float(s.mode)])
        put(self._braking_state, s.braking_distance)
        put(self._outcome_state, [float(s.outcome)])
        put(self._command_count_state, [float(s.command_count)])
        put(self._bookkeeping_state, book)
        put(self._plan_state, s.plan)
        put(self._limiter_state, s.limiter)

    def _poll(self, s: _GuardState, poll: int, count: float, q_accepted: np.ndarray,
              identity: tuple[float, float] | None = None) -> None:
        """One poll (the rules of the class docstring), on the unpacked state ``s``;
        ``identity`` is the (seq, session) of ``q_accepted``'s packet, or None (unknown)."""
        if count < s.count_seen:  # a restarted receiver: re-baseline, nothing new
            s.count_seen = s.count_consumed = count
            # q_accepted is now the new receiver's (its initial pose until its first
            # packet): nothing pending may steer toward it, and its next packet is a gap.
            s.pending = False
            s.used_seq = s.used_session = math.nan
        elif count > s.count_seen:
            s.count_seen = count
            if self.pose_is_within_limits(q_accepted):
                s.last_packet_poll = poll
                s.pending = True
            else:  # never commanded; as if lost (the receiver never passes one)
                s.count_consumed = count
                s.pending = False  # q_accepted no longer holds the earlier packet
                s.used_seq = s.used_session = math.nan  # the next packet follows a gap
        if s.mode == MODE_TRACK and s.pending and self._consecutive(s, count, identity):
            self._use_packet(s, count, identity)
            self._issue(s, q_accepted, poll)
            return
        silent = poll - s.last_packet_poll >= self._config.timeout_polls
        if s.mode in (MODE_TRACK, MODE_RESUMING) and not s.pending and silent:
            self._start_stop(s)
        if poll - s.last_command_poll < self._config.period_polls:
            return  # not a guard tick
        if s.pending:  # in TRACK only after a gap
            self._rejoin_tick(s, poll, count, q_accepted, identity)
        elif s.mode == MODE_STOPPING:
            self._stop_tick(s, poll)

    @staticmethod
    def _consecutive(s: _GuardState, count: float,
                     identity: tuple[float, float] | None) -> bool:
        """Whether the pending packet directly follows the packet the last command used."""
        if count - s.count_consumed != 1.0:
            return False
        if identity is None:
            return True
        seq, session = identity
        return session == s.used_session and seq == s.used_seq + 1.0

    @staticmethod
    def _use_packet(s: _GuardState, count: float,
                    identity: tuple[float, float] | None) -> None:
        """The pending packet is consumed by the command being made."""
        s.pending = False
        s.count_consumed = count
        s.used_seq, s.used_session = (math.nan, math.nan) if identity is None else identity

    def pose_is_within_limits(self, q) -> bool:
        """Finite and within [lower_rad, upper_rad] (what the receiver guarantees)."""
        q = np.asarray(q, dtype=float)
        return bool(q.shape == self._lower.shape and np.all(np.isfinite(q))
                    and np.all(q >= self._lower) and np.all(q <= self._upper))

    @staticmethod
    def _issue(s: _GuardState, q: np.ndarray, poll: int) -> None:
        """Commands ``q`` at ``poll``: p_k = q, history shifted."""
        s.older = np.vstack([s.older[1:], s.q[None, :]])
        s.q = np.array(q, dtype=float)
        s.last_command_poll = poll
        s.command_count += 1

    def plan_stop(self, command_history) -> CollisionStopPlan:
        """The stop the guard plans from the last three commanded poses (3, J), oldest first:
        the planner, which first nudges a history that only rounding puts outside the
        stoppable set (its ``rounding_tolerance``, :func:`nudge_into_stoppable_set`)."""
        return self._planner.plan(command_history, max_ticks=self._config.max_stop_ticks)

    def _start_stop(self, s: _GuardState) -> None:
        plan = self.plan_stop(s.history)
        s.outcome = STOP_OUTCOMES.index(plan.outcome)
        s.braking_distance = np.array(plan.braking_distance, dtype=float)
        s.matches = 0
        s.plan_index = 0
        if plan.is_stop:
            s.mode = MODE_STOPPING
            s.plan_length = plan.ticks_to_rest
            s.plan[:] = 0.0
            s.plan[:s.plan_length] = plan.commands
        else:
            # The hold: keep p_{k−1} and command nothing new. From now on the robot rests
            # there, so the history is p_{k−1} three times (the step happened here).
            s.mode = MODE_HELD
            s.plan_length = 0
            s.older = np.tile(s.q, (_COMMAND_HISTORY_LENGTH - 1, 1))

    def _stop_tick(self, s: _GuardState, poll: int) -> None:
        self._issue(s, s.plan[s.plan_index], poll)
        s.plan_index += 1
        if s.plan_index >= s.plan_length:
            s.mode = MODE_HELD  # at rest at the plan's last command

    def _rejoin_tick(self, s: _GuardState, poll: int, count: float, q_accepted: np.ndarray,
                     identity: tuple[float, float] | None = None) -> None:
        limiter = self._limiter
        if s.mode == MODE_HELD:
            limiter.reset(s.q)
        elif s.mode in (MODE_STOPPING, MODE_TRACK):
            start_limiter_moving(limiter, s.history, q_accepted)
        else:
            limiter.set_state_vector(s.limiter)
        command = limiter.step(q_accepted)
        consecutive = self._consecutive(s, count, identity)
        self._use_packet(s, count, identity)
        if not self.pose_is_safe(command):
            # Never issued: stop from what was commanded (checked pose by pose) or hold.
            self._start_stop(s)
            if s.mode == MODE_STOPPING:
                self._stop_tick(s, poll)
            return
        self._issue(s, command, poll)
        s.limiter = limiter.get_state_vector()
        exact = consecutive and np.array_equal(command, q_accepted)
        s.matches = s.matches + 1 if exact else 0
        if s.matches >= self._config.resume_match_ticks:
            s.mode = MODE_TRACK
            s.matches = 0
        else:
            s.mode = MODE_RESUMING
