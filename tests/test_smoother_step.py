"""The online smoother's pure step (``telesmooth.smoothing.smoother_step``): what the tick does
around the Online-CKS core, each against a value computed here, and the ReducedQSmoother system
holding what the step returns."""

import numpy as np
import pytest
from core_fixtures import operator_recording
from hypothesis import given, settings
from hypothesis import strategies as st

from telesmooth.safety.limiter import limiter_params
from telesmooth.smoothing.model import JerkModel
from telesmooth.smoothing.reduced_q import OnlineCks
from telesmooth.smoothing.smoother_step import (
    SmootherStepParams,
    SmootherStepStateVector,
    smoother_initial_state,
    smoother_step,
)

DT, LAG, A_MAX, J_MAX = 0.25, 3, 0.02, 0.04
Q0 = np.array([0.3, -0.2])


def _params(method="online-cks"):
    limits = method in ("online-cks", "online-hard")
    online = OnlineCks(JerkModel.make(DT, 4e-4, 1e-6, num_joints=2),
                       max_acceleration=A_MAX if limits else np.inf,
                       max_jerk=J_MAX if limits else np.inf, lag=LAG)
    limiter = None if method != "online-hard" else limiter_params(
        dt_s=DT, max_acceleration=A_MAX, max_jerk=J_MAX, num_joints=2)
    return SmootherStepParams(online=online, pass_through=method == "original",
                              limiter=limiter, period_s=DT)


def _run(params, samples, resets=()):
    state = smoother_initial_state(params, Q0)
    codec = SmootherStepStateVector(params, state)
    ticks = []
    for k, z in enumerate(samples):
        given = codec.pack(state)
        tick = smoother_step(params, state, z, k in resets)
        # The step returns a new state: the one it was given still packs as it did.
        np.testing.assert_array_equal(codec.pack(state), given)
        state = tick.state
        ticks.append(tick)
    return ticks


def test_pass_through_sends_the_sample_l_ticks_old_at_rest():
    z = operator_recording(num_samples=12, num_joints=2, seed=3) + Q0
    ticks = _run(_params("original"), z)
    delayed = np.vstack([np.tile(Q0, (LAG, 1)), z])[:len(z)]
    for k, tick in enumerate(ticks):
        np.testing.assert_array_equal(tick.output[:, 0], delayed[k])
        np.testing.assert_array_equal(tick.output[:, 1:], 0.0)


def test_bmfls_never_changes_sigma_nor_triggers():
    z = operator_recording(num_samples=20, num_joints=2, seed=4, noise=5e-2) + Q0
    params = _params("bmfls")
    sigma0 = smoother_initial_state(params, Q0).online.sigma
    for tick in _run(params, z):
        np.testing.assert_array_equal(tick.state.online.sigma, sigma0)
        assert not tick.triggered.any()


@pytest.mark.parametrize("method", ["online-cks", "online-hard"])
def test_a_reset_restarts_at_rest_at_the_sample_and_keeps_sigma(method):
    z = operator_recording(num_samples=14, num_joints=2, seed=5, noise=5e-2) + Q0
    params = _params(method)
    ticks = _run(params, z, resets={8})
    sigma_before = ticks[7].state.online.sigma
    assert np.any(sigma_before < _run(params, z[:1])[0].state.online.sigma), \
        "the stream should have lowered σ before the reset (else the test proves nothing)"
    # Written here: a fresh smoother at rest at z_8 with the σ carried, fed z_8, z_9, ...
    fresh = smoother_initial_state(params, z[8], sigma_before)
    for k in range(8, 14):
        expected = smoother_step(params, fresh, z[k], False)
        np.testing.assert_array_equal(ticks[k].output, expected.output)
        fresh = expected.state
    np.testing.assert_array_equal(ticks[8].state.raw, np.tile(z[8], (LAG + 1, 1)))


def test_a_non_finite_sample_holds_at_the_last_sent_position_at_rest():
    z = operator_recording(num_samples=10, num_joints=2, seed=6) + Q0
    z[6] = [np.nan, 0.1]
    ticks = _run(_params(), z)
    held = ticks[5].state.online   # the state after tick 5: its smoothed position is sent at 6
    np.testing.assert_array_equal(ticks[6].output[:, 0],
                                  _params().online.smoother.output(held.smoother)[:, 0])
    np.testing.assert_array_equal(ticks[6].output[:, 1:], 0.0)
    assert all(np.all(np.isfinite(tick.output)) for tick in ticks)


