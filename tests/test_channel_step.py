"""The in-process link as a pure step (link.channel), on hand-made polls: what is a new
packet, when a poll changes nothing, and the deliveries' numbering and window."""

from __future__ import annotations

from telesmooth.lcm_types import lcmt_teleop_joint_command
from telesmooth.link.channel import channel_counts, channel_initial_state, channel_step
from telesmooth.link.faults import LinkFaultConfig


def command(seq, session=7):
    msg = lcmt_teleop_joint_command()
    msg.seq, msg.session_id = seq, session
    return msg


def test_new_packets_arrive_after_the_delay_numbered_in_order():
    state = channel_initial_state(LinkFaultConfig(delay_s=0.05))
    assert channel_step(state, 0.0, command(-1), keep=3) is None      # the placeholder
    state = channel_step(state, 0.0, command(0), keep=3)
    assert state.delivered == () and channel_counts(state)["sent"] == 1
    assert channel_step(state, 0.01, command(0), keep=3) is None      # the same packet
    for k in range(1, 5):
        state = channel_step(state, 0.25 * k, command(k), keep=3)
    # Packet k arrives at 0.25 k + 0.05: at the poll of packet k + 1. Four delivered, the
    # last three kept, numbered from 1.
    assert [number for number, _ in state.delivered] == [2, 3, 4]
    assert channel_counts(state) == {"sent": 5, "delivered": 4, "lost": 0, "duplicated": 0,
                                     "held_back": 0}
    # A new session restarts nothing: (session, seq) is new.
    after = channel_step(state, 1.26, command(4, session=8), keep=3)
    assert channel_counts(after)["sent"] == 6
    # The step never changes the state it was given (its queue is copied before a send).
    assert channel_counts(state)["sent"] == 5
