"""The compiled fixed-lag recursion and Online-CKS cycle (smoothing/fixed_lag_kernel.py).

The NumPy form (``OnlineCks`` and its ``FixedLagSmoother`` with their compiled paths switched
off) is the reference. The 4×4
products differ in summation order (BLAS's versus index order), so the estimates agree to
round-off, not bit for bit: relative to each state component's scale over the stream, within
1e-10 (measured: ~4e-15 on the bench's stream, up to ~3e-12 at lag 12 with random σ and r,
where the smoothed jerk cancels; the fixed-lag oracles of test_fixed_lag.py allow 1e-11); σ and
the triggers are the same.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from telesmooth.smoothing.model import JerkModel
from telesmooth.smoothing.reduced_q import OnlineCks, ReducedQConfig

RELATIVE = 1e-10


def _pair(joints, lag, config, sigma=4e-4, r=1e-6, dt=0.25, a_max=0.05, j_max=0.1):
    model = JerkModel.make(dt, sigma, r, num_joints=joints)
    compiled = OnlineCks(model, max_acceleration=a_max, max_jerk=j_max, lag=lag, config=config)
    reference = OnlineCks(model, max_acceleration=a_max, max_jerk=j_max, lag=lag,
                          config=config)
    reference._compiled = reference.smoother._compiled = None
    assert compiled._compiled is not None and compiled.smoother._compiled is not None
    return compiled, reference


def _assert_close(a, b):
    scale = np.maximum(np.abs(b).max(axis=0), 1e-300)
    assert np.all(np.abs(a - b) <= RELATIVE * scale), (np.abs(a - b) / scale).max()


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), joints=st.integers(1, 6),
       lag=st.sampled_from([0, 1, 3, 12]),
       trigger=st.sampled_from(["state", "fd"]),
       step_rule=st.sampled_from(["multiplicative", "additive"]),
       amplitude=st.sampled_from([1e-3, 0.1, 2.0]))
def test_compiled_cycle_matches_the_numpy_form(seed, joints, lag, trigger, step_rule,
                                               amplitude):
    rng = np.random.default_rng(seed)
    config = ReducedQConfig(trigger=trigger, step_rule=step_rule)
    compiled, reference = _pair(joints, lag, config,
                                sigma=rng.uniform(1e-6, 1e-2, joints),
                                r=rng.uniform(1e-8, 1e-4, joints))
    steps = 60
    z = np.cumsum(rng.normal(0.0, amplitude / 10, (steps, joints)), axis=0)
    z[steps // 2:] += rng.normal(0.0, amplitude, joints)      # a jump: triggers
    a, b = compiled.run(z), reference.run(z)
    _assert_close(a.outputs, b.outputs)
    np.testing.assert_array_equal(a.triggered, b.triggered)
    np.testing.assert_array_equal(a.sigma, b.sigma)
    _assert_close(a.final_state.smoother.blocks_scaled, b.final_state.smoother.blocks_scaled)
    _assert_close(a.final_state.smoother.covariance.reshape(joints, -1),
                  b.final_state.smoother.covariance.reshape(joints, -1))
    np.testing.assert_array_equal(a.final_state.sent_positions, a.outputs[-3:, :, 0])
    assert a.final_state.smoother.steps == steps


@pytest.mark.parametrize("trigger", ["state", "fd"])
def test_the_fused_cycle_equals_the_compiled_smoother_step_bit_for_bit(trigger):
    """OnlineCks's one-call cycle and its step-by-step form over the compiled smoother (the
    NumPy trigger and σ update) give the same floats: Online-CKS without triggers stays the
    fixed-lag smoother exactly (test_reduced_q.py)."""
    from telesmooth.scripts.bench_core import synthetic_operator

    z = synthetic_operator(300, 6, seed=2)
    compiled, _ = _pair(6, 3, ReducedQConfig(trigger=trigger))
    stepwise, _ = _pair(6, 3, ReducedQConfig(trigger=trigger))
    stepwise._compiled = None
    a, b = compiled.run(z), stepwise.run(z)
    assert a.triggered.any()
    for x, y in ((a.outputs, b.outputs), (a.sigma, b.sigma), (a.triggered, b.triggered),
                 (a.final_state.smoother.covariance, b.final_state.smoother.covariance),
                 (a.final_state.sent_positions, b.final_state.sent_positions)):
        assert x.tobytes() == y.tobytes()


def test_fixed_lag_smoother_compiled_matches_the_numpy_form_with_a_sigma_schedule():
    from telesmooth.smoothing.fixed_lag import FixedLagSmoother

    rng = np.random.default_rng(7)
    model = JerkModel.make(0.25, rng.uniform(1e-5, 1e-3, 4), 1e-6, num_joints=4)
    z = np.cumsum(rng.normal(0.0, 0.01, (80, 4)), axis=0)
    schedule = model.sigma * rng.uniform(0.01, 1.0, (80, 4))
    compiled = FixedLagSmoother(model, lag=5)
    reference = FixedLagSmoother(model, lag=5)
    reference._compiled = None
    for sigma in (None, schedule):
        _assert_close(compiled.run(z, sigma_schedule=sigma),
                      reference.run(z, sigma_schedule=sigma))
    assert FixedLagSmoother(model, lag=5, method="superstate")._compiled is None


def test_the_bench_stream_triggers_the_same_cycles():
    from telesmooth.scripts.bench_core import synthetic_operator

    z = synthetic_operator(600, 6, seed=1)
    compiled, reference = _pair(6, 3, ReducedQConfig())
    a, b = compiled.run(z), reference.run(z)
    assert a.triggered.any()
    np.testing.assert_array_equal(a.triggered, b.triggered)
    np.testing.assert_array_equal(a.sigma, b.sigma)
    _assert_close(a.outputs, b.outputs)


def test_only_variant_a_in_the_recursion_form_is_compiled():
    model = JerkModel.make(0.25, 4e-4, 1e-6, num_joints=2)
    for config, method in ((ReducedQConfig(variant="B1"), "recursion"),
                           (ReducedQConfig(variant="B2"), "recursion"),
                           (ReducedQConfig(), "superstate")):
        online = OnlineCks(model, max_acceleration=0.05, max_jerk=0.1, config=config,
                           method=method)
        assert online._compiled is None


def test_bad_measurements_raise_the_numpy_forms_error():
    compiled, reference = _pair(3, 3, ReducedQConfig())
    state = compiled.initial_state(np.zeros(3))
    for bad in ([0.0, np.nan, 0.0], [0.0, 0.0], [[0.0, 0.0, 0.0]]):
        with pytest.raises(ValueError) as from_compiled:
            compiled.step(state, bad)
        with pytest.raises(ValueError) as from_reference:
            reference.step(state, bad)
        assert str(from_compiled.value) == str(from_reference.value)


def test_a_state_of_another_lag_is_never_read_out_of_bounds():
    compiled, _ = _pair(3, 3, ReducedQConfig())
    other, _ = _pair(3, 1, ReducedQConfig())
    state = other.initial_state(np.zeros(3))
    assert compiled._step_compiled(state, np.zeros(3)) is None
    assert compiled.smoother._step_compiled(state.smoother, np.zeros(3), None) is None


def test_states_built_on_the_per_tick_path_are_the_dataclasses_own():
    import dataclasses

    from telesmooth.smoothing.fixed_lag import FixedLagState, frozen_instance
    from telesmooth.smoothing.reduced_q import OnlineCksState

    values = {"blocks_scaled": np.zeros((2, 4, 4)), "covariance": np.ones((2, 4, 4, 4)),
              "steps": 3, "smoother": "s", "sigma": np.full(2, 4e-4),
              "sent_positions": np.zeros((3, 2)), "window": ()}
    for cls in (FixedLagState, OnlineCksState):
        assert not hasattr(cls, "__post_init__")
        names = [f.name for f in dataclasses.fields(cls)]
        fields = {name: values[name] for name in names}
        fast, slow = frozen_instance(cls, **fields), cls(**fields)
        assert type(fast) is cls and vars(fast).keys() == vars(slow).keys()
        for name in names:
            assert getattr(fast, name) is getattr(slow, name)
        with pytest.raises(dataclasses.FrozenInstanceError):
            setattr(fast, names[0], None)


def test_the_compiled_paths_build_every_field():
    """frozen_instance is given every field on both compiled paths (a field added to the
    dataclasses later must be added there too)."""
    import dataclasses

    from telesmooth.smoothing.fixed_lag import FixedLagState
    from telesmooth.smoothing.reduced_q import OnlineCksState

    compiled, _ = _pair(2, 3, ReducedQConfig())
    state, _, _ = compiled.step(compiled.initial_state(np.zeros(2)), np.full(2, 0.01))
    for instance, cls in ((state, OnlineCksState), (state.smoother, FixedLagState)):
        assert set(vars(instance)) == {f.name for f in dataclasses.fields(cls)}
    smoother_state = compiled.smoother.step(state.smoother, np.zeros(2))
    assert set(vars(smoother_state)) == {f.name for f in dataclasses.fields(FixedLagState)}
