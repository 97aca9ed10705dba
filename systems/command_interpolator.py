"""The onboard motor-side servo set-point: turns the held 4 Hz commands into a desired state.

The uplink delivers one joint-position command per period (0.25 s) and holds it. Feeding
that staircase straight into the plant's PD would step the motors four times a second and
ring the flexible links; this block instead ramps the desired motor position from where it
is to each new command over one uplink period (or steps, ``interpolation="zoh"``), and
emits ``[q_d; v_d]`` for ``MultibodyPlant.get_desired_state_input_port``. It is also the
onboard gatekeeper: a command that is not finite or is outside the joint limits never
reaches the plant; the robot keeps its current target (holds) and a flag is raised.

The numerics are the two pure functions :func:`ramp_desired_state` and
:func:`command_violation` (numpy only, tested without a simulator).
"""

from __future__ import annotations

import dataclasses
import logging
import math

import numpy as np
from pydrake.systems.framework import LeafSystem

from telesmooth.systems.timing import check_period

__all__ = [
    "CommandInterpolator",
    "CommandInterpolatorConfig",
    "INTERPOLATIONS",
    "command_violation",
    "ramp_desired_state",
]

INTERPOLATIONS = ("linear", "zoh")
"""The interpolation options of :class:`CommandInterpolatorConfig`."""

_logger = logging.getLogger(__name__)


@dataclasses.dataclass(frozen=True)
class CommandInterpolatorConfig:
    """Settings of the command interpolator.

    Attributes:
        interpolation: ``"linear"`` (default): ramp from the current desired position to each
            new command over ``ramp_duration_s`` with the matching constant desired velocity,
            then hold. ``"zoh"``: step to each new command with zero desired velocity.
        ramp_duration_s: Duration of a linear ramp, s (> 0); one uplink period (0.25 s) by
            default, so that a steady 4 Hz stream gives a continuous, piecewise-linear
            desired position. Unused by ``"zoh"``.
        poll_period_s: How often the held command is read, s (> 0); a new command is
            detected at the first poll at which it differs from the current target, i.e.
            at most one poll period late. 1 ms = the plant step.
    """

    interpolation: str = "linear"
    ramp_duration_s: float = 0.25
    poll_period_s: float = 0.001

    def __post_init__(self) -> None:
        if self.interpolation not in INTERPOLATIONS:
            raise ValueError(
                f"CommandInterpolatorConfig.interpolation = {self.interpolation!r} must be "
                f"one of {INTERPOLATIONS}"
            )
        check_period("CommandInterpolatorConfig.ramp_duration_s", self.ramp_duration_s)
        check_period("CommandInterpolatorConfig.poll_period_s", self.poll_period_s)


