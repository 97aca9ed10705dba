"""The FIFO's pure step (``telesmooth.safety.fifo``), without Drake.

* A plain delay line (a deque written here) is the oracle for every tick without a hold;
  a hold sends the sent command L + 1 times and discards the queue.
* Release: ``collision-clear`` at the first clear tick; ``clutch`` only after the clutch was
  released and re-engaged during the hold.
* Stop: the contingency is planned between ticks from [p_{k−2}, p_{k−1}, q_sent]; the collision
  tick plays its commands one per tick (each :func:`plan_stop`'s own), then holds at the rest
  pose, and the hold ends only once the stop is at rest. A collision whose history is not the
  contingency's is a hold, flagged ``unplanned``.
* Properties over random streams: the state round-trips through the Context's codec, the
  step never changes the state it is given, and the DelayFifo system's outputs are the step's.
"""

import collections

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from telesmooth.safety.fifo import (
    FifoInputs,
    FifoParams,
    fifo_initial_state,
    fifo_plan_contingency,
    fifo_step,
)
from telesmooth.safety.state_codec import VectorCodec
from telesmooth.safety.stop import StopOutcome, plan_stop, stop_params

J, LAG, DT = 2, 3, 0.25
Q0 = np.array([0.1, -0.2])


def _stop():
    return stop_params(dt_s=DT, max_acceleration=0.2, max_jerk=0.5,
                       pose_is_safe=lambda q: True, joint_names=["a", "b"])


def _params(release="collision-clear", stop=False):
    return FifoParams(num_joints=J, lag=LAG, release=release,
                      stop=_stop() if stop else None, max_stop_ticks=40 if stop else 0)


def _inputs(sample, collision=False, enable=True, q_sent=None):
    return FifoInputs(np.asarray(sample, dtype=float), collision, enable,
                      None if q_sent is None else np.asarray(q_sent, dtype=float))


def test_without_a_hold_it_is_a_delay_line():
    params = _params()
    state = fifo_initial_state(params, Q0)
    line = collections.deque([Q0] * LAG)
    rng = np.random.default_rng(4)
    for _ in range(20):
        sample = rng.normal(size=J)
        state, out = fifo_step(params, state, _inputs(sample))
        line.append(sample)
        assert not out.hold
        np.testing.assert_array_equal(out.window, np.array(line))
        line.popleft()
        np.testing.assert_array_equal(state.queue, np.array(line))


def test_a_collision_sends_the_sent_command_and_discards_the_queue():
    params = _params()
    state = fifo_initial_state(params, Q0)
    for k in range(5):
        state, _ = fifo_step(params, state, _inputs(Q0 + 0.01 * k))
    sent = np.array([0.3, 0.4])
    state, out = fifo_step(params, state, _inputs([9.0, 9.0], collision=True, q_sent=sent))
    assert out.hold and state.holding
    np.testing.assert_array_equal(out.window, np.tile(sent, (LAG + 1, 1)))
    # Clear: the queue restarts from the held command, the new sample enters.
    state, out = fifo_step(params, state, _inputs([1.0, 1.0], q_sent=sent))
    assert not out.hold
    np.testing.assert_array_equal(out.window, np.vstack([np.tile(sent, (LAG, 1)), [1.0, 1.0]]))


@pytest.mark.parametrize("bad", [[np.nan, 0.0], [np.inf, 0.0], [0.0, 0.0, 0.0]])
def test_a_bad_sample_is_never_queued(bad):
    params = _params()
    state, out = fifo_step(params, fifo_initial_state(params, Q0), _inputs(bad))
    assert out.hold and np.all(np.isfinite(out.window))


def test_without_q_sent_the_hold_keeps_the_last_delayed_sample():
    params = _params()
    state = fifo_initial_state(params, Q0)
    for k in range(LAG + 2):
        state, out = fifo_step(params, state, _inputs(Q0 + k))
    last = out.window[0]
    _, out = fifo_step(params, state, _inputs(Q0, collision=True))
    np.testing.assert_array_equal(out.window, np.tile(last, (LAG + 1, 1)))


def test_the_clutch_release_needs_a_release_and_a_re_engagement():
    params = _params(release="clutch")
    state = fifo_initial_state(params, Q0)
    script = [  # (collision, enable) → hold
        (True, True, True),      # collision
        (False, True, True),     # clear, but the clutch was never released: hold
        (False, False, True),    # released
        (False, False, True),    # still released
        (False, True, False),    # re-engaged: the hold ends
        (False, True, False),
    ]
    for collision, enable, hold in script:
        state, out = fifo_step(params, state, _inputs(Q0, collision, enable))
        assert out.hold == hold, (collision, enable)
    # With collision-clear the same script ends the hold at the first clear tick.
    params = _params()
    state = fifo_initial_state(params, Q0)
    holds = []
    for collision, enable, _ in script:
        state, out = fifo_step(params, state, _inputs(Q0, collision, enable))
        holds.append(out.hold)
    assert holds == [True, False, False, False, False, False]


