"""The compiled limiter tick (safety/limiter_kernel.py) gives the array form's floats bit for bit.

The array form (``limiter._step_arrays``, NumPy over joints) is the reference: every tick the
compiled path takes is also computed by the array form from the same state and compared
byte for byte (command, nominal velocity and acceleration, sent history, target history,
held joints, outcome). States come from streams through the limiter (jumps, holds, reversals,
ramps within the limits, lookahead with and without non-finite columns, both rules, with and
without a velocity limit, 1 to 6 joints, 4 Hz and 10 Hz), and from adversarial histories far
outside the stoppable set (the projection and the empty-interval midpoint).
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from telesmooth.safety import limiter
from telesmooth.safety.limiter import (
    LimiterOutcome,
    limiter_moving_state,
    limiter_params,
    limiter_rest_state,
    limiter_step,
)

# A few limit sets (the stoppable polygons are cached by limits, so each is computed once).
LIMITS = [
    dict(dt_s=0.25, max_acceleration=0.05, max_jerk=0.1),                       # the bench's
    dict(dt_s=0.25, max_acceleration=0.05, max_jerk=0.1, max_velocity=0.1),
    dict(dt_s=0.25, max_acceleration=[0.05, 0.2, 0.01, 0.05, 0.3, 0.02],
         max_jerk=[0.1, 0.05, 0.02, 0.4, 0.1, 0.01], max_velocity=[0.1, 0.3, np.inf, 0.02,
                                                                   0.5, 0.05]),
    dict(dt_s=0.1, max_acceleration=0.5, max_jerk=2.0, max_velocity=0.8),
]


def _params(index: int, joints: int, rule: str):
    limits = dict(LIMITS[index])
    for key in ("max_acceleration", "max_jerk", "max_velocity"):
        if isinstance(limits.get(key), list):
            limits[key] = limits[key][:joints]
    return limiter_params(num_joints=joints, rule=rule, **limits)


def _bytes(state, command):
    return (state.position.tobytes(), state.velocity.tobytes(), state.acceleration.tobytes(),
            np.ascontiguousarray(state.sent).tobytes(),
            np.ascontiguousarray(state.targets).tobytes(), state.held.tobytes(),
            int(state.ticks), state.outcome, command.tobytes())


def _compare_tick(params, state, target, lookahead=None):
    """Both forms from the same state: the compiled one (if it takes the tick) must equal
    the array form byte for byte. Returns the array form's result and whether the compiled
    path took the tick."""
    r = np.asarray(target, dtype=float)
    future = None if lookahead is None else np.asarray(lookahead, dtype=float)
    reference = limiter._step_arrays(params, state, r, future)
    compiled = limiter._step_compiled(params, state, r, future)
    if compiled is not None:
        assert _bytes(*compiled) == _bytes(*reference)
    return reference, compiled is not None


def _stream(rng, joints: int, ticks: int, scale: float):
    """Targets that jump, hold, reverse and ramp (rad)."""
    kind = rng.integers(4)
    if kind == 0:          # jumps between random levels
        levels = rng.normal(0.0, scale, (ticks // 8 + 1, joints))
        return np.repeat(levels, 8, axis=0)[:ticks]
    if kind == 1:          # random walk
        return np.cumsum(rng.normal(0.0, scale / 10, (ticks, joints)), axis=0)
    if kind == 2:          # square wave (reversals)
        sign = np.where((np.arange(ticks) // rng.integers(2, 12)) % 2 == 0, 1.0, -1.0)
        return sign[:, None] * rng.uniform(0.0, scale, joints)[None, :]
    # slow ramp, within the limits for most joints: exact ticks
    return np.outer(np.arange(ticks) * 1e-4, rng.uniform(-1.0, 1.0, joints))


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), index=st.integers(0, len(LIMITS) - 1),
       joints=st.integers(1, 6), rule=st.sampled_from(limiter.RULES),
       scale=st.sampled_from([1e-3, 0.05, 0.5, 3.0]), lag=st.sampled_from([0, 1, 2, 3]))
def test_compiled_tick_equals_the_array_form_on_streams(seed, index, joints, rule, scale, lag):
    rng = np.random.default_rng(seed)
    params = _params(index, joints, rule)
    ticks = 40
    targets = _stream(rng, joints, ticks + lag, scale)
    state = limiter_rest_state(params, targets[0] * rng.uniform(0.0, 1.0))
    taken = 0
    for k in range(ticks):
        target = targets[k].copy()
        lookahead = targets[k + 1:k + 1 + lag].copy() if lag else None
        if rng.random() < 0.05:        # a non-finite target: the array form brakes
            target[rng.integers(joints)] = rng.choice([np.nan, np.inf, -np.inf])
        if lookahead is not None and rng.random() < 0.2:   # a non-finite lookahead column
            lookahead[rng.integers(lag), rng.integers(joints)] = np.nan
        (state, _), took = _compare_tick(params, state, target, lookahead)
        taken += took
    assert taken > 0


@settings(max_examples=80, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), index=st.integers(0, len(LIMITS) - 1),
       joints=st.integers(1, 6), rule=st.sampled_from(limiter.RULES),
       spread=st.sampled_from([1e-6, 1e-3, 0.1, 10.0]))
def test_compiled_tick_equals_the_array_form_from_adversarial_states(
        seed, index, joints, rule, spread):
    """Histories whose FD state lies anywhere (also far outside S: the projection, an empty
    jerk interval), targets near and far, with ±0.0 and exact repeats."""
    rng = np.random.default_rng(seed)
    params = _params(index, joints, rule)
    for _ in range(10):
        history = np.cumsum(rng.normal(0.0, spread, (3, joints)), axis=0)
        if rng.random() < 0.3:
            history[:, rng.integers(joints)] = rng.choice([0.0, -0.0])
        previous = history[-1] + rng.normal(0.0, spread, (2, joints))
        state = limiter_moving_state(params, history, previous)
        for target in (history[-1], previous[-1], previous[-1] + rng.normal(0.0, spread, joints),
                       -history[-1], np.zeros(joints), np.full(joints, -0.0),
                       history[-1] + rng.normal(0.0, 1e3 * spread, joints)):
            lookahead = (previous[-1] + rng.normal(0.0, spread, (rng.integers(1, 4), joints))
                         if rng.random() < 0.5 else None)
            (after, _), _ = _compare_tick(params, state, target, lookahead)
            _compare_tick(params, after, target, lookahead)     # and one tick later


def test_the_bench_stream_runs_compiled_bit_for_bit():
    """The benchmark's stream (6 joints, braking on almost every tick) through both rules and
    with the smoother's lookahead: every tick compiled, every tick equal."""
    from telesmooth.scripts.bench_core import synthetic_operator

    z = synthetic_operator(400, 6, seed=1)
    for rule in limiter.RULES:
        for lag in (0, 3):
            params = _params(0, 6, rule)
            state = limiter_rest_state(params, z[0])
            outcomes = set()
            for k in range(len(z) - lag):
                lookahead = z[k + 1:k + 1 + lag] if lag else None
                (state, _), took = _compare_tick(params, state, z[k], lookahead)
                assert took
                outcomes.add(state.outcome)
            assert LimiterOutcome.LIMITED in outcomes


