"""What has arrived on one LCM channel as a pure step (``telesmooth.link.inbox``).

A script with known answers: the error text of each kind of bad packet, the newest good bytes
kept, an oversized packet refused unread, nothing new returns the state given. An oracle: a
plain loop over packets labelled when they were made (good or not) gives the counts, the flag,
the newest good bytes and the window. Over random streams the step agrees with the oracle,
the counts round-trip through the Context's codec, and the step returns the state it is
given exactly when nothing changed. And
:class:`~telesmooth.systems.lcm_safe_subscriber.LcmSafeSubscriber`'s outputs equal the step's
run on the same packets.
"""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from telesmooth.lcm_types import lcmt_teleop_haptic_command, lcmt_teleop_joint_command
from telesmooth.lcm_types.channels import TELEOP_JOINT_COMMAND
from telesmooth.link.inbox import (
    RECENT_PACKETS,
    InboxState,
    Packets,
    inbox_initial_state,
    inbox_params,
    inbox_step,
    nothing_new,
)
from telesmooth.safety.state_codec import VectorCodec

MAX_BYTES = 300
WINDOW = 5
PARAMS = inbox_params(TELEOP_JOINT_COMMAND, lcmt_teleop_joint_command, MAX_BYTES, WINDOW)
FINGERPRINT = lcmt_teleop_joint_command._get_packed_fingerprint()


def _command(seq, joints=2):
    msg = lcmt_teleop_joint_command()
    msg.seq, msg.utime, msg.sample_utime = seq, seq * 250_000, seq * 250_000
    msg.num_joints = joints
    msg.joint_name = [f"j{i}" for i in range(joints)]
    msg.joint_position_smoothed = [0.1 * seq + i for i in range(joints)]
    msg.joint_velocity_smoothed = [0.0] * joints
    return msg.encode()


def _haptic():
    msg = lcmt_teleop_haptic_command()
    msg.utime, msg.num_axes, msg.pose_desired, msg.enable = 3, 3, [0.7, 0.1, 0.2], True
    return msg.encode()


# Packets labelled when made: True for a message of the channel's type within the bound.
POOL = ([(_command(k), True) for k in range(4)]
        + [(b"garbage", False), (b"", False), (_command(1)[:-3], False), (_haptic(), False),
           (FINGERPRINT + b"\x00" * 20 + b"\x7f\xff\xff\xff", False),
           (_command(7, joints=40), False), (b"\xff" * (MAX_BYTES + 1), False)])


def test_the_pool_is_what_its_labels_say():
    assert all(len(data) <= MAX_BYTES for data, good in POOL if good)
    assert len(_command(7, joints=40)) > MAX_BYTES      # a good message, but oversized


def _oracle(packets, window):
    """The rule the module states, as a plain loop over labelled packets."""
    good = bad = 0
    newest_bad, message, recent = False, b"", []
    for number, (data, label) in enumerate(packets, start=1):
        recent.append((number, b"" if len(data) > MAX_BYTES else data))
        if label:
            good, newest_bad, message = good + 1, False, data
        else:
            bad, newest_bad = bad + 1, True
    return good, bad, newest_bad, message, recent[-window:]


def test_a_script_of_packets():
    state = inbox_initial_state()
    assert inbox_step(PARAMS, state, [], math.nan) is state          # nothing new
    state = inbox_step(PARAMS, state, [_command(0), _command(0)], math.nan)   # a duplicate
    assert state.counts[:3] == (2, 0, False) and state.message_bytes == _command(0)
    assert state.recent == ((1, _command(0)), (2, _command(0))) and state.last_error == ""
    state = inbox_step(PARAMS, state, [b"abc"], math.nan)
    assert state.counts[:3] == (2, 1, True) and state.message_bytes == _command(0)
    assert state.last_error == (f"{TELEOP_JOINT_COMMAND}: packet 3 (3 bytes) is not a valid "
                                "lcmt_teleop_joint_command: shorter than the 8-byte type "
                                "fingerprint (starts b'abc')")
    other = _haptic()
    state = inbox_step(PARAMS, state, [_command(1), other], math.nan)
    assert state.counts[:3] == (3, 2, True) and state.message_bytes == _command(1)
    assert state.last_error.endswith(f"packet 5 ({len(other)} bytes) is not a valid "
                                     f"lcmt_teleop_joint_command: type fingerprint "
                                     f"{other[:8].hex()} is not {FINGERPRINT.hex()} (another "
                                     "message type on this channel, or garbage)")
    big = _command(2, joints=40)
    state = inbox_step(PARAMS, state, [big], 4.0)
    assert state.counts == (3, 3, True, 4.0)
    assert state.last_error.endswith(f"packet 6 ({len(big)} bytes) is not a valid "
                                     f"lcmt_teleop_joint_command: {len(big)} bytes, more than "
                                     f"the {MAX_BYTES}-byte bound of a message (not decoded)")
    # The window: the last WINDOW packets; the oversized one as an empty stand-in.
    assert state.recent == ((2, _command(0)), (3, b"abc"), (4, _command(1)), (5, other),
                            (6, b""))
    assert type(state.recent) is Packets
    # Only the drop count changed: a new state; the same count: the same state.
    assert inbox_step(PARAMS, state, [], 4.0) is state
    dropped = inbox_step(PARAMS, state, [], 5.0)
    assert dropped is not state and dropped == state._replace(
        counts=state.counts._replace(dropped_count=5.0))
    body = FINGERPRINT + b"\x00" * 20 + b"\x7f\xff\xff\xff"
    state = inbox_step(PARAMS, state, [body], 4.0)
    assert "the body does not decode (" in state.last_error and state.counts[:3] == (3, 4, True)


