"""The onboard packet receiver's pure step (``telesmooth.link.receiver``), without Drake.

Packets are built here and signed with the uplink key; each script says, packet by packet,
what class it is and what the robot's command is afterwards:

* every class counted once per packet, in :class:`PacketClass` order, the flag raised by the
  flagged classes only and cleared by the next accepted packet;
* a packet already examined (its arrival index) is not examined again; the newest accepted
  packet of a poll wins it;
* the timeout counts from the last accepted packet (from t = 0 before the first);
* the newest-message mode examines a message once, ignores the default message and raises
  the flag on ``undecodable``;
* over random streams: the state round-trips through the Context's codec and the step
  never changes the state it is given (the JointCommandReceiver system holds the state the
  step returns: tests/test_fuzz_joint_command_receiver.py checks it against a model).
"""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from telesmooth.lcm_types import lcmt_teleop_joint_command
from telesmooth.link.auth import sign
from telesmooth.link.receiver import (
    FLAGGED,
    REJECTION_CLASSES,
    PacketClass,
    ReceiverInputs,
    ReceiverParams,
    RejectionCounts,
    receiver_initial_state,
    receiver_step,
)
from telesmooth.link.session import session_id
from telesmooth.safety.state_codec import VectorCodec

JOINTS = ("shoulder", "elbow")
LOWER, UPPER = np.array([-1.0, -2.0]), np.array([1.0, 2.0])
KEY = bytes(range(32))
EPOCH = 77
SESSION = session_id(1, 5)
Q0 = np.array([0.1, 0.2])


def _params(key=KEY):
    return ReceiverParams(joint_names=JOINTS, lower_rad=LOWER, upper_rad=UPPER, key=key,
                          onboard_epoch=EPOCH, timeout_s=1.0)


def _message(seq, positions=(0.3, 0.4), *, session=SESSION, epoch=EPOCH, names=JOINTS):
    msg = lcmt_teleop_joint_command()
    msg.seq, msg.session_id, msg.onboard_epoch = seq, session, epoch
    msg.num_joints = len(names)
    msg.joint_name = list(names)
    msg.joint_position_smoothed = list(positions)
    msg.joint_velocity_smoothed = [0.0] * len(names)
    return msg


def _packet(seq, positions=(0.3, 0.4), **kwargs):
    return sign(_message(seq, positions, **kwargs), KEY).encode()


def test_the_classes_are_the_counts_order():
    assert REJECTION_CLASSES == ("invalid", "auth", "duplicate", "stale", "undecodable",
                                 "session")
    assert RejectionCounts._fields == REJECTION_CLASSES
    assert {kind.label for kind in FLAGGED} == {"invalid", "auth", "undecodable", "session"}


# (packet bytes, its class, the command after it)
SCRIPT = [
    (_packet(0, (0.3, 0.4)), PacketClass.ACCEPTED, (0.3, 0.4)),
    (_packet(0, (0.3, 0.4)), PacketClass.DUPLICATE, (0.3, 0.4)),
    (_packet(2, (0.5, 0.6)), PacketClass.ACCEPTED, (0.5, 0.6)),
    (_packet(1, (0.9, 0.9)), PacketClass.STALE, (0.5, 0.6)),
    (_packet(3, (5.0, 0.0)), PacketClass.INVALID, (0.5, 0.6)),            # outside [−1, 1]
    (_message(4).encode(), PacketClass.AUTH, (0.5, 0.6)),                  # unsigned
    (_packet(5, epoch=EPOCH + 1), PacketClass.SESSION, (0.5, 0.6)),        # another run
    (b"\x00\x01garbage", PacketClass.UNDECODABLE, (0.5, 0.6)),
    (_packet(6, (0.7, 0.8)), PacketClass.ACCEPTED, (0.7, 0.8)),
    (_packet(7, names=("elbow", "shoulder")), PacketClass.INVALID, (0.7, 0.8)),
    (_packet(0, (0.0, 0.1), session=session_id(2, 9)), PacketClass.ACCEPTED, (0.0, 0.1)),
    (_packet(0, (0.2, 0.2), session=session_id(4, 9)), PacketClass.SESSION, (0.0, 0.1)),
]