def ramp_desired_state(
    ramp_start_rad: np.ndarray,
    ramp_target_rad: np.ndarray,
    ramp_start_time_s: float,
    ramp_duration_s: float,
    time_s: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Desired position and velocity on a linear ramp at ``time_s``.

    With q₀ = ``ramp_start_rad``, q₁ = ``ramp_target_rad``, t₀ = ``ramp_start_time_s``,
    T = ``ramp_duration_s`` and s = clip((t − t₀)/T, 0, 1):

        q_d(t) = q₀ + s·(q₁ − q₀)
        v_d(t) = (q₁ − q₀)/T   if t₀ ≤ t < t₀ + T,   else 0.

    A step (``"zoh"``) is the degenerate ramp q₀ = q₁.

    Args:
        ramp_start_rad: q₀, rad; shape (n,).
        ramp_target_rad: q₁, rad; shape (n,).
        ramp_start_time_s: t₀, s.
        ramp_duration_s: T, s (> 0).
        time_s: t, s.

    Returns:
        (q_d, v_d): rad and rad/s, each shape (n,).
    """
    start = np.asarray(ramp_start_rad, dtype=float)
    target = np.asarray(ramp_target_rad, dtype=float)
    elapsed = time_s - ramp_start_time_s
    if elapsed < 0.0 or elapsed >= ramp_duration_s:
        velocity = np.zeros_like(target)
    else:
        velocity = (target - start) / ramp_duration_s
    fraction = min(max(elapsed / ramp_duration_s, 0.0), 1.0)
    # At s = 1 return the target itself, not q₀ + (q₁ − q₀), which can differ in the last bit.
    position = target.copy() if fraction >= 1.0 else start + fraction * (target - start)
    return position, velocity


def command_violation(
    q_rad: np.ndarray, lower_rad: np.ndarray, upper_rad: np.ndarray, joint_names
) -> str | None:
    """Why a joint command is unsafe, or None if it is finite and within the joint limits.

    Args:
        q_rad: The command, rad; shape (n,).
        lower_rad, upper_rad: Joint limits, rad; shape (n,). A command exactly on a limit
            is accepted.
        joint_names: Joint names, used in the message; length n.

    Returns:
        None, or a message naming the first offending joint and its value, e.g.
        ``"q_commanded[1] (elbow) = nan is not finite"``.
    """
    q = np.asarray(q_rad, dtype=float)
    if q.shape != np.shape(lower_rad):
        return f"q_commanded has shape {q.shape}, expected {np.shape(lower_rad)}"
    for index, (value, lower, upper) in enumerate(zip(q, lower_rad, upper_rad)):
        label = f"q_commanded[{index}] ({joint_names[index]}) = {float(value)!r}"
        if not math.isfinite(value):
            return f"{label} is not finite"
        if not lower <= value <= upper:
            return f"{label} is outside the joint limits [{float(lower)!r}, {float(upper)!r}]"
    return None


def _validated_vector(field: str, values, size: int) -> np.ndarray:
    """``values`` as a finite float vector of length ``size``, or ValueError naming ``field``."""
    try:
        vector = np.asarray(values, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"{field} = {values!r} must be {size} numbers") from None
    if vector.shape != (size,):
        raise ValueError(f"{field} = {values!r} must have {size} values, got shape {vector.shape}")
    for index, value in enumerate(vector):
        if not math.isfinite(value):
            raise ValueError(f"{field}[{index}] = {float(value)!r} must be finite")
    return vector


class CommandInterpolator(LeafSystem):
    r"""Motor-side set-point generator and command gate: held 4 Hz commands → [q_d; v_d].

    .. pydrake_system::

        name: CommandInterpolator
        input_ports:
        - q_commanded
        - command_time (optional)
        output_ports:
        - state_desired
        - command_rejected

    Ports (n = number of joints, joint order = ``joint_names``):

    - ``q_commanded``: the held joint-position command (e.g. the uplink's zero-order hold),
      rad, shape (n,). Must be connected.
    - ``command_time``: optional; the instant the held command was issued upstream (the
      uplink's ``send_time``), s, shape (1,). A discrete update cannot see another system's
      update of the same instant (Drake runs them simultaneously), so a command sent at t
      is seen by the poll after t; with this input the ramp starts at t all the same, as if
      the poll had run at t (a poll sees its value only together with the command).
    - ``state_desired``: [q_d; v_d], desired motor positions (rad) and velocities (rad/s),
      shape (2n,), in joint order (map it to actuator order before the plant's
      desired-state input). No direct feedthrough: computed from the state and the
      context time, so it is continuous in time between polls.
    - ``command_rejected``: 1.0 while the last received command was rejected, else 0.0,
      shape (1,).

    State (discrete, updated every ``poll_period_s`` at t_k = k·poll_period_s, offset 0):
    ramp start q₀ (n), ramp target q₁ (n), ramp start time t₀ (1), [rejected flag,
    rejected-command count] (2), and the last rejected command (n; to count a held invalid
    command once).

    Poll at t_k, with u = q_commanded(t_k):

    - u == q₁ (bit-for-bit): nothing new; the flag is cleared (the last command received is
      this valid one).
    - u is the command already rejected (NaN compares equal here) while the flag is up:
      nothing (it is counted once).
    - u not finite, or outside [lower_rad, upper_rad] for some joint: **rejected**; the
      target q₁ is kept, i.e. the ramp in progress (already validated) finishes and the
      robot then holds; flag ← 1, count += 1, and a warning naming the joint and value is
      logged (see :func:`command_violation`).
    - otherwise a new command, starting at s = ``command_time`` if that is connected,
      finite and within [t₀, t_k] (the command's own instant), else s = t_k:
      ``"linear"``: q₀ ← q_d(s) (on the ramp in progress), q₁ ← u, t₀ ← s;
      ``"zoh"``: q₀ ← u, q₁ ← u, t₀ ← s; flag ← 0. Starting at s < t_k moves q_d at t_k by
      (t_k − s)·(v_new − v_old), one poll period's worth of the velocity change.

    Output at any time t (:func:`ramp_desired_state`), T = ``ramp_duration_s``,
    s = clip((t + lead − t₀)/T, 0, 1) (lead = the constructor's ``lead_s``, 0 by default):

        q_d(t) = q₀ + s·(q₁ − q₀)
        v_d(t) = (q₁ − q₀)/T  for t₀ ≤ t + lead < t₀ + T,  else 0

    so a new command issued at t₀ is reached at t₀ + T; a command arriving mid-ramp
    starts a new ramp from the current q_d (the position is continuous, the velocity
    jumps). With a steady 4 Hz stream and T = 0.25 s, q_d is the piecewise-linear
    interpolation of the commands delayed by one uplink period (exactly, with
    ``command_time``; else plus at most one poll period: a command that changes at t is
    seen at the first poll after t, or at t itself if the upstream value has already
    changed when the poll runs).

    Before the first command (and at t = 0): q₀ = q₁ = ``initial_position_rad``, t₀ = 0,
    so the output is [initial_position_rad; 0] and the robot holds. A held input equal to
    that position is not a command. **The upstream hold must start at the robot's pose**:
    an uplink zero-order hold that outputs zeros before its first sample would be taken
    as a (valid) command to go to zero.
    """

    def __init__(
        self,
        config: CommandInterpolatorConfig = CommandInterpolatorConfig(),
        *,
        joint_names,
        lower_rad,
        upper_rad,
        initial_position_rad=None,
        lead_s: float = 0.0,
    ):
        """Validates the joint data and declares ports, state and the poll event.

        Args:
            config: Interpolation settings.
            joint_names: Joint names, base to tip (used in messages); n ≥ 1 unique names.
            lower_rad, upper_rad: Joint position limits, rad; shape (n,), finite,
                lower < upper.
            initial_position_rad: Position held before the first command, rad; shape (n,);
                within the limits. Default zeros.
            lead_s: The set-point is output this far ahead, s (≥ 0, default 0): the output at
                t is the ramp at t + lead_s. A discrete plant reads its servo's desired state
                at the start of each step and reaches it, with an implicit PD, at the end:
                :class:`~telesmooth.systems.flexible_arm.FlexibleJointArm` sets its plant
                step here, so the motors track the ramp itself instead of lagging it by one
                step (which would make the tracking error grow with the plant step).

        Raises:
            ValueError: naming the field, joint and value, if any argument is invalid.
        """
        super().__init__()
        if not isinstance(config, CommandInterpolatorConfig):
            raise ValueError(f"config = {config!r} must be a CommandInterpolatorConfig")
        names = tuple(joint_names)
        if not names or not all(isinstance(name, str) for name in names):
            raise ValueError(f"joint_names = {joint_names!r} must be a non-empty list of str")
        if len(set(names)) != len(names):
            raise ValueError(f"joint_names = {joint_names!r} must be unique")
        n = len(names)
        lower = _validated_vector("lower_rad", lower_rad, n)
        upper = _validated_vector("upper_rad", upper_rad, n)
        for index in range(n):
            if not lower[index] < upper[index]:
                raise ValueError(
                    f"lower_rad[{index}] ({names[index]}) = {float(lower[index])!r} must be "
                    f"below upper_rad[{index}] = {float(upper[index])!r}"
                )
        q0 = np.zeros(n) if initial_position_rad is None else _validated_vector(
            "initial_position_rad", initial_position_rad, n)
        for index in range(n):
            if not lower[index] <= q0[index] <= upper[index]:
                raise ValueError(
                    f"initial_position_rad[{index}] ({names[index]}) = {float(q0[index])!r} "
                    f"is outside the joint limits [{float(lower[index])!r}, "
                    f"{float(upper[index])!r}]"
                )
        if isinstance(lead_s, bool) or not isinstance(lead_s, (int, float)) \
                or not math.isfinite(lead_s) or lead_s < 0.0:
            raise ValueError(f"lead_s = {lead_s!r} must be finite and >= 0")
        self._config = config
        self._joint_names = names
        self._lower = lower
        self._upper = upper
        self._lead_s = float(lead_s)

        self._q_commanded_input = self.DeclareVectorInputPort("q_commanded", n)
        self._command_time_input = self.DeclareVectorInputPort("command_time", 1)

        self._ramp_start_state = self.DeclareDiscreteState(q0.copy())
        self._ramp_target_state = self.DeclareDiscreteState(q0.copy())
        self._ramp_start_time_state = self.DeclareDiscreteState(np.zeros(1))
        # [rejected flag (0/1), number of rejected commands]
        self._rejection_state = self.DeclareDiscreteState(np.zeros(2))
        self._last_rejected_state = self.DeclareDiscreteState(np.full(n, np.nan))
        self.DeclarePeriodicDiscreteUpdateEvent(
            config.poll_period_s, 0.0, self._update_on_poll)

        # Outputs depend on the state and the time only (no feedthrough of q_commanded).
        self._state_desired_output = self.DeclareVectorOutputPort(
            "state_desired", 2 * n, self._calc_state_desired,
            prerequisites_of_calc={self.time_ticket(), self.xd_ticket()})
        self._command_rejected_output = self.DeclareVectorOutputPort(
            "command_rejected", 1, self._calc_command_rejected,
            prerequisites_of_calc={self.xd_ticket()})

    # -- accessors ------------------------------------------------------------------------

    @property
    def config(self) -> CommandInterpolatorConfig:
        return self._config

    @property
    def joint_names(self) -> tuple[str, ...]:
        return self._joint_names

    @property
    def num_joints(self) -> int:
        return len(self._joint_names)

    def get_q_commanded_input_port(self):
        return self._q_commanded_input

    def get_command_time_input_port(self):
        return self._command_time_input

    def get_state_desired_output_port(self):
        return self._state_desired_output

    def get_command_rejected_output_port(self):
        return self._command_rejected_output

    def get_rejected_command_count(self, context) -> int:
        """How many distinct commands were rejected so far (in this context)."""
        return int(context.get_discrete_state(self._rejection_state).get_value()[1])

    def get_ramp(self, context) -> tuple[np.ndarray, np.ndarray, float]:
        """(q₀, q₁, t₀) of the current ramp: start (rad), target (rad), start time (s)."""
        return (
            context.get_discrete_state(self._ramp_start_state).get_value().copy(),
            context.get_discrete_state(self._ramp_target_state).get_value().copy(),
            float(context.get_discrete_state(self._ramp_start_time_state).get_value()[0]),
        )

    def SetHoldPosition(self, context, q_rad) -> None:
        """Makes this context hold ``q_rad`` from its current time (no ramp, flag cleared).

        The held ``q_commanded`` input must then also be ``q_rad``: a different value is a
        new command at the next poll.

        Raises:
            ValueError: if ``q_rad`` is not n finite values within the joint limits.
        """
        q = _validated_vector("q_rad", q_rad, self.num_joints)
        reason = command_violation(q, self._lower, self._upper, self._joint_names)
        if reason is not None:
            raise ValueError(f"SetHoldPosition: {reason}")
        context.SetDiscreteState(self._ramp_start_state, q)
        context.SetDiscreteState(self._ramp_target_state, q)
        context.SetDiscreteState(self._ramp_start_time_state, [context.get_time()])
        rejection = context.get_discrete_state(self._rejection_state).get_value()
        context.SetDiscreteState(self._rejection_state, [0.0, rejection[1]])

    # -- callbacks ------------------------------------------------------------------------

    def _desired(self, context) -> tuple[np.ndarray, np.ndarray]:
        # Read the state in place (ramp_desired_state does not modify its inputs).
        start = context.get_discrete_state(self._ramp_start_state).get_value()
        target = context.get_discrete_state(self._ramp_target_state).get_value()
        start_time = context.get_discrete_state(self._ramp_start_time_state).get_value()[0]
        return ramp_desired_state(
            start, target, start_time, self._config.ramp_duration_s,
            context.get_time() + self._lead_s)

    def _calc_state_desired(self, context, output) -> None:
        position, velocity = self._desired(context)
        output.SetFromVector(np.concatenate([position, velocity]))

    def _calc_command_rejected(self, context, output) -> None:
        output.SetAtIndex(0, context.get_discrete_state(self._rejection_state).get_value()[0])

    def _update_on_poll(self, context, discrete_state) -> None:
        command = self._q_commanded_input.Eval(context)
        target = context.get_discrete_state(self._ramp_target_state).get_value()
        rejected, count = context.get_discrete_state(self._rejection_state).get_value()
        if np.array_equal(command, target):
            if rejected:
                discrete_state.get_mutable_vector(self._rejection_state).SetFromVector(
                    [0.0, count])
            return
        last_rejected = context.get_discrete_state(self._last_rejected_state).get_value()
        if rejected and np.array_equal(command, last_rejected, equal_nan=True):
            return
        reason = command_violation(command, self._lower, self._upper, self._joint_names)
        if reason is not None:
            _logger.warning(
                "%s: command rejected at t = %.6f s, holding the current target: %s",
                self.get_name() or "CommandInterpolator", context.get_time(), reason)
            discrete_state.get_mutable_vector(self._rejection_state).SetFromVector(
                [1.0, count + 1.0])
            discrete_state.get_mutable_vector(self._last_rejected_state).SetFromVector(
                command)
            return
        now = context.get_time()
        previous_start_time = context.get_discrete_state(
            self._ramp_start_time_state).get_value()[0]
        start_time = now
        if self._command_time_input.HasValue(context):
            issued = float(self._command_time_input.Eval(context)[0])
            if math.isfinite(issued) and previous_start_time <= issued <= now:
                start_time = issued
        if self._config.interpolation == "linear":
            start, _ = ramp_desired_state(
                context.get_discrete_state(self._ramp_start_state).get_value(), target,
                previous_start_time, self._config.ramp_duration_s, start_time)
        else:
            start = command
        discrete_state.get_mutable_vector(self._ramp_start_state).SetFromVector(start)
        discrete_state.get_mutable_vector(self._ramp_target_state).SetFromVector(command)
        discrete_state.get_mutable_vector(self._ramp_start_time_state).SetFromVector(
            [start_time])
        discrete_state.get_mutable_vector(self._rejection_state).SetFromVector([0.0, count])