def test_online_hard_sends_the_limiters_motion_with_its_third_difference():
    z = operator_recording(num_samples=30, num_joints=2, seed=7, noise=2e-2) + Q0
    ticks = _run(_params("online-hard"), z)
    sent = np.vstack([np.tile(Q0, (3, 1))] + [tick.output[:, 0] for tick in ticks])
    for k, tick in enumerate(ticks):
        p = sent[k:k + 4]
        np.testing.assert_allclose(tick.output[:, 3],
                                   (p[3] - 3 * p[2] + 3 * p[1] - p[0]) / DT**3, rtol=1e-12,
                                   atol=1e-12)
        assert np.all(np.abs(tick.output[:, 2]) <= A_MAX * (1 + 1e-9))
        assert np.all(np.abs(tick.output[:, 3]) <= J_MAX * (1 + 1e-9))


@pytest.mark.parametrize("method", ["online-cks", "bmfls", "original", "online-hard"])
def test_the_state_vector_round_trip_is_exact(method):
    params = _params(method)
    z = operator_recording(num_samples=8, num_joints=2, seed=8) + Q0
    state = smoother_initial_state(params, Q0)
    codec = SmootherStepStateVector(params, state)
    for k in range(8):
        state = smoother_step(params, state, z[k], k == 4).state
        vector = codec.pack(state)
        assert vector.shape == (codec.size,)
        np.testing.assert_array_equal(codec.pack(codec.unpack(vector)), vector)
    with pytest.raises(ValueError, match="shape"):
        codec.unpack(np.zeros(3))


@settings(derandomize=True, database=None, deadline=None, max_examples=25)
@given(stream=st.lists(st.tuples(st.floats(-1.0, 1.0), st.floats(-1.0, 1.0), st.booleans(),
                                 st.booleans()), min_size=1, max_size=25),
       method=st.sampled_from(["online-cks", "online-hard"]))
def test_sigma_never_grows_and_the_output_stays_finite(stream, method):
    # (bmfls and pass-through keep σ constant: test_bmfls_never_changes_sigma_nor_triggers.)
    params = _params(method)
    state = smoother_initial_state(params, Q0)
    for a, b, nan, reset in stream:
        z = np.array([np.nan if nan else a, b])
        tick = smoother_step(params, state, z, reset)
        assert np.all(tick.state.online.sigma <= state.online.sigma)
        assert np.all(np.isfinite(tick.output))
        state = tick.state


@pytest.mark.parametrize("method", ["online-cks", "online-hard", "bmfls", "original"])
def test_the_drake_system_outputs_the_steps_tick(method):
    from pydrake.systems.framework import DiagramBuilder
    from pydrake.systems.primitives import ConstantVectorSource

    from telesmooth.systems.reduced_q_smoother import ReducedQSmoother, ReducedQSmootherConfig

    config = ReducedQSmootherConfig(period_s=DT, sigma=4e-4, r=1e-6, lag=LAG, method=method,
                                    max_acceleration_rad_per_s2=A_MAX,
                                    max_jerk_rad_per_s3=J_MAX)
    builder = DiagramBuilder()
    smoother = builder.AddSystem(ReducedQSmoother(config, joint_names=("a", "b"),
                                                  initial_position_rad=Q0))
    source = builder.AddSystem(ConstantVectorSource(Q0))
    reset = builder.AddSystem(ConstantVectorSource(np.zeros(1)))
    builder.Connect(source.get_output_port(), smoother.get_q_sample_input_port())
    builder.Connect(reset.get_output_port(), smoother.get_reset_input_port())
    diagram = builder.Build()
    context = diagram.CreateDefaultContext()
    source_context, reset_context, smoother_context = (
        s.GetMyContextFromRoot(context) for s in (source, reset, smoother))
    params = _params(method)
    state = smoother_initial_state(params, Q0)
    z = operator_recording(num_samples=10, num_joints=2, seed=9, noise=2e-2) + Q0
    for k in range(10):
        source.get_mutable_source_value(source_context).SetFromVector(z[k])
        reset.get_mutable_source_value(reset_context).SetFromVector([float(k == 6)])
        tick = smoother_step(params, state, z[k], k == 6)
        np.testing.assert_array_equal(
            smoother.get_state_smoothed_output_port().Eval(smoother_context),
            tick.output.T.ravel())
        np.testing.assert_array_equal(smoother.get_sigma_output_port().Eval(smoother_context),
                                      tick.state.online.sigma)
        np.testing.assert_array_equal(
            smoother.get_triggered_output_port().Eval(smoother_context),
            tick.triggered.astype(float))
        smoother_context.SetDiscreteState(
            smoother.EvalUniquePeriodicDiscreteUpdate(smoother_context))
        state = tick.state
