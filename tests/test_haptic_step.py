"""The live haptic stream as a pure step (link.haptic), on hand-made message sequences with
known outcomes, and its state through the Context's vector."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from telesmooth.lcm_types import lcmt_teleop_haptic_command
from telesmooth.link.haptic import HapticInputs, haptic_flags, haptic_initial_state, haptic_step
from telesmooth.safety.state_codec import VectorCodec

POSE0 = [0.7, 0.0, 0.0]


def message(utime, pose=(0.6, 0.1, 0.2), enable=True, stop=False, num_axes=None, seq=1):
    msg = lcmt_teleop_haptic_command()
    msg.utime, msg.seq, msg.enable, msg.stop = utime, seq, enable, stop
    msg.pose_desired = list(pose)
    msg.num_axes = len(pose) if num_axes is None else num_axes
    return msg


def step(state, msg, now, undecodable=False):
    return haptic_step(state, HapticInputs(now=now, message=msg, undecodable=undecodable))


def test_a_valid_message_moves_the_hand_until_it_is_stale():
    state = step(haptic_initial_state(POSE0), message(10), now=1.0)
    np.testing.assert_array_equal(state.pose, [0.6, 0.1, 0.2])
    assert haptic_flags(state, 1.05, 0.1) == (True, False)
    assert haptic_flags(state, 1.11, 0.1) == (False, False)      # silent: clutch off
    # The same message again is not new: it does not refresh the clutch.
    assert step(state, message(10), now=1.5).arrived_s == 1.0


def test_the_default_message_and_a_bad_one_do_not_move_the_hand():
    state = step(haptic_initial_state(POSE0), lcmt_teleop_haptic_command(), now=0.5)
    assert not state.have_message and haptic_flags(state, 0.5, 0.1) == (False, False)
    state = step(state, message(11, enable=True, stop=True), now=1.0)
    assert haptic_flags(state, 1.0, 0.1) == (True, True)
    for bad in (message(12, pose=(0.1, math.nan, 0.0)), message(13, pose=(0.1, 0.2)),
                message(14, num_axes=0)):
        after = step(state, bad, now=1.01)
        assert after.rejected and haptic_flags(after, 1.01, 0.1) == (False, False)
        np.testing.assert_array_equal(after.pose, state.pose)      # the pose holds
    after = step(state, message(11), now=1.02, undecodable=True)
    assert after.rejected and haptic_flags(after, 1.02, 0.1) == (False, False)


def test_utimes_beyond_a_float64_compare_exactly():
    big = 2**62 + 1
    state = step(haptic_initial_state(POSE0), message(big), now=1.0)
    assert step(state, message(big), now=2.0).arrived_s == 1.0          # the same message
    # float(big + 1) == float(big), yet it is another message.
    assert step(state, message(big + 1), now=2.0).arrived_s == 2.0
    negative = step(state, message(-(2**63)), now=3.0)
    assert negative.arrived_s == 3.0 and step(negative, message(-(2**63)), 4.0).arrived_s == 3.0


@settings(max_examples=80, deadline=None)
@given(st.lists(st.tuples(st.integers(-(2**63), 2**63 - 1), st.booleans(), st.booleans(),
                          st.booleans()), max_size=12))
def test_the_state_survives_the_contexts_vector(stream):
    state = haptic_initial_state(POSE0)
    codec = VectorCodec(state)
    for k, (utime, enable, stop, undecodable) in enumerate(stream):
        state = step(state, message(utime, enable=enable, stop=stop), 0.01 * k, undecodable)
        again = codec.unpack(codec.pack(state))
        for name, value in state._asdict().items():
            np.testing.assert_array_equal(getattr(again, name), value, err_msg=name)
