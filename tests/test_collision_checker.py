"""CollisionChecker: port contract, update equations, latch window, invalid input."""

import math

import numpy as np
import pytest
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder, LeafSystem
from pydrake.systems.primitives import LogVectorOutput, TrajectorySource
from pydrake.trajectories import PiecewisePolynomial

from telesmooth.arms.description import AIR_BEARING_ARM_3DOF
from telesmooth.arms.workspace import AIR_BEARING_WORKSPACE
from telesmooth.datasets.lasa import lasa_operator_session
from telesmooth.systems.collision_checker import CollisionChecker, CollisionCheckerConfig

FREE_Q = np.array([0.0, 0.0, 0.0])  # 0.06 m from wall_x_upper (test_arm_collision)
COLLIDING_Q = np.array([math.pi / 4, 0.0, 0.0])  # link2 0.045 m deep in the fixture
PERIOD_S = 0.01


def _checker(**config):
    return CollisionChecker(CollisionCheckerConfig(**config), arm=AIR_BEARING_ARM_3DOF,
                            workspace=AIR_BEARING_WORKSPACE)


def _outputs(dut, context):
    return (dut.get_min_distance_output_port().Eval(context)[0],
            dut.get_in_collision_output_port().Eval(context)[0],
            dut.get_collision_detected_output_port().Eval(context)[0])


def _update(dut, context):
    context.SetDiscreteState(dut.EvalUniquePeriodicDiscreteUpdate(context))


@pytest.fixture(scope="module")
def dut():
    return _checker()


# --- config and port contract ---


@pytest.mark.parametrize("field, value, match", [
    ("period_s", 0.0, r"CollisionCheckerConfig.period_s = 0.0 must be positive"),
    ("period_s", float("nan"), r"period_s = nan"),
    ("safety_margin_m", -0.01, r"safety_margin_m = -0.01 must be non-negative"),
    ("distance_horizon_m", float("inf"), r"distance_horizon_m = inf must be non-negative and "
                                         r"finite"),
    ("distance_horizon_m", 0.02, r"distance_horizon_m = 0.02 must exceed safety_margin_m"),
    ("latch_s", 0.005, r"latch_s = 0.005 must be at least period_s = 0.01"),
    ("latch_s", "0.26", r"latch_s = '0.26' must be non-negative"),
])
def test_config_validation_names_field_and_value(field, value, match):
    with pytest.raises(ValueError, match=match):
        CollisionCheckerConfig(**{field: value})


@pytest.mark.parametrize("latch_s, period_s, expected", [
    (0.26, 0.01, 26),  # 0.26/0.01 = 26.000000000000004 in floating point: still 26
    (0.25, 0.01, 25), (0.255, 0.01, 26), (0.01, 0.01, 1), (0.3, 0.1, 3),
])
def test_latch_samples_is_the_ceiling_of_the_ratio(latch_s, period_s, expected):
    assert CollisionCheckerConfig(period_s=period_s, latch_s=latch_s).latch_samples == expected


def test_port_contract(dut):
    assert dut.num_input_ports() == 1 and dut.num_output_ports() == 3
    assert dut.get_q_target_input_port().get_name() == "q_target"
    assert dut.get_q_target_input_port().size() == 3
    names = [dut.get_output_port(i).get_name() for i in range(3)]
    assert names == ["min_distance", "in_collision", "collision_detected"]
    assert [dut.get_output_port(i).size() for i in range(3)] == [1, 1, 1]
    # All outputs are state: the checker can sit in a feedback loop.
    assert not any(dut.HasDirectFeedthrough(0, j) for j in range(3))
    assert dut.latch_samples == 26
    timing = dut.GetUniquePeriodicDiscreteUpdateAttribute()
    assert (timing.period_sec(), timing.offset_sec()) == (PERIOD_S, 0.0)


def test_wrong_size_input_is_rejected_by_drake(dut):
    context = dut.CreateDefaultContext()
    with pytest.raises(RuntimeError):  # Drake checks the size of a fixed vector value
        dut.get_q_target_input_port().FixValue(context, np.zeros(2))


def test_outputs_before_the_first_update_are_no_collision_at_the_horizon(dut):
    context = dut.CreateDefaultContext()
    assert _outputs(dut, context) == (0.2, 0.0, 0.0)


