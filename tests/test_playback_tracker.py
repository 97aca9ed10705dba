"""A playback's laser tracker, sampled after the run from the integrator's dense output.

In a playback (``compare``, ``experiment``, the offline mode) nothing reads the tracker while
the plant runs, so with the continuous plant the tracker is not a stage of the diagram and its
100 Hz event no longer ends an integrator step every 10 ms:
:func:`~telesmooth.diagrams.offline_playback.simulate_playback` evaluates the dense output at
t_k = k·period and :meth:`LaserTracker.Record` samples those states. Oracles: the tracker as a
stage of the diagram, sampling with its own event, in the same playback (the way every
playback ran before), integrated at the default accuracy and 10⁴× more accurately; and the
noise's closed form.
"""

import dataclasses

import numpy as np
import pytest
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import LogVectorOutput

from telesmooth.diagrams.offline_playback import (
    AddPathPlayback,
    simulate_playback,
    tracker_sample_times,
)
from telesmooth.diagrams.scenario import LoadScenario
from telesmooth.diagrams.simulation import tool_positions
from telesmooth.diagrams.teleoperation import AddOnboardRobot, ConnectUplinkToRobot
from telesmooth.studies.comparison import prepare_comparison, run_method
from telesmooth.systems.flexible_arm import FlexibleJointArm, MakeSimulator
from telesmooth.systems.laser_tracker import LaserTrackerConfig, tracker_record
from telesmooth.systems.planned_path_source import PlannedPathSource
from telesmooth.systems.uplink import Uplink


@pytest.mark.parametrize("period, duration, count", [
    (0.01, 0.05, 5),          # t = 0.05 is the end: its event would fire only later
    (0.01, 0.0501, 6),
    (0.25, 1.0, 4),
    (0.3, 1.0, 4),            # 0, 0.3, 0.6, 0.9
    (0.01, 41.75, 4175),
])
def test_the_sample_instants_are_those_of_the_periodic_event(period, duration, count):
    times = tracker_sample_times(period, duration)
    assert times.size == count
    np.testing.assert_array_equal(times, period * np.arange(count))
    assert times[-1] < duration


def test_the_sample_instants_written_out():
    np.testing.assert_allclose(tracker_sample_times(0.3, 1.0), [0.0, 0.3, 0.6, 0.9],
                               rtol=0, atol=1e-15)
    np.testing.assert_allclose(tracker_sample_times(0.01, 0.0501),
                               [0.0, 0.01, 0.02, 0.03, 0.04, 0.05], rtol=0, atol=1e-15)


def _event_record(scenario, packets, q_start, duration_s):
    """The same playback with the tracker as a stage of the diagram, sampling with its own
    periodic event (the oracle: no dense output involved)."""
    period = scenario.uplink.period_s
    builder = DiagramBuilder()
    source = builder.AddSystem(PlannedPathSource(packets, period_s=period))
    uplink = builder.AddSystem(Uplink(scenario.uplink, num_joints=packets.shape[1],
                                      initial_position_rad=q_start))
    builder.Connect(source.get_q_planned_output_port(), uplink.get_q_smoothed_input_port())
    builder.Connect(source.get_state_planned_output_port(),
                    uplink.get_state_smoothed_input_port())
    robot = AddOnboardRobot(builder, scenario, initial_position_rad=q_start,
                            command_period_s=period)
    assert robot.tracker_in_diagram
    ConnectUplinkToRobot(builder, uplink, robot)
    logger = LogVectorOutput(robot.GetOutputPort("tracker_measurement"), builder,
                             scenario.onboard.tracker.period_s)
    simulator = MakeSimulator(builder.Build(), robot.config)
    simulator.AdvanceTo(duration_s)
    return tracker_record(logger.FindLog(simulator.get_context()).data().T)


def _dense_record(scenario, packets, q_start, duration_s):
    builder = DiagramBuilder()
    _, _, robot, loggers = AddPathPlayback(builder, scenario, packets, q_start=q_start)
    assert not robot.tracker_in_diagram
    _, logs = simulate_playback(builder.Build(), robot, loggers, duration_s)
    return logs["tracker"]


