"""The experiment's figures of issue-free reading: e at the tracker's rate against the robot's
set-point, the motion and settle phases, the states against the limits and σ carried over.

Each is checked against an independent computation: the set-point against the interpolator's
own ramp function and, in the paper's chain, against the closed form (the packets linearly
interpolated one uplink period behind, from the poll after each tick); the phases on hand-made
samples; the carried σ against the C8 study's own chain.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import LogVectorOutput

from telesmooth.diagrams.offline_playback import (
    RAMP_START_LOG,
    AddPathPlayback,
    set_points,
    simulate_playback,
)
from telesmooth.diagrams.scenario import LoadScenario
from telesmooth.smoothing.metrics import motion_span
from telesmooth.studies.comparison import (
    _phase_means,
    _state_summary,
    _tracker_phases,
    prepare_comparison,
    run_method,
    run_summary,
)
from telesmooth.studies.experiment import (
    CARRIED_LABEL,
    ExperimentConfig,
    carried_sigma0,
    experiment_scenario,
    make_tasks,
    run_task,
    run_task_group,
    task_groups,
)
from telesmooth.systems.command_interpolator import ramp_desired_state

FAST = "{haptic: {lasa_mapping: {time_scale: 4.0, hold_start_s: 0.5, hold_end_s: 1.0}}}"


# --- the motion phase -------------------------------------------------------------------------


def test_the_motion_phase_runs_from_the_last_rest_sample_to_the_first_final_one():
    q = np.zeros((12, 2))
    q[4:8, 1] = [0.1, 0.3, 0.2, 0.4]       # moves at 4..7
    q[8:, 1] = 0.5                           # final pose from 8
    q[:4, 0] = 1e-9                          # round-off at rest is not motion
    assert motion_span(q) == (3, 8)
    assert motion_span(np.ones((5, 3))) is None
    # Moving from the first sample to the last: the whole recording.
    assert motion_span(np.arange(6.0)[:, None]) == (0, 5)


def test_phase_means_split_at_the_motion_and_leave_out_the_start():
    errors = np.array([9.0, 1.0, 2.0, 3.0, 5.0, 7.0])
    assert _phase_means(errors, (1, 3)) == {"motion_mean": 2.0, "settle_mean": 6.0}
    assert all(math.isnan(v) for v in _phase_means(errors, None).values())
    # No settle samples after a motion that ends the recording.
    assert math.isnan(_phase_means(errors, (2, 5))["settle_mean"])
    # The tracker's samples: from the first response less the ramp to the last response.
    t = 0.01 * np.arange(100)
    motion, settle = _tracker_phases((1, 2), np.array([0.1, 0.3, 0.5, 0.7]), 0.25, t)
    assert t[motion][0] == pytest.approx(0.05) and t[motion][-1] == pytest.approx(0.5)
    assert t[settle][0] == pytest.approx(0.51) and settle.sum() == 49


def test_the_state_summary_takes_the_worst_joint_and_none_without_states():
    metrics = {"state_acceleration": {"max_over_limit": [0.5, 1.2],
                                      "fraction_over_limit": [0.0, 0.25]},
               "state_jerk": {"max_over_limit": [2.0, 0.1], "fraction_over_limit": [0.5, 0.0]}}
    assert _state_summary(metrics) == {
        "state_acc_max_over_limit": 1.2, "state_acc_fraction_over": 0.25,
        "state_jerk_max_over_limit": 2.0, "state_jerk_fraction_over": 0.5}
    assert set(_state_summary({}).values()) == {None}


# --- the set-point ----------------------------------------------------------------------------


def test_set_points_follow_the_interpolators_own_ramp_function():
    rng = np.random.default_rng(3)
    starts = np.sort(rng.uniform(0.0, 5.0, 9))
    starts[0] = 0.0
    rows = np.column_stack([starts, rng.normal(size=(9, 2)), rng.normal(size=(9, 2))])
    logged = np.repeat(rows, 3, axis=0)              # each ramp logged several times
    times = np.sort(rng.uniform(-0.5, 6.0, 300))
    for lead in (0.0, 0.004):
        found = set_points(logged, times, 0.25, lead_s=lead)
        for t, q in zip(times, found):
            active = np.flatnonzero(starts <= t + lead)
            row = rows[active[-1]] if active.size else rows[0]
            expected, _ = ramp_desired_state(row[1:3], row[3:], row[0] if active.size else
                                             t + lead, 0.25, t + lead)
            np.testing.assert_array_equal(q, expected if active.size else row[1:3])


@pytest.fixture(scope="module")
def angle_setup():
    base = LoadScenario(scenario_text=FAST)
    scenario = experiment_scenario(base, ExperimentConfig(settle_s=2.0), "Angle", 0,
                                   speed=2.5)
    return prepare_comparison(scenario)


def test_e_at_the_tracker_rate_is_the_distance_to_the_closed_form_set_point(angle_setup):
    """Paper chain: the robot ramps to each packet over one period from the packet's send
    time (its ``command_time``; it polls 0.1 ms later, when the ramp's fraction is still
    that of the instant it was issued), so its set-point is the packets linearly
    interpolated, packet k reached one period after its tick; e at the tracker's rate is the
    tool's distance from the FK of that, computed here from the run's packets alone."""
    setup = angle_setup
    run = run_method(setup, "bmfls")
    period = setup.period_s
    ticks = run.t_s + period                          # packet k reached here
    knots_t = np.r_[ticks[0] - period, ticks]
    knots_q = np.vstack([setup.q_start, run.packets])
    t = run.tracker_t_s
    expected_q = np.column_stack([np.interp(t, knots_t, knots_q[:, j])
                                  for j in range(knots_q.shape[1])])
    e = np.linalg.norm(run.tool_position_m - setup.fk(expected_q), axis=-1)
    figures = run.metrics["response_error_tracker_rate_m"]
    assert figures["mean"] == pytest.approx(e.mean(), rel=1e-9)
    assert figures["max"] == pytest.approx(e.max(), rel=1e-9)
    # The phases: the motion from the robot's start towards the first moving packet.
    first, last = setup.motion
    delay = round(run.metrics["delay_s"] / period)
    begin = (first + delay) * period                 # its response instant less the ramp
    end = (last + delay) * period + setup.ramp_s
    motion = (t >= begin - 1e-12) & (t <= end + 1e-12)
    assert figures["motion_mean"] == pytest.approx(e[motion].mean(), rel=1e-9)
    assert figures["settle_mean"] == pytest.approx(e[t > end + 1e-12].mean(), rel=1e-9)
    # At command instants, the motion phase is the same samples of e.
    summary = run_summary(run.metrics)
    assert summary["e_motion_mean_m"] == pytest.approx(
        run.response_error_m[first:last + 1].mean(), rel=1e-12)
    assert summary["e_settle_mean_m"] == pytest.approx(
        run.response_error_m[last + 1:].mean(), rel=1e-12)
    # The motion phase's Cartesian deformation, from the estimate and the operator's track.
    d = np.linalg.norm(setup.fk(run.estimate) - setup.operator_tool_m, axis=-1)
    assert summary["cartesian_deformation_motion_mean_m"] == pytest.approx(
        d[first:last + 1].mean(), rel=1e-12)
    # The whole run's mean: the same distances over every sample, the holds included.
    assert summary["cartesian_deformation_mean_m"] == pytest.approx(d.mean(), rel=1e-9)
    assert summary["cartesian_deformation_mean_m"] < summary["cartesian_deformation_motion_mean_m"]


@pytest.mark.parametrize("chain", ["paper", "deployed"])
def test_set_points_from_the_logged_ramps_are_the_robots_desired_state(angle_setup, chain):
    """The robot's own desired state, logged every 10 ms in a diagram built for the test,
    against :func:`set_points` from the ramps the playback logs (deployed: behind the link
    and the guard, whose commands start ramps at the 10 ms polls)."""
    setup = prepare_comparison(angle_setup.scenario, chain=chain)
    run = run_method(setup, "offline-cks")
    builder = DiagramBuilder()
    _, _, robot, loggers = AddPathPlayback(builder, setup.scenario, run.packets,
                                           q_start=setup.q_start, chain=chain)
    loggers["desired"] = LogVectorOutput(robot.GetOutputPort("state_desired"), builder, 0.01)
    diagram = builder.Build()
    logs = simulate_playback(diagram, robot, loggers, setup.duration_s)[1]
    desired = logs["desired"]
    ramps = logs[RAMP_START_LOG if chain == "deployed" else "command_ramp"].values
    n = setup.q_start.size
    found = set_points(ramps, desired.t_s, setup.scenario.onboard.interpolator.ramp_duration_s)
    np.testing.assert_allclose(found, desired.values[:, :n], rtol=0, atol=1e-12)
    assert np.ptp(found, axis=0).max() > 0.1          # the robot went somewhere


# --- σ carried over ---------------------------------------------------------------------------


def test_carried_sigma_is_the_c8_studys_chain_and_demo_0_starts_from_sigma_0():
    base = LoadScenario(scenario_text=FAST)
    config = ExperimentConfig(shapes=("Angle",), demos=(0, 2), methods=("original",
                              "online-cks"), sensitivity_shapes=(), c8_shapes=("Angle",),
                              settle_s=2.0, speeds=(2.5,), kf_sigma0_factors=())
    tasks = make_tasks(config)
    c8 = run_task(next(t for t in tasks if t.kind == "c8"), base, config)["c8"]["demos"]
    for demo in (0, 2):
        group = next(g for g in task_groups(tasks) if g[0].kind == "run" and g[0].demo == demo)
        records = {r["label"]: r for r in run_task_group(group, base, config)}
        carried = records[CARRIED_LABEL]
        fresh = records["online-cks"]
        start = carried["online_cks"]["sigma_start"]
        assert start == c8[demo]["carried"]["sigma_start"]
        assert carried["online_cks"]["sigma_end"] == c8[demo]["carried"]["sigma_end"]
        assert carried["online_cks"]["sigma_monotone"] == c8[demo]["carried"]["sigma_monotone"]
        task = next(t for t in group if t.study == "carried")
        if demo == 0:
            assert carried_sigma0(base, config, task) is None
            assert carried["metrics"] == fresh["metrics"]
        else:
            assert np.all(np.asarray(start) < np.asarray(fresh["online_cks"]["sigma_start"]))
            assert carried["metrics"]["fd_jerk_max_over_limit"] == pytest.approx(
                c8[demo]["carried"]["fd_jerk_max_over_limit"], rel=1e-12)
