"""The onboard motor-side servo set-point: turns the held 4 Hz commands into a desired state.

The uplink delivers one joint-position command per period (0.25 s) and holds it. Feeding
that staircase straight into the plant's PD would step the motors four times a second and
ring the flexible links; this block instead ramps the desired motor position from where it
is to each new command over one uplink period (or steps, ``interpolation="zoh"``), and
emits ``[q_d; v_d]`` for ``MultibodyPlant.get_desired_state_input_port``. It is also the
onboard gatekeeper: a command that is not finite or is outside the joint limits never
reaches the plant; the robot keeps its current target (holds) and a flag is raised.

Two parts, so that no Python runs at the plant rate: the :class:`CommandGate` (Python)
reads the held command at its polls and keeps the ramp in progress, (t₀, q₀, q₁), as
discrete state, changed once per command; the set-point itself, a closed-form function of
that ramp and the time, is evaluated by Drake (a ``SymbolicVectorSystem``,
:func:`RampSetPoint`) whenever the plant reads it.

The numerics are the pure functions of :mod:`telesmooth.safety.command_gate` (re-exported
here): the gate's step, :func:`ramp_desired_state` (the oracle of the symbolic
set-point) and :func:`command_violation` (numpy only, tested without a simulator).
"""

from __future__ import annotations

import dataclasses
import logging
import math

import numpy as np
from pydrake.symbolic import Variable, if_then_else, logical_and
from pydrake.symbolic import max as symbolic_max
from pydrake.symbolic import min as symbolic_min
from pydrake.systems.framework import Diagram, DiagramBuilder, LeafSystem
from pydrake.systems.primitives import SymbolicVectorSystem

from telesmooth.arms.joint_vectors import check_joint_limits, check_joint_vector
from telesmooth.safety.command_gate import (
    GateParams,
    GateState,
    Ramp,
    command_violation,
    gate_initial_state,
    gate_step,
    ramp_desired_state,
)
from telesmooth.systems.codec_state import CodecState
from telesmooth.systems.timing import check_period

__all__ = [
    "DEFAULT_POLL_PERIOD_S",
    "CommandGate",
    "CommandInterpolator",
    "CommandInterpolatorConfig",
    "INTERPOLATIONS",
    "RampSetPoint",
    "command_violation",
    "ramp_desired_state",
]

INTERPOLATIONS = ("linear", "zoh")
"""The interpolation options of :class:`CommandInterpolatorConfig`."""

