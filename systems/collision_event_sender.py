"""Pre-simulator collision/hold state as an ``lcmt_teleop_collision_event`` (translation)."""

from __future__ import annotations

from pydrake.common.value import AbstractValue
from pydrake.systems.framework import LeafSystem

from telesmooth.lcm_types import lcmt_teleop_collision_event

__all__ = ["CollisionEventSender"]


class CollisionEventSender(LeafSystem):
    r"""Packs the collision checker's and the FIFO's flags into a message.

    .. pydrake_system::

        name: CollisionEventSender
        input_ports:
        - collision_detected
        - holding
        - min_distance
        - sequence_number
        output_ports:
        - lcm_message

    All inputs are (1,) vectors: the checker's latched flag and distance (m), the FIFO's hold
    flag, and the uplink's packet number (so events line up with commands). utime is the
    context time in µs.
    """

    def __init__(self):
        super().__init__()
        self._collision_input = self.DeclareVectorInputPort("collision_detected", 1)
        self._holding_input = self.DeclareVectorInputPort("holding", 1)
        self._distance_input = self.DeclareVectorInputPort("min_distance", 1)
        self._sequence_input = self.DeclareVectorInputPort("sequence_number", 1)
        self._message_output = self.DeclareAbstractOutputPort(
            "lcm_message", lambda: AbstractValue.Make(lcmt_teleop_collision_event()),
            self._calc_lcm_message)

    def get_collision_detected_input_port(self):
        return self._collision_input

    def get_holding_input_port(self):
        return self._holding_input

    def get_min_distance_input_port(self):
        return self._distance_input

    def get_sequence_number_input_port(self):
        return self._sequence_input

    def get_lcm_message_output_port(self):
        return self._message_output

    def _calc_lcm_message(self, context, output):
        msg = lcmt_teleop_collision_event()
        msg.utime = int(round(context.get_time() * 1e6))
        msg.seq = int(round(self._sequence_input.Eval(context)[0]))
        msg.collision_detected = bool(self._collision_input.Eval(context)[0] > 0.5)
        msg.holding = bool(self._holding_input.Eval(context)[0] > 0.5)
        msg.min_distance_m = float(self._distance_input.Eval(context)[0])
        output.set_value(msg)
