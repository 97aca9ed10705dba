"""The operator's process on the bus: its hand out, what the ground and the robot say in.

`telesmooth operator` is the console alone (docs/operator.md): it publishes the operator's
hand as a haptic device would, and reads the ground's packets and collision events and the
robot's telemetry for its display. Thin translations between vectors and LCM messages:

* :class:`HapticCommandSender`: pose, clutch and stop → ``lcmt_teleop_haptic_command``
  (what ``telesmooth ground`` with ``haptic: {source: lcm}`` reads);
* :class:`JointCommandPositions`: the newest ``lcmt_teleop_joint_command`` → its positions;
* :class:`CollisionEventValues`: the newest ``lcmt_teleop_collision_event`` → the
  pre-simulator's flag, the FIFO's hold and the distance.

Before a message arrives their outputs are NaN: nothing is invented.
"""

from __future__ import annotations

import math

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import LeafSystem

from telesmooth.lcm_types import (
    lcmt_teleop_collision_event,
    lcmt_teleop_haptic_command,
    lcmt_teleop_joint_command,
)
from telesmooth.systems.timing import check_period

__all__ = ["CollisionEventValues", "HapticCommandSender", "JointCommandPositions"]


class HapticCommandSender(LeafSystem):
    r"""The operator's hand as a haptic device's message.

    .. pydrake_system::

        name: HapticCommandSender
        input_ports:
        - pose_desired
        - enable
        - stop_requested
        output_ports:
        - lcm_message

    - ``pose_desired`` (m,), ``enable`` (1,), ``stop_requested`` (1,): the console's outputs.
    - ``lcm_message``: ``lcmt_teleop_haptic_command`` with utime = the context time (µs),
      seq = round(t / ``period_s``) (publish it every ``period_s``: gaps reveal drops),
      the pose, the clutch and the stop.
    """

    def __init__(self, *, num_axes: int, period_s: float = 0.01):
        super().__init__()
        check_period("HapticCommandSender.period_s", period_s)
        self._m = int(num_axes)
        self._period = float(period_s)
        self._pose_input = self.DeclareVectorInputPort("pose_desired", self._m)
        self._enable_input = self.DeclareVectorInputPort("enable", 1)
        self._stop_input = self.DeclareVectorInputPort("stop_requested", 1)
        self._output = self.DeclareAbstractOutputPort(
            "lcm_message", lambda: AbstractValue.Make(lcmt_teleop_haptic_command()),
            self._calc)

    def get_pose_desired_input_port(self):
        return self._pose_input

    def get_enable_input_port(self):
        return self._enable_input

    def get_stop_requested_input_port(self):
        return self._stop_input

    def get_lcm_message_output_port(self):
        return self._output

    def _calc(self, context, output):
        msg = lcmt_teleop_haptic_command()
        t = context.get_time()
        msg.utime = int(round(t * 1e6))
        msg.seq = int(round(t / self._period))
        msg.num_axes = self._m
        msg.pose_desired = [float(v) for v in self._pose_input.Eval(context)]
        msg.enable = bool(self._enable_input.Eval(context)[0] > 0.5)
        msg.stop = bool(self._stop_input.Eval(context)[0] > 0.5)
        output.set_value(msg)


class JointCommandPositions(LeafSystem):
    r"""The positions and sequence number of the newest uplink packet the ground sent (NaN
    before one).

    .. pydrake_system::

        name: JointCommandPositions
        input_ports:
        - lcm_message
        output_ports:
        - q_sent
        - sequence_number

    A packet of another arm (a joint count that is not ``num_joints``) reads as NaN.
    """

    def __init__(self, *, num_joints: int):
        super().__init__()
        self._n = int(num_joints)
        self._input = self.DeclareAbstractInputPort(
            "lcm_message", AbstractValue.Make(lcmt_teleop_joint_command()))
        self._output = self.DeclareVectorOutputPort("q_sent", self._n, self._calc)
        self._sequence_output = self.DeclareVectorOutputPort("sequence_number", 1,
                                                             self._calc_sequence)

    def get_lcm_message_input_port(self):
        return self._input

    def get_q_sent_output_port(self):
        return self._output

    def get_sequence_number_output_port(self):
        return self._sequence_output

    def _usable(self, msg) -> bool:
        return (len(msg.joint_position_smoothed) == self._n and msg.seq >= 0
                and msg.num_joints == self._n)

    def _calc_sequence(self, context, output):
        msg = self._input.Eval(context)
        output.SetAtIndex(0, float(msg.seq) if self._usable(msg) else math.nan)

    def _calc(self, context, output):
        msg = self._input.Eval(context)
        output.SetFromVector(np.asarray(msg.joint_position_smoothed, dtype=float)
                             if self._usable(msg) else np.full(self._n, np.nan))


class CollisionEventValues(LeafSystem):
    r"""The newest collision event of the ground (NaN before one).

    .. pydrake_system::

        name: CollisionEventValues
        input_ports:
        - lcm_message
        - message_count
        output_ports:
        - collision_detected
        - holding
        - min_distance

    ``message_count`` is the subscriber's count of messages received: with none (0, or the
    port unconnected) there is no event yet, whatever the held message's fields hold.
    """

    def __init__(self):
        super().__init__()
        self._input = self.DeclareAbstractInputPort(
            "lcm_message", AbstractValue.Make(lcmt_teleop_collision_event()))
        self._count_input = self.DeclareVectorInputPort("message_count", 1)
        self._outputs = {name: self.DeclareVectorOutputPort(
            name, 1, lambda context, output, name=name: output.SetAtIndex(
                0, self._values(context)[name])) for name in
            ("collision_detected", "holding", "min_distance")}

    def get_lcm_message_input_port(self):
        return self._input

    def get_message_count_input_port(self):
        return self._count_input

    def GetOutput(self, name: str):
        return self._outputs[name]

    def _values(self, context) -> dict:
        if not (self._count_input.HasValue(context) and self._count_input.Eval(context)[0] > 0):
            return dict.fromkeys(("collision_detected", "holding", "min_distance"), np.nan)
        msg = self._input.Eval(context)
        return {"collision_detected": float(msg.collision_detected),
                "holding": float(msg.holding), "min_distance": float(msg.min_distance_m)}