DEFAULT_POLL_PERIOD_S = 0.01
"""The poll period when neither the config nor the diagram gives one: the onboard command
receiver's (and the link guard's) 10 ms."""

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
        poll_period_s: How often the held command is read, s (> 0), or None (default):
            the period at which the command can change, as the diagram that connects the
            robot knows it (``command_period_s`` of :class:`CommandInterpolator`): the
            uplink's 0.25 s when the uplink drives the robot directly, the onboard command
            receiver's 10 ms (:data:`DEFAULT_POLL_PERIOD_S`) behind a link. A new command is
            detected at the first poll at which it differs from the current target.
        poll_offset_s: Time of the first poll, s (≥ 0, below the poll period); 0.1 ms by
            default. The upstream commands change at multiples of the poll period (the
            uplink's ticks, the receiver's polls), and a poll at the same instant would not
            see the change (Drake computes simultaneous updates from the state before the
            instant): it would find it one whole poll period later. Polling 0.1 ms after
            the instant, the robot follows the command from 0.1 ms after it was issued.
            That delay is not free: on Defaults the response error e grows by about 20 %
            per millisecond of it (the servo stalls at the end of each ramp until the next
            command is seen), so keep it small.
    """

    interpolation: str = "linear"
    ramp_duration_s: float = 0.25
    poll_period_s: float | None = None
    poll_offset_s: float = 1e-4

    def __post_init__(self) -> None:
        if self.interpolation not in INTERPOLATIONS:
            raise ValueError(
                f"CommandInterpolatorConfig.interpolation = {self.interpolation!r} must be "
                f"one of {INTERPOLATIONS}"
            )
        check_period("CommandInterpolatorConfig.ramp_duration_s", self.ramp_duration_s)
        if self.poll_period_s is not None:
            check_period("CommandInterpolatorConfig.poll_period_s", self.poll_period_s)
        self.poll_timing(DEFAULT_POLL_PERIOD_S)

    def poll_timing(self, command_period_s: float | None) -> tuple[float, float]:
        """(period, offset) of the polls, s: ``poll_period_s``, or ``command_period_s`` if it
        is None (:data:`DEFAULT_POLL_PERIOD_S` if that is None too), and ``poll_offset_s``.

        Raises:
            ValueError: naming the field, if the offset is not in [0, period).
        """
        if self.poll_period_s is not None:
            period = check_period("CommandInterpolatorConfig.poll_period_s", self.poll_period_s)
        elif command_period_s is not None:
            period = check_period("command_period_s", command_period_s)
        else:
            period = DEFAULT_POLL_PERIOD_S
        offset = self.poll_offset_s
        if isinstance(offset, bool) or not isinstance(offset, (int, float)) \
                or not 0.0 <= offset < period:
            raise ValueError(
                f"CommandInterpolatorConfig.poll_offset_s = {offset!r} must be a number of "
                f"seconds in [0, poll period = {period!r})")
        return period, float(offset)


def RampSetPoint(num_joints: int, ramp_duration_s: float, lead_s: float = 0.0, *,
                 continuous_state: bool = False) -> SymbolicVectorSystem:
    r"""The set-point of a ramp, evaluated by Drake: [t₀; q₀; q₁] and the time → [q_d; v_d].

    .. pydrake_system::

        name: RampSetPoint
        input_ports:
        - u0
        output_ports:
        - y0

    Input ``u0``: the ramp in progress, [t₀ (s), q₀ (rad, n), q₁ (rad, n)], shape (2n + 1,)
    (the :class:`CommandGate`'s ``ramp`` port). Output ``y0``: [q_d; v_d], rad and rad/s,
    shape (2n,), at the context's time t, with e = (t + lead) − t₀, T = ``ramp_duration_s``,
    s = min(max(e/T, 0), 1):

        q_d = q₁                      if s ≥ 1,  else  q₀ + s·(q₁ − q₀)
        v_d = (q₁ − q₀)/T             if 0 ≤ e < T,  else  0

    the operations of :func:`ramp_desired_state` in the same order, so the two agree to the
    last bit. Direct feedthrough, no state; Drake re-evaluates it whenever the time or the
    ramp changed, in C++ (about 15 µs for 6 joints, against about 60 µs for the same formula
    in a Python output callback).

    Args:
        num_joints: n ≥ 1.
        ramp_duration_s: T, s (> 0).
        lead_s: The output at t is the ramp at t + lead_s, s (≥ 0).
        continuous_state: Give the system one continuous state x with ẋ = 0 (x is never
            read). Needed in a diagram that has continuous state (e.g. a continuous plant):
            drake 1.51's SymbolicVectorSystem aborts when an integrator asks a stateless
            one for its time derivatives. Without it, a purely discrete diagram needs no
            integrator (about 7 % faster).
    """
    n = int(num_joints)
    period = float(ramp_duration_s)
    time = Variable("t")
    start_time = Variable("t0")
    start = [Variable(f"q0_{i}") for i in range(n)]
    target = [Variable(f"q1_{i}") for i in range(n)]
    elapsed = (time + float(lead_s)) - start_time
    fraction = symbolic_min(symbolic_max(elapsed / period, 0.0), 1.0)
    moving = logical_and(elapsed >= 0.0, elapsed < period)
    position = [if_then_else(fraction >= 1.0, target[i],
                             start[i] + fraction * (target[i] - start[i]))
                for i in range(n)]
    velocity = [if_then_else(moving, (target[i] - start[i]) / period, 0.0) for i in range(n)]
    inputs = [start_time] + start + target
    if continuous_state:
        unused = Variable("x")
        system = SymbolicVectorSystem(time=time, state=[unused], input=inputs,
                                      dynamics=[0.0 * unused], output=position + velocity)
    else:
        system = SymbolicVectorSystem(time=time, input=inputs, output=position + velocity)
    system.set_name("ramp_set_point")
    return system


class CommandGate(LeafSystem):
    r"""The command gate of :class:`CommandInterpolator`: polls the held command, rejects
    unsafe ones and keeps the ramp in progress.

    .. pydrake_system::

        name: CommandGate
        input_ports:
        - q_commanded
        - command_time (optional)
        output_ports:
        - ramp
        - command_rejected

    Ports (n joints): ``q_commanded`` and ``command_time`` as in :class:`CommandInterpolator`;
    ``ramp``: [t₀, q₀ (n), q₁ (n)], the ramp in progress, (2n + 1,) (for
    :func:`RampSetPoint`); ``command_rejected``: [flag], (1,). Both outputs are state (no
    feedthrough), evaluated by Drake without a Python call.

    State (:class:`~telesmooth.safety.command_gate.GateState`, two discrete vectors): the ramp
    [t₀, q₀, q₁]; the rejected flag, the rejected-command count and the last rejected command
    (a held invalid command is counted once); updated by
    :func:`~telesmooth.safety.command_gate.gate_step` at every poll (see
    :meth:`CommandInterpolatorConfig.poll_timing`; described in :class:`CommandInterpolator`).
    """

    def __init__(
        self,
        config: CommandInterpolatorConfig = CommandInterpolatorConfig(),
        *,
        joint_names,
        lower_rad,
        upper_rad,
        initial_position_rad=None,
        command_period_s: float | None = None,
    ):
        """Validates the joint data and declares ports, state and the poll event.

        Args and Raises: as :class:`CommandInterpolator` (without ``lead_s``).
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
        lower, upper = check_joint_limits(lower_rad, upper_rad, names)
        q0 = check_joint_vector(
            "initial_position_rad", np.zeros(n) if initial_position_rad is None
            else initial_position_rad, names, lower=lower, upper=upper)
        self._config = config

        self._q_commanded_input = self.DeclareVectorInputPort("q_commanded", n)
        self._command_time_input = self.DeclareVectorInputPort("command_time", 1)

        self._params = GateParams(joint_names=names, lower_rad=lower, upper_rad=upper,
                                  interpolation=config.interpolation,
                                  ramp_duration_s=config.ramp_duration_s)
        initial = gate_initial_state(q0)
        # Two state vectors: the ramp [t₀, q₀ (n), q₁ (n)], which the plant's set-point reads
        # at every step (a state output port: no Python call), and the refusals.
        self._ramp = CodecState(self, initial.ramp)
        self._refusals = CodecState(self, initial.refusals)
        poll_period_s, poll_offset_s = config.poll_timing(command_period_s)
        self.DeclarePeriodicDiscreteUpdateEvent(poll_period_s, poll_offset_s,
                                                self._update_on_poll)
        self._ramp_output = self.DeclareStateOutputPort("ramp", self._ramp.index)
        self._command_rejected_output = self._refusals.output("command_rejected", "rejected")

    # -- accessors ------------------------------------------------------------------------

    @property
    def config(self) -> CommandInterpolatorConfig:
        return self._config

    @property
    def joint_names(self) -> tuple[str, ...]:
        return self._params.joint_names

    @property
    def num_joints(self) -> int:
        return len(self._params.joint_names)

    def get_q_commanded_input_port(self):
        return self._q_commanded_input

    def get_command_time_input_port(self):
        return self._command_time_input

    def get_ramp_output_port(self):
        return self._ramp_output

    def get_command_rejected_output_port(self):
        return self._command_rejected_output

    def gate_state(self, context) -> GateState:
        """The gate, as :func:`~telesmooth.safety.command_gate.gate_step` left it."""
        return GateState(ramp=self._ramp.get(context), refusals=self._refusals.get(context))

    def get_rejected_command_count(self, context) -> int:
        """How many distinct commands were rejected so far (in this context)."""
        return self._refusals.get(context).count

    def get_ramp(self, context) -> tuple[np.ndarray, np.ndarray, float]:
        """(q₀, q₁, t₀) of the current ramp: start (rad), target (rad), start time (s)."""
        ramp = self._ramp.get(context)
        return ramp.start.copy(), ramp.target.copy(), float(ramp.start_s)

    def SetHoldPosition(self, context, q_rad) -> None:
        """Makes this context hold ``q_rad`` from its current time (see
        :meth:`CommandInterpolator.SetHoldPosition`)."""
        params = self._params
        q = check_joint_vector("q_rad", q_rad, params.joint_names)
        reason = command_violation(q, params.lower_rad, params.upper_rad, params.joint_names)
        if reason is not None:
            raise ValueError(f"SetHoldPosition: {reason}")
        q = np.array(q, dtype=float)
        self._ramp.set(context, Ramp(start_s=context.get_time(), start=q, target=q.copy()))
        self._refusals.set(context, self._refusals.get(context)._replace(rejected=False))

    # -- the poll -------------------------------------------------------------------------

    def _update_on_poll(self, context, discrete_state) -> None:
        issued = (float(self._command_time_input.Eval(context)[0])
                  if self._command_time_input.HasValue(context) else None)
        before = self.gate_state(context)
        state, reason = gate_step(self._params, before, self._q_commanded_input.Eval(context),
                                  context.get_time(), issued)
        if state is before:      # most polls: the held command is the target (nothing to write)
            return
        if reason is not None:
            _logger.warning(
                "%s: command rejected at t = %.6f s, holding the current target: %s",
                self.GetSystemPathname(), context.get_time(), reason)
        self._ramp.store(discrete_state, state.ramp)
        self._refusals.store(discrete_state, state.refusals)


class CommandInterpolator(Diagram):
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

    Inside: a :class:`CommandGate` ("command_gate", Python, runs at its polls only) keeps
    the ramp; a :func:`RampSetPoint` ("ramp_set_point", evaluated by Drake in C++) turns
    the ramp and the time into the set-point, so nothing runs in Python at the plant rate.

    State (the gate's, discrete, updated every poll period P (``poll_period_s``, or
    ``command_period_s``, or 10 ms) at t_k = ``poll_offset_s`` + k·P): the ramp
    [t₀, q₀ (n), q₁ (n)] (start time, start, target), the rejected flag (1), and
    [rejected-command count, last rejected command (n)] (to count a held invalid command once).

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
      (t_k − s)·(v_new − v_old), the velocity change times the time the poll was late.

    Output at any time t (:func:`ramp_desired_state`), T = ``ramp_duration_s``,
    s = clip((t + lead − t₀)/T, 0, 1) (lead = the constructor's ``lead_s``, 0 by default):

        q_d(t) = q₀ + s·(q₁ − q₀)
        v_d(t) = (q₁ − q₀)/T  for t₀ ≤ t + lead < t₀ + T,  else 0

    so a new command issued at t₀ is reached at t₀ + T; a command arriving mid-ramp
    starts a new ramp from the current q_d (the position is continuous, the velocity
    jumps). With a steady 4 Hz stream and T = 0.25 s, q_d is the piecewise-linear
    interpolation of the commands delayed by one uplink period less the lead (exactly, with
    ``command_time``; else plus the time until the next poll: a command that changes at t
    is seen at the first poll after t, or at t itself if the upstream value has already
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
        continuous_diagram: bool = False,
        command_period_s: float | None = None,
    ):
        """Validates the joint data and builds the gate and the set-point evaluator.

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
            continuous_diagram: True if this system will be part of a diagram with
                continuous state (a continuous plant): see :func:`RampSetPoint`'s
                ``continuous_state``.
            command_period_s: The period at which ``q_commanded`` can change, s (the
                upstream source's: the uplink's, the receiver's); the poll period when
                ``config.poll_period_s`` is None (10 ms if this is None too).

        Raises:
            ValueError: naming the field, joint and value, if any argument is invalid.
        """
        super().__init__()
        builder = DiagramBuilder()
        gate = builder.AddNamedSystem("command_gate", CommandGate(
            config, joint_names=joint_names, lower_rad=lower_rad, upper_rad=upper_rad,
            initial_position_rad=initial_position_rad, command_period_s=command_period_s))
        if isinstance(lead_s, bool) or not isinstance(lead_s, (int, float)) \
                or not math.isfinite(lead_s) or lead_s < 0.0:
            raise ValueError(f"lead_s = {lead_s!r} must be finite and >= 0")
        set_point = builder.AddNamedSystem("ramp_set_point", RampSetPoint(
            gate.num_joints, config.ramp_duration_s, float(lead_s),
            continuous_state=bool(continuous_diagram)))
        builder.Connect(gate.get_ramp_output_port(), set_point.get_input_port())
        builder.ExportInput(gate.get_q_commanded_input_port(), "q_commanded")
        builder.ExportInput(gate.get_command_time_input_port(), "command_time")
        builder.ExportOutput(set_point.get_output_port(), "state_desired")
        builder.ExportOutput(gate.get_command_rejected_output_port(), "command_rejected")
        builder.ExportOutput(gate.get_ramp_output_port(), "ramp")
        builder.BuildInto(self)
        self._gate = gate
        self._lead_s = float(lead_s)

    # -- accessors ------------------------------------------------------------------------

    @property
    def config(self) -> CommandInterpolatorConfig:
        return self._gate.config

    @property
    def joint_names(self) -> tuple[str, ...]:
        return self._gate.joint_names

    @property
    def num_joints(self) -> int:
        return self._gate.num_joints

    @property
    def gate(self) -> CommandGate:
        """The command gate (the poll and its state)."""
        return self._gate

    def get_q_commanded_input_port(self):
        return self.GetInputPort("q_commanded")

    def get_command_time_input_port(self):
        return self.GetInputPort("command_time")

    def get_state_desired_output_port(self):
        return self.GetOutputPort("state_desired")

    def get_command_rejected_output_port(self):
        return self.GetOutputPort("command_rejected")

    def get_ramp_output_port(self):
        """The ramp in progress, [t₀ (s), q₀ (rad, n), q₁ (rad, n)]: t₀ is when the robot
        started towards its newest command q₁ (the instant a response is measured from)."""
        return self.GetOutputPort("ramp")

    def get_rejected_command_count(self, context) -> int:
        """How many distinct commands were rejected so far (``context``: this system's)."""
        return self._gate.get_rejected_command_count(
            self.GetSubsystemContext(self._gate, context))

    def get_ramp(self, context) -> tuple[np.ndarray, np.ndarray, float]:
        """(q₀, q₁, t₀) of the current ramp: start (rad), target (rad), start time (s)."""
        return self._gate.get_ramp(self.GetSubsystemContext(self._gate, context))

    def SetHoldPosition(self, context, q_rad) -> None:
        """Makes this context hold ``q_rad`` from its current time (no ramp, flag cleared).

        The held ``q_commanded`` input must then also be ``q_rad``: a different value is a
        new command at the next poll.

        Raises:
            ValueError: if ``q_rad`` is not n finite values within the joint limits.
        """
        self._gate.SetHoldPosition(self.GetMutableSubsystemContext(self._gate, context), q_rad)
