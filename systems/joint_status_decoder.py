"""The robot's telemetry on the ground: ``lcmt_onboard_joint_status`` → one vector to log.

The ground process receives the robot's telemetry (ONBOARD_JOINT_STATUS) over LCM. This
system turns the newest message into a fixed vector (:data:`TELEMETRY_FIELDS`), so that a
``LogVectorOutput`` can record what the robot reported and the ground's report can draw it
(:mod:`telesmooth.scripts.process_report`). A message of another arm (a joint count that
does not match) or the default message before any arrives reads as NaN: no value is
invented.
"""

from __future__ import annotations

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import LeafSystem

from telesmooth.lcm_types import lcmt_onboard_joint_status

__all__ = ["JointStatusDecoder", "TELEMETRY_FIELDS", "telemetry_layout", "telemetry_vector"]

TELEMETRY_FIELDS = ("utime_s", "seq", "last_command_seq", "guard_mode", "stream_distance_rad",
                    "q_link", "q_motor", "tool_position", "q_commanded")
"""The decoded vector, in this order: the onboard time of the message (s), its seq, the last
accepted command's seq, the guard mode, the stream distance (rad), then q_link (J), q_motor
(J), the tool position (3, m) and the guard's command (J)."""


def telemetry_layout(num_joints: int) -> dict[str, slice]:
    """Where each of :data:`TELEMETRY_FIELDS` sits in the vector of ``num_joints`` joints."""
    sizes = {"q_link": num_joints, "q_motor": num_joints, "tool_position": 3,
             "q_commanded": num_joints}
    layout, start = {}, 0
    for name in TELEMETRY_FIELDS:
        size = sizes.get(name, 1)
        layout[name] = slice(start, start + size)
        start += size
    return layout


def telemetry_vector(msg, num_joints: int) -> np.ndarray:
    """``msg`` as the vector of :data:`TELEMETRY_FIELDS`; all NaN for a message whose joint
    count is not ``num_joints`` (or the default message: no joints)."""
    layout = telemetry_layout(num_joints)
    size = layout["q_commanded"].stop
    vector = np.full(size, np.nan)
    n = int(msg.num_joints)
    if n != num_joints or len(msg.joint_position_link) != n \
            or len(msg.joint_position_commanded) != n:
        return vector
    vector[layout["utime_s"]] = msg.utime * 1e-6
    vector[layout["seq"]] = msg.seq
    vector[layout["last_command_seq"]] = msg.last_command_seq
    vector[layout["guard_mode"]] = msg.guard_mode
    vector[layout["stream_distance_rad"]] = msg.stream_distance_rad
    vector[layout["q_link"]] = msg.joint_position_link
    vector[layout["q_motor"]] = msg.joint_position_motor
    vector[layout["tool_position"]] = msg.tool_position_measured
    vector[layout["q_commanded"]] = msg.joint_position_commanded
    return vector


class JointStatusDecoder(LeafSystem):
    r"""The newest telemetry message as a vector.

    .. pydrake_system::

        name: JointStatusDecoder
        input_ports:
        - lcm_message
        output_ports:
        - telemetry

    - ``lcm_message``: the newest ``lcmt_onboard_joint_status`` (a subscriber's output).
    - ``telemetry``: :func:`telemetry_vector` of it, (3J + 8,); NaN before the first
      message of this arm. Direct feedthrough, no state.
    """

    def __init__(self, *, num_joints: int):
        super().__init__()
        if num_joints < 1:
            raise ValueError(f"num_joints = {num_joints!r} must be positive")
        self._n = int(num_joints)
        self._message_input = self.DeclareAbstractInputPort(
            "lcm_message", AbstractValue.Make(lcmt_onboard_joint_status()))
        size = telemetry_layout(self._n)["q_commanded"].stop
        self._output = self.DeclareVectorOutputPort(
            "telemetry", size, lambda context, output: output.SetFromVector(
                telemetry_vector(self._message_input.Eval(context), self._n)))

    @property
    def layout(self) -> dict[str, slice]:
        return telemetry_layout(self._n)

    def get_lcm_message_input_port(self):
        return self._message_input

    def get_telemetry_output_port(self):
        return self._output
