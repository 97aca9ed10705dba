"""Onboard link guard: the robot enforces the limits itself, ramps down when the uplink goes
silent, and re-joins the stream when it comes back.

A thin Drake system around the pure state machine :func:`telesmooth.safety.guard.guard_step`
(see :mod:`telesmooth.safety.guard` for the modes, the rules and the guarantees). It sits
between the :class:`~telesmooth.systems.joint_command_receiver.JointCommandReceiver` and the
robot's command interpolator; all its state (a :class:`~telesmooth.safety.guard.GuardState`)
lives in the Context as one discrete vector (:class:`~telesmooth.systems.codec_state.CodecState`),
and the only things on ``self`` are immutable parameters.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from pydrake.systems.framework import LeafSystem

from telesmooth.safety.guard import (
    FdLimitRatios,
    GuardInputs,
    GuardMode,
    GuardParams,
    LinkGuardConfig,
    fd_limits_ratio,
    guard_initial_state,
    guard_params,
    guard_step,
)
from telesmooth.safety.stop import StopPlan, plan_stop
from telesmooth.systems.codec_state import CodecState

__all__ = [
    "GUARD_MODES",
    "MODE_HELD",
    "MODE_RESUMING",
    "MODE_STOPPING",
    "MODE_TRACK",
    "FdLimitRatios",
    "GuardMode",
    "LinkGuard",
    "LinkGuardConfig",
    "fd_limits_ratio",
]

MODE_TRACK = GuardMode.TRACK
MODE_STOPPING = GuardMode.STOPPING
MODE_HELD = GuardMode.HELD
MODE_RESUMING = GuardMode.RESUMING

GUARD_MODES = tuple(mode.label for mode in GuardMode)
"""Mode names; the ``guard_mode`` output carries the index in this tuple."""


class LinkGuard(LeafSystem):
    r"""The accepted uplink commands, kept within the FD limits, with a jerk-limited ramp-down
    when the uplink goes silent and a converging re-join when it comes back.

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
        - stream_distance
        - limited_count

    Ports (J = number of joints):

    - ``q_accepted``: the receiver's last accepted command (held), rad, (J,)
      (``JointCommandReceiver.q_commanded``). Read only when ``accepted_count`` increases.
    - ``accepted_count``: packets accepted so far, (1,); any increase means "a new command was
      accepted"; a decrease (a restarted receiver) only re-baselines the count.
    - ``command_seq``, ``command_session``: optional, (1,) each: the sequence number and
      session of the packet on ``q_accepted``. When connected, a packet is *consecutive* only
      if it is the next seq of the same session as the packet the last command used;
      unconnected, every single new packet counts as consecutive.
    - ``q_commanded``: the command for the robot, rad, (J,).
    - ``guard_mode``: (1,), the :class:`~telesmooth.safety.guard.GuardMode` (index in
      :data:`GUARD_MODES`): 0 track, 1 stopping, 2 held, 3 resuming.
    - ``braking_distance``: per joint, the signed braking distance of the last stop plan,
      rad, (J,); zeros before the first plan and after a hold fallback.
    - ``stop_outcome``: (1,), the :class:`~telesmooth.safety.stop.StopOutcome` of the last
      stop plan (0 none before any, 1 stop, 3…6 the hold fallbacks).
    - ``command_count``: (1,), the number of commands issued; ``q_commanded`` sampled where it
      increases is the command *sequence* whose FD values the limits are about.
    - ``stream_distance``: (1,), max over joints of |q_commanded − the newest accepted
      packet|, rad (0 before the first packet).
    - ``limited_count``: (1,), the commands that followed a packet but differ from it: the
      limiter cut them to keep the limits.

    All outputs read the state (no direct feedthrough): at a poll they show the state *before*
    that poll's update (Drake's x⁻). One periodic discrete update every ``poll_period_s``
    (offset 0) runs :func:`~telesmooth.safety.guard.guard_step` with poll i =
    round(t/poll_period_s). In a diagram with the receiver (an unrestricted update on the same
    poll grid) the guard sees a packet in the same poll in which the receiver accepts it
    (Drake runs unrestricted updates before discrete ones).
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
        """Validates (:func:`~telesmooth.safety.guard.guard_params`, whose arguments these
        are), then declares ports, state and the poll.

        Raises:
            ValueError: naming the field, the value and (where relevant) the joint.
        """
        super().__init__()
        self._params = guard_params(
            config, joint_names=joint_names, lower_rad=lower_rad, upper_rad=upper_rad,
            initial_position_rad=initial_position_rad, max_acceleration=max_acceleration,
            max_jerk=max_jerk, max_velocity=max_velocity, pose_is_safe=pose_is_safe)
        n = self._params.num_joints
        initial = guard_initial_state(self._params)

        self._q_accepted_input = self.DeclareVectorInputPort("q_accepted", n)
        self._accepted_count_input = self.DeclareVectorInputPort("accepted_count", 1)
        self._command_seq_input = self.DeclareVectorInputPort("command_seq", 1)
        self._command_session_input = self.DeclareVectorInputPort("command_session", 1)

        self._state = CodecState(self, initial)
        self.DeclarePeriodicDiscreteUpdateEvent(config.poll_period_s, 0.0, self._update_guard)
        self.DeclareForcedDiscreteUpdateEvent(self._update_guard)

        history = self._state.codec.field_slice("history")
        command = slice(history.stop - n, history.stop)   # the last row of the history
        state_output = self._state.output
        self._q_commanded_output = state_output("q_commanded", command)
        self._guard_mode_output = state_output("guard_mode", "mode")
        self._braking_distance_output = state_output("braking_distance", "braking_distance")
        self._stop_outcome_output = state_output("stop_outcome", "stop_outcome")
        self._command_count_output = state_output("command_count", "command_count")
        self._stream_distance_output = state_output("stream_distance", "stream_distance_rad")
        self._limited_count_output = state_output("limited_count", "limited_count")

    # -- accessors ------------------------------------------------------------------------

    @property
    def params(self) -> GuardParams:
        """The immutable parameters of :func:`~telesmooth.safety.guard.guard_step`."""
        return self._params

    @property
    def config(self) -> LinkGuardConfig:
        return self._params.config

    @property
    def joint_names(self) -> tuple[str, ...]:
        return self._params.joint_names

    @property
    def lower_rad(self) -> np.ndarray:
        return self._params.lower_rad.copy()

    @property
    def upper_rad(self) -> np.ndarray:
        return self._params.upper_rad.copy()

    @property
    def max_acceleration(self) -> np.ndarray:
        return self._params.limiter.max_acceleration.copy()

    @property
    def max_jerk(self) -> np.ndarray:
        return self._params.limiter.max_jerk.copy()

    def pose_is_safe(self, q) -> bool:
        """Whether the guard may command ``q`` itself (joint limits and the pose check)."""
        return self._params.pose_is_safe(q)

    def plan_stop(self, command_history) -> StopPlan:
        """The stop the guard plans from the last three commanded poses (3, J)."""
        return plan_stop(self._params.stop, command_history,
                         max_ticks=self._params.config.max_stop_ticks)

    def guard_state(self, context):
        """The :class:`~telesmooth.safety.guard.GuardState` in ``context``."""
        return self._state.get(context)

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

    def get_stream_distance_output_port(self):
        return self._stream_distance_output

    def get_limited_count_output_port(self):
        return self._limited_count_output

    # -- the poll -------------------------------------------------------------------------

    def _update_guard(self, context, discrete_state):
        packet_id = None
        if self._command_seq_input.HasValue(context):
            session = (float(self._command_session_input.Eval(context)[0])
                       if self._command_session_input.HasValue(context) else 0.0)
            packet_id = (float(self._command_seq_input.Eval(context)[0]), session)
        inputs = GuardInputs(
            poll=int(round(context.get_time() / self._params.config.poll_period_s)),
            accepted_count=float(self._accepted_count_input.Eval(context)[0]),
            q_accepted=np.array(self._q_accepted_input.Eval(context), dtype=float),
            packet_id=packet_id)
        state, _ = guard_step(self._params, self.guard_state(context), inputs)
        self._state.store(discrete_state, state)