def test_the_step_matches_the_oracle_on_a_fixed_stream():
    stream = [POOL[i] for i in (0, 0, 4, 9, 1, 10, 5, 2, 6, 7, 8, 3, 3)]
    state = inbox_initial_state(dropped_count=0.0)
    for k in range(0, len(stream), 3):
        state = inbox_step(PARAMS, state, [data for data, _ in stream[k:k + 3]], float(k))
    good, bad, newest_bad, message, recent = _oracle(stream, WINDOW)
    assert state.counts == (good, bad, newest_bad, 12.0) == (6, 7, False, 12.0)
    assert state.message_bytes == message == _command(3)
    assert list(state.recent) == recent


def test_only_the_counts_fit_a_float_vector():
    state = inbox_step(PARAMS, inbox_initial_state(), [b"junk", _command(1)], 2.0)
    with pytest.raises(TypeError):
        VectorCodec(state)          # bytes and text: the system keeps those as abstract states
    codec = VectorCodec(state.counts)
    np.testing.assert_array_equal(codec.pack(state.counts), [1.0, 1.0, 0.0, 2.0])
    assert codec.unpack(codec.pack(state.counts)) == state.counts


@settings(derandomize=True, database=None, deadline=None, max_examples=60)
@given(batches=st.lists(st.tuples(st.lists(st.integers(0, len(POOL) - 1), max_size=7),
                                  st.sampled_from([math.nan, 0.0, 1.0, 3.0])),
                        min_size=1, max_size=12))
def test_random_streams_agree_with_the_oracle_and_round_trip(batches):
    state = inbox_initial_state()
    codec = VectorCodec(state.counts)
    seen = []
    for indices, dropped in batches:
        vector = codec.pack(state.counts)
        given_state = InboxState(codec.unpack(vector), *state[1:])
        np.testing.assert_array_equal(codec.pack(given_state.counts), vector)
        state = inbox_step(PARAMS, given_state, [POOL[i][0] for i in indices], dropped)
        unchanged = not indices and (given_state.counts.dropped_count == dropped or (
            math.isnan(dropped) and math.isnan(given_state.counts.dropped_count)))
        assert (state is given_state) == unchanged
        seen += [POOL[i] for i in indices]
        good, bad, newest_bad, message, recent = _oracle(seen, WINDOW)
        assert state.counts[:3] == (good, bad, newest_bad)
        np.testing.assert_array_equal(state.counts.dropped_count, dropped)
        assert state.message_bytes == message and list(state.recent) == recent
        assert [n for n, _ in state.recent] == list(range(len(seen) + 1 - len(recent),
                                                          len(seen) + 1))
        assert (state.last_error == "") == (bad == 0)


def test_the_drake_subscriber_outputs_what_the_step_gives():
    import lcm as lcm_module
    from pydrake.systems.analysis import Simulator
    from pydrake.systems.framework import DiagramBuilder

    from telesmooth.systems.lcm_safe_subscriber import LcmSafeSubscriber

    bus = lcm_module.LCM("memq://")
    builder = DiagramBuilder()
    dut = builder.AddSystem(LcmSafeSubscriber(channel=TELEOP_JOINT_COMMAND,
                                              lcm_type=lcmt_teleop_joint_command, lcm=bus,
                                              max_message_bytes=MAX_BYTES))
    simulator = Simulator(builder.Build())
    simulator.Initialize()
    context = dut.GetMyContextFromRoot(simulator.get_context())
    params = inbox_params(TELEOP_JOINT_COMMAND, lcmt_teleop_joint_command, MAX_BYTES)
    assert params.window == RECENT_PACKETS
    state = inbox_initial_state()
    rng = np.random.default_rng(3)
    for step in range(40):
        batch = [POOL[i][0] for i in rng.integers(0, len(POOL), rng.integers(0, 9))]
        for data in batch:
            bus.publish(TELEOP_JOINT_COMMAND, data)
        simulator.AdvanceTo(0.01 * (step + 1))
        state = inbox_step(params, state, batch, math.nan)
        message = dut.get_lcm_message_output_port().Eval(context)
        assert message.encode() == (state.message_bytes or lcmt_teleop_joint_command().encode())
        counts = [dut.get_output_port(i).Eval(context)[0] for i in (1, 2, 3, 6)]
        np.testing.assert_array_equal(counts, list(state.counts))
        assert dut.get_last_decode_error_output_port().Eval(context) == state.last_error
        assert dut.get_packets_output_port().Eval(context) == state.recent
    assert state.counts.message_count > 0 and state.counts.undecodable_count > 0
    assert len(state.recent) > WINDOW


def test_nothing_new_is_no_payload_and_the_same_drop_count():
    assert nothing_new(math.nan, [], math.nan)
    assert nothing_new(3.0, [], 3.0)
    assert not nothing_new(3.0, [], 4.0)
    assert not nothing_new(math.nan, [], 0.0)
    assert not nothing_new(0.0, [], math.nan)
    assert not nothing_new(3.0, [b""], 3.0)