def test_update_equations_free_then_colliding(dut):
    context = dut.CreateDefaultContext()
    dut.get_q_target_input_port().FixValue(context, FREE_Q)
    _update(dut, context)
    distance, in_collision, detected = _outputs(dut, context)
    assert distance == pytest.approx(1.2 - 1.14, abs=1e-5)
    assert (in_collision, detected) == (0.0, 0.0)
    dut.get_q_target_input_port().FixValue(context, COLLIDING_Q)
    _update(dut, context)
    distance, in_collision, detected = _outputs(dut, context)
    assert distance == pytest.approx(-0.045, abs=1e-5)
    assert (in_collision, detected) == (1.0, 1.0)
    # The margin, not contact, decides: 0.06 m is a collision for a 0.1 m margin.
    wide = _checker(safety_margin_m=0.1)
    wide_context = wide.CreateDefaultContext()
    wide.get_q_target_input_port().FixValue(wide_context, FREE_Q)
    _update(wide, wide_context)
    assert _outputs(wide, wide_context)[1:] == (1.0, 1.0)


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_non_finite_input_is_flagged_not_raised(dut, bad):
    context = dut.CreateDefaultContext()
    dut.get_q_target_input_port().FixValue(context, [0.0, bad, 0.0])
    _update(dut, context)
    outputs = _outputs(dut, context)
    assert outputs == (0.0, 1.0, 1.0)
    assert all(math.isfinite(v) for v in outputs)


def test_unconnected_input_is_flagged(dut):
    context = dut.CreateDefaultContext()
    _update(dut, context)
    assert _outputs(dut, context) == (0.0, 1.0, 1.0)


# --- latch window in simulation ---


def _pulse_source(builder, pulse_time_s, duration_s=2.0):
    """q(t): FREE_Q, except COLLIDING_Q on [t_p - p/2, t_p + p/2), which holds one sample."""
    breaks = [0.0, pulse_time_s - PERIOD_S / 2, pulse_time_s + PERIOD_S / 2, duration_s]
    values = np.column_stack([FREE_Q, COLLIDING_Q, FREE_Q, FREE_Q])
    return builder.AddSystem(
        TrajectorySource(PiecewisePolynomial.ZeroOrderHold(breaks, values)))


def test_one_sample_pulse_stays_visible_for_the_latch_window():
    builder = DiagramBuilder()
    dut = builder.AddSystem(_checker())
    source = _pulse_source(builder, pulse_time_s=0.51)
    builder.Connect(source.get_output_port(), dut.get_q_target_input_port())
    diagram = builder.Build()
    simulator = Simulator(diagram)
    context = dut.GetMyContextFromRoot(simulator.get_mutable_context())
    in_collision, detected = [], []
    # Read between samples (t_k + p/2), so no read is co-timed with an update.
    read_times = PERIOD_S * np.arange(100) + PERIOD_S / 2
    for t in read_times:
        simulator.AdvanceTo(t)
        _, c, d = _outputs(dut, context)
        in_collision.append(c)
        detected.append(d)
    in_collision, detected = np.array(in_collision), np.array(detected)
    # The update at t = 0.51 s sees the pulse: in_collision for exactly that sample, the
    # latch for N = 26 samples (the updates at 0.51 ... 0.76 s).
    k_pulse = 51
    expected_in_collision = np.zeros(100)
    expected_in_collision[k_pulse] = 1.0
    expected_detected = np.zeros(100)
    expected_detected[k_pulse:k_pulse + 26] = 1.0
    np.testing.assert_array_equal(in_collision, expected_in_collision)
    np.testing.assert_array_equal(detected, expected_detected)


class _FourHzReader(LeafSystem):
    """Counts the 0.25 s ticks at which its input (a collision flag) was set, as the FIFO."""

    def __init__(self, period_s=0.25):
        super().__init__()
        self._flag_input = self.DeclareVectorInputPort("flag", 1)
        self._count_state = self.DeclareDiscreteState(1)
        self.DeclarePeriodicDiscreteUpdateEvent(period_s, 0.0, self._read)

    def _read(self, context, state):
        count = context.get_discrete_state(self._count_state).get_value()[0]
        seen = self._flag_input.Eval(context)[0] > 0.5
        state.get_mutable_vector(self._count_state).SetAtIndex(0, count + seen)

    def count(self, context):
        return context.get_discrete_state(self._count_state).get_value()[0]


