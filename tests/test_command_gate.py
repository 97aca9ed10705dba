"""The robot's command gate as a pure step (safety.command_gate), on hand-made polls with
known outcomes: the ramp's start against ramp_desired_state, refusals counted once, the
issue instant used only within its bounds, and the state through the Context's vectors."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from telesmooth.safety.command_gate import (
    GateParams,
    gate_initial_state,
    gate_step,
    ramp_desired_state,
)
from telesmooth.safety.state_codec import VectorCodec

NAMES = ("shoulder", "elbow")
PARAMS = GateParams(joint_names=NAMES, lower_rad=np.array([-1.0, -2.0]),
                    upper_rad=np.array([1.0, 2.0]), interpolation="linear", ramp_duration_s=0.25)


def test_a_new_command_ramps_from_where_the_set_point_is():
    state, reason = gate_step(PARAMS, gate_initial_state([0.0, 0.0]), np.array([0.5, 1.0]),
                              now=1.0001, issued=1.0)
    assert reason is None and state.ramp.start_s == 1.0            # from its issue instant
    np.testing.assert_array_equal(state.ramp.target, [0.5, 1.0])
    # Mid-ramp, the next command starts from the set-point at its issue instant.
    after, _ = gate_step(PARAMS, state, np.array([0.0, 0.0]), now=1.1001, issued=1.1)
    expected, _ = ramp_desired_state([0.0, 0.0], [0.5, 1.0], 1.0, 0.25, 1.1)
    np.testing.assert_array_equal(after.ramp.start, expected)
    # An issue instant before the last ramp's start (or after now) is not used: now is.
    late, _ = gate_step(PARAMS, state, np.array([0.2, 0.2]), now=1.2, issued=0.9)
    assert late.ramp.start_s == 1.2
    step, _ = gate_step(dataclasses.replace(PARAMS, interpolation="zoh"), state,
                        np.array([0.2, 0.2]), now=1.2)
    np.testing.assert_array_equal(step.ramp.start, step.ramp.target)   # a step, no ramp


@pytest.mark.parametrize("bad, words", [([math.nan, 0.0], "is not finite"),
                                        ([0.0, 2.5], "outside the joint limits")])
def test_an_unsafe_command_is_refused_once_and_the_target_holds(bad, words):
    start = gate_initial_state([0.1, 0.2])
    state, reason = gate_step(PARAMS, start, np.array(bad), now=0.5)
    assert words in reason and state.refusals.rejected and state.refusals.count == 1
    np.testing.assert_array_equal(state.ramp.target, start.ramp.target)
    again, reason = gate_step(PARAMS, state, np.array(bad), now=0.51)
    assert reason is None and again.refusals.count == 1               # held: counted once
    cleared, _ = gate_step(PARAMS, again, np.array([0.1, 0.2]), now=0.52)   # the target
    assert not cleared.refusals.rejected and cleared.refusals.count == 1


def test_the_state_survives_the_contexts_vectors():
    state, _ = gate_step(PARAMS, gate_initial_state([0.1, 0.2]), np.array([math.nan, 0.0]),
                         now=0.5)
    for part in state:
        codec = VectorCodec(part)
        again = codec.unpack(codec.pack(part))
        for name, value in part._asdict().items():
            np.testing.assert_array_equal(getattr(again, name), value, err_msg=name)
