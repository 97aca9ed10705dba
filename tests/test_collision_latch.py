"""The pre-simulator's collision latch as a pure step (safety.collision_latch), against an
independent computation: a deque of the last N flags, and a query that counts its calls."""

from __future__ import annotations

import collections
import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from telesmooth.safety.collision_latch import (
    collision_detected,
    latch_initial_state,
    latch_step,
)
from telesmooth.safety.state_codec import VectorCodec

MARGIN = 0.01


class CountingQuery:
    """Distance = first joint (m), in collision below the margin; counts its calls."""

    def __init__(self):
        self.calls = 0

    def __call__(self, q):
        self.calls += 1
        return float(q[0]), float(q[0]) < MARGIN


def test_the_first_state_is_clear_and_the_latch_holds_n_samples():
    state = latch_initial_state(2, 3, 0.2)
    assert state.distance_m == 0.2 and collision_detected(state) == 0.0
    query = CountingQuery()
    stream = [[0.005, 0.0]] + [[0.1 + 0.01 * k, 0.0] for k in range(4)]
    seen = []
    for q in stream:
        state = latch_step(state, np.array(q), query=query, safety_margin_m=MARGIN)
        seen.append(collision_detected(state))
    # The collision at sample 0 shows for N = 3 samples, then clears.
    assert seen == [1.0, 1.0, 1.0, 0.0, 0.0]
    assert state.distance_m == 0.13 and query.calls == 5


def test_a_held_target_is_not_queried_again_and_a_nan_target_is_a_collision():
    query = CountingQuery()
    state = latch_initial_state(2, 2, 0.2)
    for _ in range(4):
        state = latch_step(state, np.array([0.05, 1.0]), query=query, safety_margin_m=MARGIN)
    assert query.calls == 1 and state.distance_m == 0.05
    state = latch_step(state, np.array([math.nan, 1.0]), query=query, safety_margin_m=MARGIN)
    assert state.distance_m == 0.0 and collision_detected(state) == 1.0
    assert np.all(np.isnan(state.checked_q))
    state = latch_step(state, None, query=query, safety_margin_m=MARGIN)   # no input
    assert collision_detected(state) == 1.0 and query.calls == 1
    # After a NaN the same finite target is queried again (nothing is checked).
    state = latch_step(state, np.array([0.05, 1.0]), query=query, safety_margin_m=MARGIN)
    assert query.calls == 2


@settings(max_examples=60, deadline=None)
@given(st.integers(1, 6), st.lists(st.one_of(st.none(), st.floats(-0.05, 0.3)), max_size=40))
def test_detected_is_any_collision_among_the_last_n_samples(n, stream):
    query = CountingQuery()      # distance = the sample; its count is not the point here
    state = latch_initial_state(1, n, 0.2)
    window = collections.deque([False] * n, maxlen=n)
    codec = VectorCodec(state)
    for value in stream:
        q = None if value is None else np.array([value])
        state = latch_step(state, q, query=query, safety_margin_m=MARGIN)
        window.append(value is None or value < MARGIN)
        assert collision_detected(state) == float(any(window))
        assert state.flags[-1] == float(window[-1])
        # The state survives the Context's vector unchanged.
        again = codec.unpack(codec.pack(state))
        assert again.distance_m == state.distance_m
        np.testing.assert_array_equal(again.flags, state.flags)
        np.testing.assert_array_equal(again.checked_q, state.checked_q)
