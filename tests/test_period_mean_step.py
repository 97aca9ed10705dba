"""The period mean's pure step (``telesmooth.smoothing.period_mean``) against a plain moving
average written here, and the PeriodMean system holding what the step returns."""

import collections

import numpy as np

from telesmooth.safety.state_codec import VectorCodec
from telesmooth.smoothing.period_mean import (
    period_mean,
    period_mean_initial_state,
    period_mean_step,
)

Q0 = np.array([0.5, -0.5])
M = 4


def test_a_moving_average_of_the_last_m_finite_samples():
    rng = np.random.default_rng(2)
    state = period_mean_initial_state(M, Q0)
    window = collections.deque([Q0] * M, maxlen=M)
    last = Q0
    codec = VectorCodec(state)
    for k in range(30):
        sample = rng.normal(size=2) if k % 7 else np.array([np.nan, 1.0])
        before = codec.pack(state)
        state = period_mean_step(codec.unpack(before), sample)
        taken = sample if np.all(np.isfinite(sample)) else last
        window.append(taken)
        last = taken
        np.testing.assert_allclose(period_mean(state), np.mean(np.array(window), axis=0),
                                   rtol=0, atol=1e-15)
        assert np.all(np.isfinite(period_mean(state)))
        np.testing.assert_array_equal(codec.pack(codec.unpack(codec.pack(state))),
                                      codec.pack(state))


def test_the_drake_system_outputs_the_steps_mean():
    from pydrake.systems.framework import DiagramBuilder
    from pydrake.systems.primitives import ConstantVectorSource

    from telesmooth.systems.period_mean import PeriodMean, PeriodMeanConfig

    builder = DiagramBuilder()
    mean = builder.AddSystem(PeriodMean(PeriodMeanConfig(sample_period_s=0.01, window_s=0.04),
                                        num_joints=2, initial_position_rad=Q0))
    source = builder.AddSystem(ConstantVectorSource(np.zeros(2)))
    builder.Connect(source.get_output_port(), mean.get_q_target_input_port())
    diagram = builder.Build()
    context = diagram.CreateDefaultContext()
    source_context, mean_context = (s.GetMyContextFromRoot(context) for s in (source, mean))
    state = period_mean_initial_state(M, Q0)
    for k in range(9):
        sample = np.array([0.1 * k, -0.2 * k])
        source.get_mutable_source_value(source_context).SetFromVector(sample)
        state = period_mean_step(state, sample)
        mean_context.SetDiscreteState(mean.EvalUniquePeriodicDiscreteUpdate(mean_context))
        np.testing.assert_array_equal(mean.get_q_mean_output_port().Eval(mean_context),
                                      period_mean(state))