def test_non_finite_targets_and_misshapen_states_are_left_to_the_array_form():
    params = _params(1, 3, "braking")
    state = limiter_rest_state(params, np.zeros(3))
    for bad in (np.nan, np.inf, -np.inf):
        target = np.array([0.1, bad, 0.0])
        assert limiter._step_compiled(params, state, target, None) is None
        new_state, command = limiter_step(params, state, target)
        assert new_state.outcome == LimiterOutcome.BRAKING and np.all(np.isfinite(command))
    # A state whose arrays do not fit the parameters is never read out of bounds by the
    # kernel: the array form gets it (and fails the way it always did).
    short = state._replace(sent=state.sent[:, :2])
    assert limiter._step_compiled(params, short, np.zeros(3), None) is None
    with pytest.raises(ValueError):
        limiter_step(params, short, np.zeros(3))
    flat = state._replace(targets=state.targets.ravel())        # another number of dimensions
    assert limiter._step_compiled(params, flat, np.zeros(3), None) is None


def test_non_contiguous_and_readonly_arrays_are_accepted():
    params = _params(0, 6, "braking")
    state = limiter_rest_state(params, np.zeros(6))
    wide = np.zeros((6, 4))
    wide[:, 0] = 0.01
    target = wide[:, 0]                         # a strided view
    frozen = state._replace(position=state.position.copy())
    frozen.position.flags.writeable = False
    for s in (state, frozen):
        (_, _), took = _compare_tick(params, s, target)
        assert took


def test_kernel_constants_are_the_limiters():
    from telesmooth.safety import limiter_kernel

    assert limiter_kernel.BAND_TOLERANCE == limiter._BAND_TOLERANCE
    assert limiter._GRID.shape == (limiter._GRID_POINTS,)