def _moving_history(params, ticks=8, speed=0.002):
    """A state whose sent commands ramp at ``speed`` rad per tick, with its contingency
    planned as between ticks; returns (state, q_sent)."""
    state = fifo_initial_state(params, Q0)
    sent = Q0.copy()
    for k in range(ticks):
        sample = Q0 + speed * (k + 1) * k / 2 / ticks
        state, _ = fifo_step(params, state, _inputs(sample, q_sent=sent))
        sent = sample
        state = fifo_plan_contingency(params, state, sent)
    return state, sent


def test_the_stop_plays_the_planned_commands_then_holds_at_rest():
    params = _params(stop=True)
    state, sent = _moving_history(params)
    history = np.vstack([state.sent_history, sent])
    plan = plan_stop(params.stop, history, max_ticks=params.max_stop_ticks)
    assert plan.outcome == StopOutcome.STOP and plan.ticks_to_rest > 1
    played = []
    q_sent = sent
    for k in range(plan.ticks_to_rest + 3):
        collision = k == 0                      # one collision tick, then clear
        state, out = fifo_step(params, state, _inputs(Q0 + 5.0, collision, q_sent=q_sent))
        assert not out.unplanned
        assert out.stop_outcome == StopOutcome.STOP
        np.testing.assert_array_equal(out.braking_distance, plan.braking_distance)
        if k < plan.ticks_to_rest:
            assert out.hold                      # never released before the stop is at rest
            played.append(out.window[0])
            np.testing.assert_array_equal(out.window, np.tile(out.window[0], (LAG + 1, 1)))
        q_sent = out.window[0]
    np.testing.assert_array_equal(np.array(played), plan.commands)
    assert not out.hold                          # at rest, collision clear: released


def test_a_collision_without_its_contingency_is_a_flagged_hold():
    params = _params(stop=True)
    state, sent = _moving_history(params)
    other = sent + 0.01                          # not the history the stop was planned from
    state, out = fifo_step(params, state, _inputs(Q0, True, q_sent=other))
    assert out.unplanned and out.hold and out.stop_outcome == StopOutcome.HOLD
    np.testing.assert_array_equal(out.window, np.tile(other, (LAG + 1, 1)))


def test_the_contingency_is_planned_once_per_history_and_not_while_holding():
    params = _params(stop=True)
    state, sent = _moving_history(params)
    assert fifo_plan_contingency(params, state, sent) is state
    held, _ = fifo_step(params, state, _inputs(Q0, True, q_sent=sent))
    assert fifo_plan_contingency(params, held, sent + 1.0) is held
    hold_policy = fifo_initial_state(_params(), Q0)
    assert fifo_plan_contingency(_params(), hold_policy, sent) is hold_policy


streams = st.lists(st.tuples(st.booleans(), st.booleans(), st.floats(-1.0, 1.0)),
                   min_size=1, max_size=30)


@settings(derandomize=True, database=None, deadline=None, max_examples=30)
@given(stream=streams, stop=st.booleans(), release=st.sampled_from(["collision-clear",
                                                                     "clutch"]))
def test_codec_round_trip_and_purity_over_streams(stream, stop, release):
    params = _params(release, stop)
    state = fifo_initial_state(params, Q0)
    codec = VectorCodec(state)
    sent = Q0.copy()
    for collision, enable, x in stream:
        vector = codec.pack(state)
        again = codec.unpack(vector)
        np.testing.assert_array_equal(codec.pack(again), vector)
        before = vector.copy()
        state, out = fifo_step(params, again, _inputs(Q0 + x, collision, enable, sent))
        np.testing.assert_array_equal(codec.pack(again), before)   # the input state unchanged
        sent = out.window[0]
        state = fifo_plan_contingency(params, state, sent)
        assert np.all(np.isfinite(out.window))


def test_the_drake_system_outputs_are_the_steps():
    from pydrake.systems.framework import DiagramBuilder
    from pydrake.systems.primitives import ConstantVectorSource

    from telesmooth.systems.delay_fifo import DelayFifo, DelayFifoConfig

    builder = DiagramBuilder()
    fifo = builder.AddSystem(DelayFifo(DelayFifoConfig(period_s=DT, delay_s=LAG * DT),
                                       num_joints=J, initial_position_rad=Q0))
    target = builder.AddSystem(ConstantVectorSource(np.zeros(J)))
    builder.Connect(target.get_output_port(), fifo.get_q_target_input_port())
    diagram = builder.Build()
    context = diagram.CreateDefaultContext()
    source_context = target.GetMyContextFromRoot(context)
    fifo_context = fifo.GetMyContextFromRoot(context)
    params, state = fifo.params, fifo_initial_state(fifo.params, Q0)
    rng = np.random.default_rng(9)
    for _ in range(12):
        sample = rng.normal(size=J)
        target.get_mutable_source_value(source_context).SetFromVector(sample)
        state, out = fifo_step(params, state, _inputs(sample))
        np.testing.assert_array_equal(
            fifo.get_window_output_port().Eval(fifo_context), out.window.ravel())
        update = fifo.EvalUniquePeriodicDiscreteUpdate(fifo_context)
        fifo_context.SetDiscreteState(update)
        np.testing.assert_array_equal(
            VectorCodec(state).pack(fifo.fifo_state(fifo_context)),
            VectorCodec(state).pack(state))