@pytest.fixture(scope="module")
def playback():
    """Defaults' recorded session as Online-CKS sends it: a real command stream."""
    scenario = LoadScenario(scenario_text="{settle_s: 1.0}")
    setup = prepare_comparison(scenario)
    run = run_method(setup, "online-cks")
    return scenario, run.packets, setup.q_start, setup.duration_s


def _with_onboard(scenario, **fields):
    return dataclasses.replace(scenario, onboard=dataclasses.replace(scenario.onboard, **fields))


def test_the_dense_record_is_as_accurate_as_the_tracker_event(playback):
    scenario, packets, q_start, duration = playback
    dense = _dense_record(scenario, packets, q_start, duration)
    event = _event_record(scenario, packets, q_start, duration)
    reference = _event_record(
        _with_onboard(scenario, integration_scheme="runge_kutta3", integration_accuracy=1e-7),
        packets, q_start, duration)
    # The same instants, to the bit.
    np.testing.assert_array_equal(dense.t_s, event.t_s)
    np.testing.assert_array_equal(dense.t_s, reference.t_s)
    assert dense.t_s.size == tracker_sample_times(0.01, duration).size

    def error(record):
        return (np.linalg.norm(record.tool_position_m - reference.tool_position_m, axis=1).max(),
                np.abs(record.q_link - reference.q_link).max(),
                np.abs(record.q_motor - reference.q_motor).max())

    # Within 1.5x of the event-bound run's own integration error (measured: 1.01x). A record
    # read one tracker period off would be off by the tool's travel in 10 ms (~1e-4 m here).
    for dense_error, event_error in zip(error(dense), error(event)):
        assert dense_error <= 1.5 * event_error + 1e-9
    tool_error, q_link_error, _ = error(dense)
    assert tool_error < 2e-5 and q_link_error < 1e-4
    # The robot moved: the comparison is not between two resting arms.
    assert np.ptp(reference.q_link, axis=0).max() > 0.1
    # Each sample is the tracker's measurement of its own state (tool = FK(q_link)).
    np.testing.assert_allclose(dense.tool_position_m, tool_positions(scenario, dense.q_link),
                               rtol=0, atol=1e-12)
    # The first sample is the start pose at rest.
    np.testing.assert_allclose(dense.q_link[0], q_start, rtol=0, atol=1e-12)
    np.testing.assert_allclose(dense.q_motor[0], q_start, rtol=0, atol=1e-12)


def test_record_adds_each_samples_own_noise():
    config = LaserTrackerConfig(noise_m=1e-4, seed=11)
    noisy = FlexibleJointArm(dataclasses.replace(LoadScenario(scenario_text="{}").onboard,
                                                 tracker=config), tracker_in_diagram=False)
    exact = FlexibleJointArm(tracker_in_diagram=False)
    rng = np.random.default_rng(3)
    states = rng.normal(scale=0.3, size=(5, noisy.plant.num_multibody_states()))
    times = np.array([0.0, 0.01, 0.02, 0.5, 7.31])
    with_noise = noisy.tracker.Record(times, states)
    without = exact.tracker.Record(times, states)
    np.testing.assert_array_equal(with_noise.q_link, without.q_link)
    for row, t in enumerate(times):
        k = round(t / 0.01)
        expected = 1e-4 * np.random.default_rng([11, k]).standard_normal(3)
        np.testing.assert_allclose(with_noise.tool_position_m[row] - without.tool_position_m[row],
                                   expected, rtol=0, atol=1e-15)
    # The link angles are motor + deflection, in joint order.
    q = states[:, :noisy.plant.num_positions()]
    np.testing.assert_allclose(without.q_link, q[:, 0::2] + q[:, 1::2], rtol=0, atol=1e-15)
    np.testing.assert_array_equal(without.q_motor, q[:, 0::2])


