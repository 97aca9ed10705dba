"""Ground side of the uplink over LCM: the held command as an ``lcmt_teleop_joint_command``."""

from __future__ import annotations

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import LeafSystem

from telesmooth.lcm_types import lcmt_teleop_joint_command
from telesmooth.link.auth import check_key, sign

__all__ = ["JointCommandSender"]


class JointCommandSender(LeafSystem):
    r"""Packs the uplink's held packet into an LCM message (no state; pure translation).

    .. pydrake_system::

        name: JointCommandSender
        input_ports:
        - q_sent
        - sequence_number
        - send_time
        - state_sent (optional)
        - holding (optional)
        - onboard_epoch (optional)
        - session_id (optional)
        output_ports:
        - lcm_message

    - ``q_sent``: joint positions of the packet, rad, (J,) (Uplink ``q_sent``).
    - ``sequence_number``, ``send_time``: the packet's number and time, s (Uplink outputs).
    - ``state_sent``: [q, q̇, q̈, q⃛] of the packet (Uplink ``state_sent``), (4J,); gives the
      velocity field (zero when unconnected).
    - ``holding``: 1 if the packet is a hold (Uplink ``holding_sent``) → ``mode = MODE_HOLD``.
    - ``onboard_epoch``, ``session_id``: the robot's epoch and this run's session
      (:class:`~telesmooth.systems.link_monitor.LinkMonitor`, from the telemetry; see
      :mod:`telesmooth.link.session`); unconnected: the constructor's. While the connected
      epoch is 0 (no telemetry yet: the robot cannot be addressed) the message carries
      seq = −1, which the onboard receiver ignores.
    - ``lcm_message``: ``lcmt_teleop_joint_command`` with utime = send_time in µs,
      sample_utime = utime − ``delay_s``, the joint names, positions and velocities,
      ``session_id`` and, with an ``uplink_key``, the HMAC tag
      (:func:`telesmooth.link.auth.sign`).

    Before the first packet (sequence −1) the message carries seq = −1; the onboard receiver
    ignores it. Publish it with ``LcmPublisherSystem.Make(..., publish_period=period,
    publish_offset=small)``: Drake publishes the pre-update value at an event time, so an
    offset of a few ms after each uplink tick sends packet k, not k−1.
    """

    def __init__(self, *, joint_names, delay_s: float, session_id: int = 0,
                 uplink_key: bytes | None = None, onboard_epoch: int = 0):
        """Args:
            joint_names: The robot's joints, base to tip.
            delay_s: The ground's safety delay (sample_utime = utime − delay), s.
            session_id: This ground run's id (µs since the epoch at process start; 0 in
                process), so that a restarted ground process is newer than the last one.
            uplink_key: The shared HMAC key; None sends unsigned packets (in-process only).
            onboard_epoch: The robot's epoch when the ``onboard_epoch`` port is unconnected.
        """
        super().__init__()
        if isinstance(session_id, bool) or not isinstance(session_id, (int, np.integer)) or \
                not 0 <= session_id < 2**63:
            raise ValueError(f"session_id = {session_id!r} must be an integer in [0, 2^63)")
        self._session_id = int(session_id)
        self._epoch = int(onboard_epoch)
        self._key = None if uplink_key is None else check_key(uplink_key, field="uplink_key")
        self._joint_names = tuple(str(n) for n in joint_names)
        n = len(self._joint_names)
        if n == 0:
            raise ValueError("joint_names must name at least one joint")
        if not (np.isfinite(delay_s) and delay_s >= 0.0):
            raise ValueError(f"delay_s = {delay_s!r} must be non-negative and finite")
        self._delay_us = int(round(delay_s * 1e6))
        self._q_sent_input = self.DeclareVectorInputPort("q_sent", n)
        self._sequence_input = self.DeclareVectorInputPort("sequence_number", 1)
        self._send_time_input = self.DeclareVectorInputPort("send_time", 1)
        self._state_input = self.DeclareVectorInputPort("state_sent", 4 * n)
        self._holding_input = self.DeclareVectorInputPort("holding", 1)
        self._epoch_input = self.DeclareVectorInputPort("onboard_epoch", 1)
        self._session_input = self.DeclareVectorInputPort("session_id", 1)
        self._message_output = self.DeclareAbstractOutputPort(
            "lcm_message", lambda: AbstractValue.Make(lcmt_teleop_joint_command()),
            self._calc_lcm_message)

    def get_q_sent_input_port(self):
        return self._q_sent_input

    def get_sequence_number_input_port(self):
        return self._sequence_input

    def get_send_time_input_port(self):
        return self._send_time_input

    def get_state_sent_input_port(self):
        return self._state_input

    def get_holding_input_port(self):
        return self._holding_input

    def get_onboard_epoch_input_port(self):
        return self._epoch_input

    def get_session_id_input_port(self):
        return self._session_input

    def get_lcm_message_output_port(self):
        return self._message_output

    def _calc_lcm_message(self, context, output):
        n = len(self._joint_names)
        msg = lcmt_teleop_joint_command()
        msg.seq = int(round(self._sequence_input.Eval(context)[0]))
        msg.utime = int(round(self._send_time_input.Eval(context)[0] * 1e6))
        msg.sample_utime = msg.utime - self._delay_us
        msg.num_joints = n
        msg.joint_name = list(self._joint_names)
        msg.joint_position_smoothed = [float(v) for v in self._q_sent_input.Eval(context)]
        velocity = np.zeros(n)
        if self._state_input.HasValue(context):
            velocity = self._state_input.Eval(context)[n:2 * n]
        msg.joint_velocity_smoothed = [float(v) for v in velocity]
        holding = (self._holding_input.HasValue(context)
                   and self._holding_input.Eval(context)[0] > 0.5)
        msg.mode = lcmt_teleop_joint_command.MODE_HOLD if holding else \
            lcmt_teleop_joint_command.MODE_TRACK
        msg.session_id = self._session_id
        msg.onboard_epoch = self._epoch
        if self._session_input.HasValue(context):
            msg.session_id = int(round(self._session_input.Eval(context)[0]))
        if self._epoch_input.HasValue(context):
            msg.onboard_epoch = int(round(self._epoch_input.Eval(context)[0]))
            if msg.onboard_epoch == 0:
                msg.seq = -1    # no telemetry yet: the robot cannot be addressed
        if self._key is not None and msg.seq >= 0:
            msg = sign(msg, self._key)
        output.set_value(msg)