def _reads_that_saw_pulse(latch_s, pulse_index):
    builder = DiagramBuilder()
    dut = builder.AddSystem(_checker(latch_s=latch_s))
    reader = builder.AddSystem(_FourHzReader())
    source = _pulse_source(builder, pulse_time_s=pulse_index * PERIOD_S)
    builder.Connect(source.get_output_port(), dut.get_q_target_input_port())
    builder.Connect(dut.get_collision_detected_output_port(), reader.get_input_port(0))
    simulator = Simulator(builder.Build())
    simulator.AdvanceTo(1.3)
    return reader.count(reader.GetMyContextFromRoot(simulator.get_context()))


def test_a_4hz_reader_sees_a_one_sample_pulse_at_every_phase():
    # Pulses at samples 30 ... 54 cover all 25 phases of a 0.25 s period relative to the
    # reader's ticks (co-timed at 0.25, 0.5, ...). Each is seen by one or two reads.
    counts = [_reads_that_saw_pulse(0.26, k) for k in range(30, 55)]
    assert min(counts) >= 1 and max(counts) <= 2
    # Control: with a 0.1 s latch most phases are missed, so the check above can fail.
    short = [_reads_that_saw_pulse(0.1, k) for k in range(30, 55)]
    assert short.count(0) == 15


def test_lasa_angle_demo_0_never_trips_the_checker():
    session = lasa_operator_session("Angle", 0)
    builder = DiagramBuilder()
    dut = builder.AddSystem(_checker())
    source = builder.AddSystem(TrajectorySource(
        PiecewisePolynomial.ZeroOrderHold(session.t_s, session.q_rad.T)))
    builder.Connect(source.get_output_port(), dut.get_q_target_input_port())
    distance_log = LogVectorOutput(dut.get_min_distance_output_port(), builder, PERIOD_S)
    detected_log = LogVectorOutput(dut.get_collision_detected_output_port(), builder, PERIOD_S)
    diagram = builder.Build()
    simulator = Simulator(diagram)
    simulator.AdvanceTo(session.t_s[-1])
    root = simulator.get_context()
    distances = distance_log.FindLog(root).data()[0]
    detected = detected_log.FindLog(root).data()[0]
    assert distances.size == session.t_s.size
    assert np.all(detected == 0.0)
    # Same minimum as the direct query over the session (test_arm_collision), 0.1720 m.
    assert distances.min() == pytest.approx(0.1720, abs=5e-4)


# --- a target that did not change is not queried again ---


def test_an_unchanged_target_reuses_the_last_distance_and_still_fills_the_latch():
    """Oracle: the update equations evaluated by hand with a query at every sample (the
    query is a pure function of q): same outputs at every sample; the model is queried only
    when the target changes, and again after an invalid target."""
    dut = _checker(latch_s=0.05)
    oracle_model = _checker().collision_model
    margin, window = dut.config.safety_margin_m, dut.latch_samples
    queries = []
    query = dut.collision_model.query
    dut.collision_model.query = lambda q: queries.append(q.copy()) or query(q)
    context = dut.CreateDefaultContext()
    sequence = [FREE_Q] * 3 + [COLLIDING_Q] * 8 + [FREE_Q] * 2 + [np.array([np.nan, 0, 0])] \
        + [FREE_Q] * 7
    flags = []
    for q in sequence:
        dut.get_q_target_input_port().FixValue(context, q)
        _update(dut, context)
        distance = oracle_model.query(q).min_distance_m if np.all(np.isfinite(q)) else 0.0
        flags.append(float(distance < margin) if np.all(np.isfinite(q)) else 1.0)
        assert _outputs(dut, context) == (distance, flags[-1], max(flags[-window:]))
    assert 0.0 in flags and 1.0 in flags
    # Queried at the first sample of each run of equal valid targets only.
    assert len(queries) == 4
    np.testing.assert_array_equal(queries, [FREE_Q, COLLIDING_Q, FREE_Q, FREE_Q])