@pytest.mark.parametrize("times, width, message", [
    ([0.0, 0.01], 11, r"plant_states has shape \(2, 11\); expected \(2, 12\)"),
    ([0.0, 0.0], 12, "times_s must be strictly increasing"),
    ([0.02, 0.01], 12, "times_s must be strictly increasing"),
])
def test_record_refuses_states_that_do_not_fit(times, width, message):
    arm = FlexibleJointArm(tracker_in_diagram=False)
    with pytest.raises(ValueError, match=message):
        arm.tracker.Record(times, np.zeros((2, width)))


def test_a_robot_without_its_tracker_has_no_tracker_ports():
    inside, outside = FlexibleJointArm(), FlexibleJointArm(tracker_in_diagram=False)
    tracker_ports = {"position_measured", "q_link", "q_motor", "tracker_sample_time",
                     "tracker_measurement", "velocity_measured"}
    names = {dut: {dut.get_output_port(i).get_name() for i in range(dut.num_output_ports())}
             for dut in (inside, outside)}
    assert tracker_ports <= names[inside]
    assert not tracker_ports & names[outside]
    assert names[inside] - tracker_ports == names[outside]
    # No 100 Hz event left in the diagram without it.
    context = outside.CreateDefaultContext()
    assert context.num_discrete_state_groups() < inside.CreateDefaultContext(
    ).num_discrete_state_groups()


@pytest.mark.parametrize("duration", [1.0, 1.0049, 0.0501])
def test_a_discrete_plant_keeps_its_tracker_and_both_give_the_same_instants(playback,
                                                                            duration):
    """The sample taken at the last instant before the end is in both records, also when
    no logger shows it (the end is not a multiple of the period)."""
    scenario, packets, q_start, _ = playback
    discrete = _with_onboard(scenario, time_step_s=0.001)
    builder = DiagramBuilder()
    _, _, robot, loggers = AddPathPlayback(builder, discrete, packets, q_start=q_start)
    assert robot.tracker_in_diagram
    _, logs = simulate_playback(builder.Build(), robot, loggers, duration)
    expected = tracker_sample_times(0.01, duration)
    np.testing.assert_array_equal(logs["tracker"].t_s, expected)
    assert "tracker_measurement" not in logs
    continuous = _dense_record(scenario, packets, q_start, duration)
    np.testing.assert_array_equal(continuous.t_s, expected)


def test_where_drake_refuses_a_dense_output_the_playback_stops_at_every_instant(playback):
    """Interpolator polls every 10 ms: a 10 ms step from a poll ends one rounding error
    before the next poll, and drake refuses the dense output (segments closer than
    2.2e-16 s). The playback then runs again, stopping at each sample instant: the record is
    the tracker event's within the integration error."""
    scenario, packets, q_start, duration = playback
    polling = dataclasses.replace(scenario, onboard=dataclasses.replace(
        scenario.onboard, interpolator=dataclasses.replace(scenario.onboard.interpolator,
                                                           poll_period_s=0.01)))
    builder = DiagramBuilder()
    _, _, robot, _ = AddPathPlayback(builder, polling, packets, q_start=q_start)
    simulator = MakeSimulator(builder.Build(), robot.config)
    simulator.Initialize()
    simulator.get_integrator().StartDenseIntegration()
    with pytest.raises(RuntimeError, match="apart"):
        simulator.AdvanceTo(duration)
    record = _dense_record(polling, packets, q_start, duration)
    event = _event_record(polling, packets, q_start, duration)
    np.testing.assert_array_equal(record.t_s, event.t_s)
    assert np.abs(record.q_link - event.q_link).max() < 1e-5
    assert np.ptp(event.q_link, axis=0).max() > 0.1


@pytest.mark.parametrize("duration", [0.0, -1.0, float("nan"), float("inf"), True])
def test_a_playback_needs_a_positive_duration(playback, duration):
    scenario, packets, q_start, _ = playback
    builder = DiagramBuilder()
    _, _, robot, loggers = AddPathPlayback(builder, scenario, packets, q_start=q_start)
    with pytest.raises(ValueError, match=r"duration_s = .* must be a finite time > 0"):
        simulate_playback(builder.Build(), robot, loggers, duration)
