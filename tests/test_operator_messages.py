"""The operator's LCM message readers (systems/operator_messages.py): no event reads as NaN
by the subscriber's count, never by guessing from the message's fields."""

from __future__ import annotations

import math

from pydrake.common.value import AbstractValue

from telesmooth.lcm_types import lcmt_teleop_collision_event
from telesmooth.systems.operator_messages import CollisionEventValues


def _values(message, count):
    system = CollisionEventValues()
    context = system.CreateDefaultContext()
    system.get_lcm_message_input_port().FixValue(context, AbstractValue.Make(message))
    if count is not None:
        system.get_message_count_input_port().FixValue(context, [count])
    return {name: system.GetOutput(name).Eval(context)[0]
            for name in ("collision_detected", "holding", "min_distance")}


def test_a_first_event_at_time_zero_in_contact_is_an_event():
    # seq 0, utime 0, distance 0: the ground's first event, at its start, touching. The
    # fields alone cannot tell it from no message; the count can.
    event = lcmt_teleop_collision_event()
    event.collision_detected = True
    event.holding = True
    assert _values(event, 1.0) == {"collision_detected": 1.0, "holding": 1.0,
                                   "min_distance": 0.0}


def test_no_message_yet_is_nan():
    for count in (0.0, None):
        assert all(math.isnan(v) for v in _values(lcmt_teleop_collision_event(), count).values())