def test_each_packet_is_classified_counted_and_flagged_one_poll_each():
    params = _params()
    state = receiver_initial_state(Q0)
    expected = dict.fromkeys(REJECTION_CLASSES, 0)
    accepted = 0
    for index, (data, kind, command) in enumerate(SCRIPT):
        before = state
        state, rejections = receiver_step(params, state,
                                          ReceiverInputs(now=0.1 * index,
                                                         packets=((index, data),)))
        if kind == PacketClass.ACCEPTED:
            accepted += 1
            assert rejections == () and not state.rejected
            assert state.last_time == pytest.approx(0.1 * index)
        else:
            expected[kind.label] += 1
            assert [r.kind for r in rejections] == [kind]
            assert str(rejections[0]).startswith(kind.label + ": ")
            assert state.rejected == (kind in FLAGGED or before.rejected)
        np.testing.assert_array_equal(state.command, command)
        assert state.counts._asdict() == expected and state.accepted == accepted
        assert state.last_packet == index


def test_an_examined_packet_is_not_examined_again_and_the_newest_accepted_wins():
    params = _params()
    window = ((0, _packet(0, (0.3, 0.3))), (1, _packet(1, (0.4, 0.4))))
    state, _ = receiver_step(params, receiver_initial_state(Q0),
                             ReceiverInputs(now=0.0, packets=window))
    np.testing.assert_array_equal(state.command, (0.4, 0.4))
    assert (state.accepted, state.last_seq) == (2, 1)
    # The same window again (a subscriber keeps the recent packets): nothing new.
    again, rejections = receiver_step(params, state, ReceiverInputs(now=0.01, packets=window))
    assert rejections == () and again.accepted == 2 and again.counts == RejectionCounts()


def test_the_timeout_counts_from_the_last_accepted_packet():
    params = _params()
    state, _ = receiver_step(params, receiver_initial_state(Q0), ReceiverInputs(now=1.0))
    assert not state.timeout                      # exactly 1 s after t = 0: not more
    state, _ = receiver_step(params, state, ReceiverInputs(now=1.01))
    assert state.timeout
    state, _ = receiver_step(params, state,
                             ReceiverInputs(now=2.0, packets=((0, _packet(0)),)))
    assert not state.timeout
    state, _ = receiver_step(params, state, ReceiverInputs(now=3.02, packets=()))
    assert state.timeout


def test_the_newest_message_mode():
    params = _params(key=None)
    state = receiver_initial_state(Q0)
    state, _ = receiver_step(params, state,
                             ReceiverInputs(now=0.0, message=lcmt_teleop_joint_command()))
    assert state.accepted == 0 and state.counts == RejectionCounts()   # the default: nothing
    message = _message(3, (0.5, 0.5))
    state, _ = receiver_step(params, state, ReceiverInputs(now=0.01, message=message))
    assert state.accepted == 1 and (state.examined_session, state.examined_seq) == (SESSION, 3)
    state, rejections = receiver_step(params, state, ReceiverInputs(now=0.02, message=message))
    assert state.accepted == 1 and rejections == ()      # held again: not examined again
    state, _ = receiver_step(params, state,
                             ReceiverInputs(now=0.03, message=message, undecodable=True))
    assert state.rejected and state.accepted == 1


kinds = st.sampled_from(["good", "duplicate", "stale", "invalid", "unsigned", "garbage"])


@settings(derandomize=True, database=None, deadline=None, max_examples=30)
@given(stream=st.lists(st.tuples(kinds, st.floats(-0.9, 0.9)), min_size=1, max_size=25))
def test_codec_round_trip_and_purity_over_streams(stream):
    params = _params()
    state = receiver_initial_state(Q0)
    codec = VectorCodec(state)
    seq = 0
    for index, (kind, x) in enumerate(stream):
        if kind == "good":
            seq += 1
        data = {"good": _packet(seq, (x, -x)), "duplicate": _packet(seq, (x, -x)),
                "stale": _packet(seq - 1, (x, x)), "invalid": _packet(seq + 1, (x, 3.0)),
                "unsigned": _message(seq + 1).encode(), "garbage": bytes([index % 256])}[kind]
        vector = codec.pack(state)
        given_state = codec.unpack(vector)
        np.testing.assert_array_equal(codec.pack(given_state), vector)
        state, _ = receiver_step(params, given_state,
                                 ReceiverInputs(now=0.01 * index, packets=((index, data),)))
        np.testing.assert_array_equal(codec.pack(given_state), vector)   # not changed
        assert sum(state.counts) + state.accepted <= index + 1
        assert np.all((LOWER <= state.command) & (state.command <= UPPER))
