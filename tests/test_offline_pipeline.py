"""The offline mode: recorded session → Offline-CKS → validation of every sample → 4 Hz playback.

One short synthetic session (8 s, air-bearing arm) is planned once per module; the tests check
the sampling (the FIFO's z_k), the solve (an independent call gives the same states), the
finite-difference limits, the rejection of a path that collides or breaks a joint limit, and
that playback sends exactly the planned samples through the uplink to the plant.
"""

import dataclasses

import numpy as np
import pytest

from telesmooth.arms.collision import ArmCollisionModel
from telesmooth.arms.planar import (
    AIR_BEARING_ARM,
    AIR_BEARING_LINK_LENGTHS_M,
    planar_3r_inverse_kinematics,
    planar_forward_kinematics,
)
from telesmooth.arms.workspace import AIR_BEARING_WORKSPACE, BoxObstacle, Workspace
from telesmooth.diagrams import offline_planning
from telesmooth.diagrams.offline_planning import plan_offline
from telesmooth.diagrams.offline_playback import (
    MakeOfflinePlaybackDiagram,
    run_offline,
    simulate_playback,
)
from telesmooth.diagrams.offline_validation import validate_joint_path
from telesmooth.diagrams.scenario import LoadScenario, make_haptic_recording
from telesmooth.smoothing.kalman import rest_start_prior
from telesmooth.smoothing.metrics import VIOLATION_RTOL
from telesmooth.smoothing.model import JerkModel
from telesmooth.smoothing.offline import OfflineCksResult, solve_offline_cks

SESSION = ("{haptic: {source: synthetic, synthetic: {duration_s: 8.0, hold_start_s: 1.0, "
           "hold_end_s: 1.0}}, settle_s: 1.0}")
TICK = 0.25
HISTORY = 3


@pytest.fixture(scope="module")
def scenario():
    return LoadScenario(scenario_text=SESSION)


@pytest.fixture(scope="module")
def plan(scenario):
    return plan_offline(scenario)


def _extended(plan):
    """What the plant receives: 3 samples of the start pose, the plan, 3 of the last pose."""
    return np.vstack([np.tile(plan.q_start, (HISTORY, 1)), plan.q_planned,
                      np.tile(plan.q_planned[-1], (HISTORY, 1))])


def _scenario_with_box_at_middle_sample(scenario, plan):
    """A 4 cm box (in the table plane) at the tool point of the middle planned sample."""
    middle = len(plan.t_s) // 2
    x, y = planar_forward_kinematics(plan.q_planned[middle], AIR_BEARING_LINK_LENGTHS_M)
    probe = BoxObstacle("probe", (x, y, 0.0), (0.04, 0.04, 0.1))
    workspace = Workspace(
        obstacles=AIR_BEARING_WORKSPACE.obstacles + (probe,),
        bounds_lower_m=AIR_BEARING_WORKSPACE.bounds_lower_m,
        bounds_upper_m=AIR_BEARING_WORKSPACE.bounds_upper_m, planar=True)
    return dataclasses.replace(scenario, workspace=workspace), middle


def test_samples_are_the_fifo_samples_of_the_ik_targets(scenario, plan):
    # Row k is the IK target the FIFO reads at t_k: the IK of the pose sampled one haptic
    # period before (25 haptic samples per tick); row 0 is the start pose.
    recording = make_haptic_recording(scenario)
    np.testing.assert_allclose(plan.t_s, TICK * np.arange(len(plan.t_s)), rtol=0, atol=1e-12)
    assert plan.t_s[-1] >= recording.t_s[-1] + 0.01
    np.testing.assert_array_equal(plan.q_raw[0], plan.q_start)
    assert plan.ik_failures == 0
    for k in range(1, len(plan.t_s)):
        j = min(25 * k - 1, recording.num_samples - 1)
        q, reachable = planar_3r_inverse_kinematics(recording.pose[j, :2], recording.pose[j, 2],
                                                    AIR_BEARING_ARM, elbow=+1)
        assert reachable
        # To round-off, not to the bit: the plan's IK works in plain floats (the math module,
        # planar_3r_inverse_kinematics_point), this one in numpy, whose transcendental
        # functions use SIMD code on some CPUs and can differ in the last bit (they do on one
        # of our machines). A wrong sample (one haptic period off) moves q by ~1e-4 rad.
        np.testing.assert_allclose(plan.q_raw[k], q, rtol=0, atol=1e-12, err_msg=f"tick {k}")


