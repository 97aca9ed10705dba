"""Onboard telemetry as an ``lcmt_onboard_joint_status`` message (pure translation)."""

from __future__ import annotations

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import LeafSystem

from telesmooth.lcm_types import lcmt_onboard_joint_status
from telesmooth.systems.joint_command_receiver import REJECTION_CLASSES

__all__ = ["JointStatusSender"]


class JointStatusSender(LeafSystem):
    r"""Packs the tracker and receiver outputs into the telemetry message.

    .. pydrake_system::

        name: JointStatusSender
        input_ports:
        - q_link
        - q_motor
        - position_measured
        - last_command_seq (optional)
        - command_rejected (optional)
        - command_timeout (optional)
        - last_command_session (optional)
        - q_commanded (optional)
        - guard_mode (optional)
        - stream_distance (optional)
        - accepted_count (optional)
        - rejection_counts (optional)
        - velocity_measured (optional)
        - sample_time (optional)
        output_ports:
        - lcm_message

    - ``q_link``, ``q_motor``: link-side and motor-side joint positions, rad, (J,).
    - ``position_measured``: tool position from the laser tracker, m, (3,).
    - the three optional flags come from :class:`JointCommandReceiver` (−1/0/0 unconnected),
      as do ``last_command_session`` (0), ``accepted_count`` (0) and ``rejection_counts``
      (5 counts in the order of ``joint_command_receiver.REJECTION_CLASSES``; zeros).
    - ``q_commanded``: what the robot is driven to (the link guard's output), rad, (J,);
      unconnected: ``q_link``. ``guard_mode``: the link guard's mode (0 unconnected);
      ``stream_distance``: its distance to the accepted stream, rad (0 unconnected).
    - ``velocity_measured``: [v_link; v_motor] of the tracker's sample, rad/s, (2J,);
      unconnected: NaN (unknown, never invented). ``sample_time``: the instant of the
      tracker's sample, s, (1,) → ``sample_utime``; unconnected: the message's time.
    - ``onboard_epoch`` (constructor): this onboard run's epoch, announced in every message
      (commands must carry it; :mod:`telesmooth.link.session`).
    - ``lcm_message``: utime = the context time in µs; seq counts published messages only
      when published periodically (seq = round(t / period)), so gaps reveal drops.
    """

    def __init__(self, *, num_joints: int, period_s: float = 0.01, onboard_epoch: int = 0):
        super().__init__()
        if num_joints < 1:
            raise ValueError(f"num_joints = {num_joints!r} must be positive")
        self._epoch = int(onboard_epoch)
        self._n = int(num_joints)
        self._period = float(period_s)
        self._q_link_input = self.DeclareVectorInputPort("q_link", self._n)
        self._q_motor_input = self.DeclareVectorInputPort("q_motor", self._n)
        self._position_input = self.DeclareVectorInputPort("position_measured", 3)
        self._seq_input = self.DeclareVectorInputPort("last_command_seq", 1)
        self._rejected_input = self.DeclareVectorInputPort("command_rejected", 1)
        self._timeout_input = self.DeclareVectorInputPort("command_timeout", 1)
        self._session_input = self.DeclareVectorInputPort("last_command_session", 1)
        self._commanded_input = self.DeclareVectorInputPort("q_commanded", self._n)
        self._guard_mode_input = self.DeclareVectorInputPort("guard_mode", 1)
        self._stream_distance_input = self.DeclareVectorInputPort("stream_distance", 1)
        self._accepted_input = self.DeclareVectorInputPort("accepted_count", 1)
        self._counts_input = self.DeclareVectorInputPort("rejection_counts",
                                                         len(REJECTION_CLASSES))
        self._velocity_input = self.DeclareVectorInputPort("velocity_measured", 2 * self._n)
        self._sample_time_input = self.DeclareVectorInputPort("sample_time", 1)
        self._message_output = self.DeclareAbstractOutputPort(
            "lcm_message", lambda: AbstractValue.Make(lcmt_onboard_joint_status()),
            self._calc_lcm_message)

    def get_q_link_input_port(self):
        return self._q_link_input

    def get_q_motor_input_port(self):
        return self._q_motor_input

    def get_position_measured_input_port(self):
        return self._position_input

    def get_last_command_seq_input_port(self):
        return self._seq_input

    def get_command_rejected_input_port(self):
        return self._rejected_input

    def get_command_timeout_input_port(self):
        return self._timeout_input

    def get_last_command_session_input_port(self):
        return self._session_input

    def get_q_commanded_input_port(self):
        return self._commanded_input

    def get_guard_mode_input_port(self):
        return self._guard_mode_input

    def get_stream_distance_input_port(self):
        return self._stream_distance_input

    def get_accepted_count_input_port(self):
        return self._accepted_input

    def get_rejection_counts_input_port(self):
        return self._counts_input

    def get_velocity_measured_input_port(self):
        return self._velocity_input

    def get_sample_time_input_port(self):
        return self._sample_time_input

    def get_lcm_message_output_port(self):
        return self._message_output

    def _optional(self, port, context, default):
        return port.Eval(context)[0] if port.HasValue(context) else default

    def _calc_lcm_message(self, context, output):
        msg = lcmt_onboard_joint_status()
        t = context.get_time()
        msg.utime = int(round(t * 1e6))
        msg.seq = int(round(t / self._period))
        msg.num_joints = self._n
        msg.joint_position_link = [float(v) for v in self._q_link_input.Eval(context)]
        msg.joint_position_motor = [float(v) for v in self._q_motor_input.Eval(context)]
        msg.tool_position_measured = [float(v) for v in self._position_input.Eval(context)]
        msg.last_command_seq = int(round(self._optional(self._seq_input, context, -1.0)))
        msg.command_rejected = bool(self._optional(self._rejected_input, context, 0.0) > 0.5)
        msg.command_timeout = bool(self._optional(self._timeout_input, context, 0.0) > 0.5)
        msg.last_command_session_id = int(round(
            self._optional(self._session_input, context, 0.0)))
        commanded = (self._commanded_input.Eval(context)
                     if self._commanded_input.HasValue(context) else msg.joint_position_link)
        msg.joint_position_commanded = [float(v) for v in commanded]
        msg.guard_mode = int(round(self._optional(self._guard_mode_input, context, 0.0)))
        msg.accepted_count = int(round(self._optional(self._accepted_input, context, 0.0)))
        counts = (self._counts_input.Eval(context) if self._counts_input.HasValue(context)
                  else [0.0] * len(REJECTION_CLASSES))
        (msg.rejected_invalid_count, msg.rejected_auth_count, msg.dropped_duplicate_count,
         msg.dropped_stale_count, msg.undecodable_count, msg.rejected_session_count) = (
            int(round(c)) for c in counts)
        msg.onboard_epoch = self._epoch
        msg.stream_distance_rad = float(self._optional(self._stream_distance_input, context, 0.0))
        msg.sample_utime = int(round(1e6 * self._optional(self._sample_time_input, context, t)))
        velocity = (self._velocity_input.Eval(context) if self._velocity_input.HasValue(context)
                    else np.full(2 * self._n, np.nan))
        msg.joint_velocity_link = [float(v) for v in velocity[:self._n]]
        msg.joint_velocity_motor = [float(v) for v in velocity[self._n:]]
        output.set_value(msg)