def test_plan_equals_an_independent_offline_cks_solve(scenario, plan):
    """The plan starts, as the robot, at rest at its start pose (the rest start prior)."""
    smoother = scenario.smoother
    model = JerkModel.make(TICK, smoother.sigma, smoother.r, num_joints=3)
    dut = solve_offline_cks(plan.q_raw, model,
                            max_acceleration=smoother.max_acceleration_rad_per_s2,
                            max_jerk=smoother.max_jerk_rad_per_s3, constraint="trajectory",
                            rest_at_end=True, start_position=plan.q_start,
                            prior=rest_start_prior(plan.q_start, model))
    assert dut.is_success and plan.solver.is_success
    assert plan.solver.solution_results == dut.solution_results
    np.testing.assert_allclose(plan.states_planned, dut.states, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(plan.q_planned, dut.states[:, :, 0])
    np.testing.assert_allclose(plan.solver.objective, dut.objective, rtol=1e-9, atol=0)


def test_planned_path_meets_the_fd_limits_and_passes_validation(scenario, plan):
    a_max = scenario.smoother.max_acceleration_rad_per_s2
    j_max = scenario.smoother.max_jerk_rad_per_s3
    path = _extended(plan)
    acceleration = np.diff(path, n=2, axis=0) / TICK**2
    jerk = np.diff(path, n=3, axis=0) / TICK**3
    assert np.abs(acceleration).max() <= a_max * (1 + VIOLATION_RTOL)
    assert np.abs(jerk).max() <= j_max * (1 + VIOLATION_RTOL)
    # The limits are active (the raw session breaks them), so the check is not vacuous.
    raw_acceleration = np.diff(plan.q_raw, n=2, axis=0) / TICK**2
    assert np.abs(raw_acceleration).max() > 5 * a_max
    assert np.abs(acceleration).max() > 0.99 * a_max
    # Rest at the end; validation passes in the default workspace.
    np.testing.assert_allclose(plan.states_planned[-1, :, 1:], 0.0, atol=1e-9)
    assert plan.is_valid and plan.reason == "" and plan.violations == ()
    assert plan.validation.fd_limits_enforced
    assert np.all(plan.validation.min_distance_m >= scenario.collision_checker.safety_margin_m)
    assert max(plan.validation.fd_limits["fd_acceleration"]["max_over_limit"]) <= 1 + 1e-6
    stages = ("inverse_kinematics", "solve", "validation")
    assert all(plan.timings_s[stage] >= 0.0 for stage in stages)
    assert plan.timings_s["total"] == pytest.approx(sum(plan.timings_s[s] for s in stages))


def test_state_mode_reports_fd_excess_without_rejecting(scenario):
    # The paper's (11) bounds the state estimates only; FD excess is reported, not enforced.
    dut = plan_offline(scenario, constraint="state")
    assert dut.is_valid and not dut.validation.fd_limits_enforced
    assert max(dut.validation.fd_limits["fd_acceleration"]["max_over_limit"]) > 1.01


def test_a_path_that_collides_is_rejected_and_never_played(scenario, plan):
    boxed, middle = _scenario_with_box_at_middle_sample(scenario, plan)
    dut = plan_offline(boxed)
    # Same samples and smoother, so the same path; only the scene differs.
    np.testing.assert_array_equal(dut.q_planned, plan.q_planned)
    assert dut.solver.is_success and not dut.is_valid
    at_middle = [v for v in dut.violations if v.sample == middle]
    assert len(at_middle) == 1
    violation = at_middle[0]
    assert violation.kind == "collision"
    assert (violation.body_a, violation.body_b) == ("link3", "probe")
    assert violation.time_s == pytest.approx(middle * TICK)
    assert violation.value < 0.0 and violation.limit == scenario.collision_checker.safety_margin_m
    # The reported distance is the rigid arm's at that sample, from a model of its own.
    model = ArmCollisionModel(boxed.arm_description, boxed.workspace_or_default,
                              distance_horizon_m=boxed.collision_checker.distance_horizon_m)
    expected = model.query(dut.q_planned[middle]).min_distance_m
    assert violation.value == pytest.approx(expected, abs=1e-12)
    assert dut.validation.min_distance_m[middle] == pytest.approx(expected, abs=1e-12)
    assert f"sample {middle} " in str(violation) and "link3/probe" in str(violation)
    assert "collision link3/probe" in dut.reason
    refusal = (r"refusing to play back an invalid offline plan: \d+ violation\(s\): "
               r"sample \d+ .*collision link3/probe")
    with pytest.raises(ValueError, match=refusal):
        MakeOfflinePlaybackDiagram(boxed, dut)
    # A plan valid in the default scene is re-checked against the scene it is played in.
    with pytest.raises(ValueError, match=r"fails the check against this scenario: .*probe"):
        MakeOfflinePlaybackDiagram(boxed, plan)
    rejected, logs = run_offline(boxed)
    assert not rejected.is_valid and logs is None


def test_joint_limit_and_non_finite_samples_are_reported(scenario, plan):
    q = np.tile(plan.q_start, (6, 1))
    t = TICK * np.arange(6)
    upper = scenario.arm_description.joint_upper_rad[2]
    q[3, 2] = upper + 0.05  # wrist beyond +170°
    q[4, 0] = np.nan
    dut = validate_joint_path(q, t, scenario, check_fd_limits=False)
    assert [(v.kind, v.sample, v.joint) for v in dut] == [
        ("non_finite", 4, "shoulder"), ("joint_limit", 3, "wrist")]
    assert dut[1].value == pytest.approx(upper + 0.05) and dut[1].limit == upper
    assert dut[1].time_s == pytest.approx(0.75)
    assert "joint 'wrist' = " in str(dut[1]) and "beyond its limit" in str(dut[1])
    # The same jump also breaks the FD limits, attributed to the newest sample involved.
    with_fd = validate_joint_path(q[:4], t[:4], scenario)
    kinds = {(v.kind, v.joint) for v in with_fd}
    assert ("joint_limit", "wrist") in kinds and ("fd_acceleration", "wrist") in kinds
    first_fd = min(v.sample for v in with_fd if v.kind == "fd_acceleration")
    assert first_fd == 3
    # The planned path itself has none.
    assert validate_joint_path(plan.q_planned, plan.t_s, scenario,
                               start_position=plan.q_start) == []


@pytest.mark.parametrize("call,match", [
    (lambda s: plan_offline(s, constraint="soft"), r"constraint = 'soft' must be one of"),
    (lambda s: plan_offline(s, max_velocity=-1.0),
     r"max_velocity_rad_per_s\[0\] = -1.0 for joint 0 \('shoulder'\) must be > 0"),
    (lambda s: validate_joint_path(np.zeros((4, 2)), np.arange(4) * TICK, s),
     r"q has shape \(4, 2\); expected \(N >= 1, 3\)"),
    (lambda s: validate_joint_path(np.zeros((3, 3)), np.array([0.0, 0.25, 0.6]), s),
     r"t_s must be uniform with the uplink period 0.25"),
    (lambda s: plan_offline(dataclasses.replace(
        s, haptic=dataclasses.replace(s.haptic, source="lcm"))), r"needs a recorded session"),
])
def test_invalid_input_raises(scenario, call, match):
    with pytest.raises(ValueError, match=match):
        call(scenario)


def test_a_failed_solve_gives_an_invalid_plan_with_the_reason(scenario, monkeypatch):
    def failing_solve(z, model, **kwargs):
        n, j = z.shape
        return OfflineCksResult(
            states=np.full((n, j, 4), np.nan), is_success=False,
            solution_results=("kSolutionFound", "kInfeasibleConstraints", "kSolutionFound"),
            solver_name="Clarabel", objective=np.full(j, np.nan),
            solve_time_s=np.zeros(j), build_time_s=np.zeros(j),
            infeasible_constraints=((), ("fd_jerk_limit_elbow",), ()),
            tolerance_reached=np.full(j, np.nan))

    monkeypatch.setattr(offline_planning, "solve_offline_cks", failing_solve)
    dut = plan_offline(scenario)
    assert not dut.is_valid and not dut.validation.checked
    assert dut.reason == ("Offline-CKS failed for joint 'elbow': kInfeasibleConstraints "
                          "(violated: ['fd_jerk_limit_elbow'])")
    with pytest.raises(ValueError, match=r"invalid offline plan: Offline-CKS failed for joint "
                                         r"'elbow'"):
        MakeOfflinePlaybackDiagram(scenario, dut)


def test_playback_sends_the_planned_samples_at_4_hz_and_the_robot_follows(scenario, plan):
    handles = MakeOfflinePlaybackDiagram(scenario, plan)
    assert handles.diagram.get_name() == "offline_playback"
    assert handles.duration_s == pytest.approx(plan.t_s[-1] + scenario.settle_s)
    simulator, copied = simulate_playback(handles.diagram, handles.robot, handles.logs,
                                          handles.duration_s)
    context = simulator.get_context()
    assert context.get_time() == pytest.approx(handles.duration_s)
    seq = handles.logs["sequence_number"].FindLog(context)
    rows = seq.sample_times()
    # The logger at t_m sees packet m − 1 (−1 before the first tick).
    np.testing.assert_allclose(rows, TICK * np.arange(rows.size), rtol=0, atol=1e-12)
    np.testing.assert_array_equal(seq.data()[0], np.arange(rows.size) - 1)
    sent = handles.logs["q_sent"].FindLog(context).data().T
    states = handles.logs["state_sent"].FindLog(context).data().T
    times = handles.logs["send_time"].FindLog(context).data()[0]
    np.testing.assert_array_equal(sent[0], plan.q_start)
    num_samples = len(plan.t_s)
    assert rows.size - 1 >= num_samples  # every planned packet was seen
    for m in range(1, rows.size):
        k = m - 1
        np.testing.assert_array_equal(sent[m], plan.q_planned[min(k, num_samples - 1)],
                                      err_msg=f"packet {k}")
        assert times[m] == pytest.approx(k * TICK, abs=1e-12)
        if k < num_samples:
            np.testing.assert_array_equal(states[m, 3:6], plan.states_planned[k, :, 1])
    # The robot accepted every command and ends on the last (rest) pose.
    assert np.all(handles.logs["command_rejected"].FindLog(context).data() == 0.0)
    q_link = copied["tracker"].q_link
    assert np.abs(q_link[-1] - plan.q_planned[-1]).max() < 0.01
    assert np.abs(q_link[0] - plan.q_start).max() < 1e-9


def test_run_offline_returns_the_plan_and_copied_logs(scenario, plan):
    dut, logs = run_offline(scenario)
    np.testing.assert_array_equal(dut.q_planned, plan.q_planned)
    assert set(logs) == {"sequence_number", "send_time", "q_sent", "state_sent", "tracker",
                         "command_rejected", "command_ramp", "plant_state"}
    # The plant's [q; v] at the tracker's instants: its link angles are the tracker's.
    state = logs["plant_state"]
    np.testing.assert_array_equal(state.t_s, logs["tracker"].t_s)
    assert state.values.shape == (state.t_s.size, 12)
    np.testing.assert_allclose(state.values[:, 0:6:2] + state.values[:, 1:6:2],
                               logs["tracker"].q_link, rtol=0, atol=1e-15)
    assert logs["q_sent"].values.shape[1] == 3
    np.testing.assert_array_equal(logs["q_sent"].values[-1], plan.q_planned[-1])
    assert np.abs(logs["tracker"].q_link[-1] - plan.q_planned[-1]).max() < 0.01
