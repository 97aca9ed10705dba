"""Inverse kinematics: FK(IK(x)) round trips, holding on bad commands, clutch re-indexing."""

import dataclasses
import math

import numpy as np
import pytest
from pydrake.math import RigidTransform, RollPitchYaw, RotationMatrix
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import LogVectorOutput, TrajectorySource
from pydrake.trajectories import PiecewisePolynomial

from telesmooth.arms import ik_step as ik_step_module
from telesmooth.arms.description import AIR_BEARING_ARM_3DOF, SPACE_ARM_6DOF
from telesmooth.arms.planar import (
    AIR_BEARING_ARM,
    planar_end_effector_angle,
    planar_forward_kinematics,
)
from telesmooth.arms.space_arm_ik import (
    SpaceArmIkStatus,
    SpaceArmKinematics,
    pose_error,
    pose_to_rigid_transform,
    rigid_transform_to_pose,
    solve_space_arm_ik,
)
from telesmooth.datasets.lasa import lasa_operator_session
from telesmooth.systems.inverse_kinematics import (
    IkStatus,
    InverseKinematicsConfig,
    InverseKinematicsSystem,
    apply_clutch_offset,
    clutch_offset,
    planar_arm_from_description,
)

PERIOD_S = 0.01
LENGTHS = AIR_BEARING_ARM.link_lengths_m
CONFIG = InverseKinematicsConfig()
Q0_PLANAR = np.array([0.1, 1.2, -0.6])
Q0_SPACE = np.array([0.3, 0.4, -1.0, 0.3, 0.2, 0.1])


@pytest.fixture(scope="module")
def kinematics():
    return SpaceArmKinematics(SPACE_ARM_6DOF)


def _planar_pose(q):
    q = np.asarray(q, dtype=float)
    return np.append(planar_forward_kinematics(q, LENGTHS), planar_end_effector_angle(q))


def _wrapped(angle):
    return math.remainder(angle, 2.0 * math.pi)


class _Harness:
    """A system under test with one context, stepped one update at a time."""

    def __init__(self, dut):
        self.dut = dut
        self.context = dut.CreateDefaultContext()

    def step(self, pose, enable=None):
        self.dut.get_pose_desired_input_port().FixValue(self.context, np.asarray(pose, float))
        if enable is not None:
            self.dut.get_enable_input_port().FixValue(self.context, [enable])
        self.context.SetDiscreteState(self.dut.EvalUniquePeriodicDiscreteUpdate(self.context))
        return self

    @property
    def q(self):
        return self.dut.get_q_target_output_port().Eval(self.context).copy()

    @property
    def failed(self):
        return self.dut.get_ik_failed_output_port().Eval(self.context)[0]

    @property
    def status(self):
        return IkStatus(int(self.dut.get_ik_status_output_port().Eval(self.context)[0]))

    @property
    def pose_commanded(self):
        return self.dut.get_pose_commanded_output_port().Eval(self.context).copy()


def _planar(**config):
    return _Harness(InverseKinematicsSystem(
        InverseKinematicsConfig(**config), arm=AIR_BEARING_ARM_3DOF,
        initial_position_rad=Q0_PLANAR))


def _space(**config):
    return _Harness(InverseKinematicsSystem(
        InverseKinematicsConfig(**config), arm=SPACE_ARM_6DOF, initial_position_rad=Q0_SPACE))


def _smooth_path(rng, center, amplitude, num_samples):
    """center + amplitude sin(w t + phase), random w in [0.5, 1.5] rad/s, t = k * 0.01 s."""
    t = PERIOD_S * np.arange(num_samples)[:, None]
    frequency = rng.uniform(0.5, 1.5, size=len(center))
    phase = rng.uniform(0.0, 2.0 * math.pi, size=len(center))
    path = center + amplitude * np.sin(frequency * t + phase)
    return path - path[0] + center  # starts exactly at center


# --- config, constructor, port contract ---


@pytest.mark.parametrize("field, value, match", [
    ("period_s", -0.01, r"InverseKinematicsConfig.period_s = -0.01 must be positive"),
    ("elbow", 0, r"InverseKinematicsConfig.elbow = 0 must be \+1 or -1"),
    ("elbow", True, r"elbow = True"),
    ("max_joint_step_rad", 0.0, r"max_joint_step_rad = 0.0 must be positive and finite"),
    ("position_tolerance_m", float("inf"), r"position_tolerance_m = inf"),
    ("orientation_tolerance_rad", -1e-3, r"orientation_tolerance_rad = -0.001"),
    ("max_iterations", 0, r"max_iterations = 0 must be an integer >= 1"),
    ("max_iterations", 2.5, r"max_iterations = 2.5"),
])
def test_config_validation_names_field_and_value(field, value, match):
    with pytest.raises(ValueError, match=match):
        InverseKinematicsConfig(**{field: value})


def test_constructor_validation_names_joint_and_value():
    with pytest.raises(ValueError, match=r"has shape \(2,\); expected \(3,\)"):
        InverseKinematicsSystem(arm=AIR_BEARING_ARM_3DOF, initial_position_rad=[0.0, 0.0])
    with pytest.raises(ValueError,
                       match=r"initial_position_rad\[1\] = nan for joint 1 \('elbow'\)"):
        InverseKinematicsSystem(arm=AIR_BEARING_ARM_3DOF, initial_position_rad=[0, np.nan, 0])
    with pytest.raises(ValueError, match=r"initial_position_rad\[5\] = 3.1 for joint 5 "
                                         r"\('wrist_roll'\) must be finite and within"):
        InverseKinematicsSystem(arm=SPACE_ARM_6DOF, initial_position_rad=[0, 0, 0, 0, 0, 3.1])
    two_joints = dataclasses.replace(
        AIR_BEARING_ARM_3DOF, joints=AIR_BEARING_ARM_3DOF.joints[:2],
        links=AIR_BEARING_ARM_3DOF.links[:2])
    with pytest.raises(ValueError, match=r"neither a planar 3R arm"):
        InverseKinematicsSystem(arm=two_joints, initial_position_rad=[0.0, 0.0])
    with pytest.raises(ValueError, match=r"config = .* must be an InverseKinematicsConfig"):
        InverseKinematicsSystem({"period_s": 0.01}, arm=AIR_BEARING_ARM_3DOF,
                                initial_position_rad=Q0_PLANAR)


def test_planar_arm_from_description_equals_the_planar_module_arm():
    assert planar_arm_from_description(AIR_BEARING_ARM_3DOF) == AIR_BEARING_ARM
    with pytest.raises(ValueError, match=r"joint 'shoulder_pitch' axis"):
        planar_arm_from_description(dataclasses.replace(
            SPACE_ARM_6DOF, joints=SPACE_ARM_6DOF.joints[:3], links=SPACE_ARM_6DOF.links[:3]))


@pytest.mark.parametrize("arm, q0, m", [(AIR_BEARING_ARM_3DOF, Q0_PLANAR, 3),
                                        (SPACE_ARM_6DOF, Q0_SPACE, 6)],
                         ids=["planar", "space"])
def test_port_contract_and_initial_outputs(arm, q0, m):
    dut = InverseKinematicsSystem(arm=arm, initial_position_rad=q0)
    n = arm.num_joints
    assert [dut.get_input_port(i).get_name() for i in range(4)] == [
        "pose_desired", "enable", "q_anchor", "anchor"]
    assert [dut.get_input_port(i).size() for i in range(4)] == [m, 1, n, 1]
    assert [dut.get_output_port(i).get_name() for i in range(4)] == [
        "q_target", "ik_failed", "ik_status", "pose_commanded"]
    assert [dut.get_output_port(i).size() for i in range(4)] == [n, 1, 1, m]
    assert dut.num_input_ports() == 4 and dut.num_output_ports() == 4
    assert not any(dut.HasDirectFeedthrough(i, j) for i in range(4) for j in range(4))
    timing = dut.GetUniquePeriodicDiscreteUpdateAttribute()
    assert (timing.period_sec(), timing.offset_sec()) == (PERIOD_S, 0.0)
    assert len(dut.pose_names) == m and dut.is_planar == (m == 3)
    context = dut.CreateDefaultContext()
    np.testing.assert_array_equal(dut.get_q_target_output_port().Eval(context), q0)
    assert dut.get_ik_failed_output_port().Eval(context)[0] == 0.0
    assert dut.get_ik_status_output_port().Eval(context)[0] == IkStatus.OK
    np.testing.assert_array_equal(dut.get_pose_commanded_output_port().Eval(context),
                                  dut.forward_kinematics_pose(q0))


# --- the pure clutch functions ---


def test_clutch_offset_maps_the_device_onto_the_reference():
    rng = np.random.default_rng(11)
    for _ in range(50):
        reference, device = rng.uniform(-2.0, 2.0, size=(2, 3))
        offset = clutch_offset(reference, device, planar=True)
        np.testing.assert_allclose(apply_clutch_offset(device, offset, planar=True), reference,
                                   rtol=0, atol=1e-15)
        reference, device = rng.uniform(-1.5, 1.5, size=(2, 6))
        offset = clutch_offset(reference, device, planar=False)
        assert offset.shape == (7,)
        assert np.linalg.norm(offset[3:]) == pytest.approx(1.0, abs=1e-12)
        commanded = apply_clutch_offset(device, offset, planar=False)
        np.testing.assert_allclose(commanded[:3], reference[:3], rtol=0, atol=1e-15)
        angle = pose_error(pose_to_rigid_transform(commanded),
                           pose_to_rigid_transform(reference))[1]
        assert angle < 1e-12


def test_spatial_clutch_rotation_is_left_multiplied():
    rng = np.random.default_rng(12)
    offset_rotation = RotationMatrix(RollPitchYaw(rng.uniform(-1, 1, 3)))
    offset = np.concatenate([[0.1, -0.2, 0.3], offset_rotation.ToQuaternion().wxyz()])
    device = rng.uniform(-1, 1, 6)
    commanded = apply_clutch_offset(device, offset, planar=False)
    # R_cmd = R_off R_dev, p_cmd = p_dev + p_off
    expected = offset_rotation.multiply(RotationMatrix(RollPitchYaw(device[3:])))
    actual = RotationMatrix(RollPitchYaw(commanded[3:]))
    np.testing.assert_allclose(actual.matrix(), expected.matrix(), rtol=0, atol=1e-12)
    np.testing.assert_allclose(commanded[:3], device[:3] + [0.1, -0.2, 0.3], atol=1e-15)


# --- FK(IK(x)) round trips ---


def test_planar_round_trip_on_a_smooth_path():
    rng = np.random.default_rng(0)
    path = _smooth_path(rng, Q0_PLANAR, np.array([1.0, 0.5, 1.2]), 400)
    assert np.all(path[:, 1] > 0.1)  # the elbow stays on the +1 branch, off the singularity
    harness = _planar()
    for q_true in path:
        pose = _planar_pose(q_true)
        harness.step(pose)
        assert harness.failed == 0.0 and harness.status == IkStatus.OK
        q = harness.q
        np.testing.assert_allclose(planar_forward_kinematics(q, LENGTHS), pose[:2],
                                   rtol=0, atol=1e-9)
        assert abs(_wrapped(planar_end_effector_angle(q) - pose[2])) < 1e-9
        # One branch, inside limits narrower than 2 pi: the IK recovers the path itself.
        np.testing.assert_allclose(q, q_true, rtol=0, atol=1e-9)
        np.testing.assert_array_equal(harness.pose_commanded, pose)  # zero clutch offset


def test_space_round_trip_on_a_smooth_path(kinematics):
    rng = np.random.default_rng(1)
    path = _smooth_path(rng, Q0_SPACE, np.array([0.6, 0.3, 0.4, 0.5, 0.5, 1.0]), 300)
    lower, upper = SPACE_ARM_6DOF.joint_lower_rad, SPACE_ARM_6DOF.joint_upper_rad
    assert np.all((path > lower) & (path < upper))
    harness = _space()
    for q_true in path:
        pose = kinematics.tool_pose(q_true)
        harness.step(pose)
        assert harness.failed == 0.0 and harness.status == IkStatus.OK
        position_m, orientation_rad = pose_error(
            kinematics.tool_transform(harness.q), pose_to_rigid_transform(pose))
        assert position_m <= CONFIG.position_tolerance_m
        assert orientation_rad <= CONFIG.orientation_tolerance_rad
        # Newton is run to 1e-3 of the tolerances, and the nearest branch is the path's.
        assert position_m <= 1e-6 and orientation_rad <= 1e-5
        np.testing.assert_allclose(harness.q, q_true, rtol=0, atol=1e-4)


def test_space_solver_on_random_reachable_poses(kinematics):
    rng = np.random.default_rng(2)
    lower, upper = SPACE_ARM_6DOF.joint_lower_rad, SPACE_ARM_6DOF.joint_upper_rad
    num_success = 0
    for _ in range(200):
        q_true = rng.uniform(0.9 * lower, 0.9 * upper)
        seed = np.clip(q_true + rng.uniform(-0.05, 0.05, 6), lower, upper)
        pose = kinematics.tool_pose(q_true)
        q, success, error = solve_space_arm_ik(kinematics, pose, seed, max_joint_step_rad=0.2)
        assert np.all((q >= lower) & (q <= upper)) and np.max(np.abs(q - seed)) <= 0.2 + 1e-12
        if success:
            num_success += 1
            position_m, orientation_rad = pose_error(
                kinematics.tool_transform(q), pose_to_rigid_transform(pose))
            assert position_m <= 1e-4 and orientation_rad <= 1e-3
            # The solver's own residual (its compiled kinematics) against Drake's, to
            # round-off: two forward-kinematics chains over a ~1 m arm (one ULP ~2e-16 m).
            assert (position_m, orientation_rad) == pytest.approx(
                (error.position_m, error.orientation_rad), abs=1e-13)
            # Away from the elbow (q3 = 0) and wrist (q5 = +-pi/2) singularities the other
            # branches are far from the seed, so the answer is the pose's own joint vector.
            if abs(q_true[2]) > 0.2 and abs(math.cos(q_true[4])) > 0.2:
                np.testing.assert_allclose(q, q_true, rtol=0, atol=1e-4)
        else:
            assert error.status != SpaceArmIkStatus.SUCCESS
    # Seeds 0.05 rad off random poses (some near singularities): measured 199/200.
    assert num_success >= 195


def test_pose_vector_round_trip():
    rng = np.random.default_rng(4)
    for _ in range(20):
        pose = np.append(rng.uniform(-1, 1, 3), rng.uniform(-1.4, 1.4, 3))
        np.testing.assert_allclose(rigid_transform_to_pose(pose_to_rigid_transform(pose)), pose,
                                   atol=1e-12)
    with pytest.raises(ValueError, match=r"pose pitch_rad = nan must be finite"):
        pose_to_rigid_transform([0, 0, 0, 0, np.nan, 0])


def test_solver_validation(kinematics):
    with pytest.raises(ValueError,
                       match=r"q_seed\[2\] = 3.0 for joint 2 \('elbow_pitch'\) must be"):
        solve_space_arm_ik(kinematics, np.zeros(6), [0, 0, 3.0, 0, 0, 0])
    with pytest.raises(ValueError, match=r"position_tolerance_m = 0.0 must be positive"):
        solve_space_arm_ik(kinematics, np.zeros(6), np.zeros(6), position_tolerance_m=0.0)
    with pytest.raises(ValueError, match=r"expected \(6,\) = \(x_m"):
        solve_space_arm_ik(kinematics, np.zeros(3), np.zeros(6))


# --- holding on bad commands, then recovering ---


def _hold_then_recover(harness, good_pose, bad_pose, expected_status, recover_pose):
    harness.step(good_pose)
    assert harness.status == IkStatus.OK
    q_held = harness.q
    for _ in range(3):  # stays held, every update
        harness.step(bad_pose)
        assert harness.failed == 1.0 and harness.status == expected_status
        np.testing.assert_array_equal(harness.q, q_held)
    harness.step(recover_pose)
    assert harness.failed == 0.0 and harness.status == IkStatus.OK
    return q_held, harness.q


def test_planar_unreachable_command_holds_then_recovers():
    harness = _planar()
    good = _planar_pose(Q0_PLANAR)
    _, q = _hold_then_recover(harness, good, [1.5, 0.0, 0.0], IkStatus.UNREACHABLE,
                              _planar_pose(Q0_PLANAR + 0.01))
    np.testing.assert_allclose(q, Q0_PLANAR + 0.01, atol=1e-12)
    np.testing.assert_array_equal(harness.pose_commanded, _planar_pose(Q0_PLANAR + 0.01))


def test_planar_limit_violating_command_holds_then_recovers():
    q_near_limit = np.array([0.2, 1.0, math.radians(165.0)])
    beyond = np.array([0.2, 1.0, math.radians(175.0)])  # wrist limit is 170 deg
    harness = _Harness(InverseKinematicsSystem(
        arm=AIR_BEARING_ARM_3DOF, initial_position_rad=q_near_limit))
    _, q = _hold_then_recover(harness, _planar_pose(q_near_limit), _planar_pose(beyond),
                              IkStatus.JOINT_LIMIT, _planar_pose([0.2, 1.0, math.radians(168)]))
    assert q[2] == pytest.approx(math.radians(168.0), abs=1e-12)


def test_planar_too_large_jump_holds():
    harness = _planar()
    _hold_then_recover(harness, _planar_pose(Q0_PLANAR), _planar_pose(Q0_PLANAR + [0.3, 0, 0]),
                       IkStatus.JOINT_STEP, _planar_pose(Q0_PLANAR + [0.15, 0, 0]))


def test_space_unreachable_command_holds_then_recovers(kinematics):
    harness = _space()
    q_held, q = _hold_then_recover(
        harness, kinematics.tool_pose(Q0_SPACE), [3.0, 0.0, 0.45, 0.0, 0.0, 0.0],
        IkStatus.UNREACHABLE, kinematics.tool_pose(Q0_SPACE + 0.01))
    np.testing.assert_allclose(q, Q0_SPACE + 0.01, atol=1e-5)


def test_space_limit_violating_command_holds_then_recovers(kinematics):
    q_near_limit = np.array([0.3, 0.4, -0.5, 0.2, 0.3, math.radians(165.0)])
    beyond = q_near_limit.copy()
    beyond[5] = math.radians(172.0)  # wrist_roll limit is 170 deg
    recover = q_near_limit.copy()
    recover[5] = math.radians(168.0)
    harness = _Harness(InverseKinematicsSystem(
        arm=SPACE_ARM_6DOF, initial_position_rad=q_near_limit))
    _, q = _hold_then_recover(harness, kinematics.tool_pose(q_near_limit),
                              kinematics.tool_pose(beyond), IkStatus.JOINT_LIMIT,
                              kinematics.tool_pose(recover))
    np.testing.assert_allclose(q, recover, atol=1e-5)


def test_space_too_large_jump_holds(kinematics):
    harness = _space()
    _hold_then_recover(harness, kinematics.tool_pose(Q0_SPACE),
                       kinematics.tool_pose(Q0_SPACE + [0.3, 0, 0, 0, 0, 0]),
                       IkStatus.JOINT_STEP, kinematics.tool_pose(Q0_SPACE + [0.1, 0, 0, 0, 0, 0]))


@pytest.mark.parametrize("make, pose_size", [(_planar, 3), (_space, 6)], ids=["planar", "space"])
def test_non_finite_inputs_never_reach_the_outputs(make, pose_size):
    harness = make()
    q0 = harness.q
    pose0 = harness.pose_commanded
    for bad in (np.nan, np.inf, -np.inf):
        for i in range(pose_size):
            pose = pose0.copy()
            pose[i] = bad
            harness.step(pose)
            assert harness.failed == 1.0 and harness.status == IkStatus.INVALID_INPUT
            np.testing.assert_array_equal(harness.q, q0)
            np.testing.assert_array_equal(harness.pose_commanded, pose0)
    harness.step(pose0, enable=np.nan)  # a NaN clutch: held, flagged
    assert harness.failed == 1.0 and harness.status == IkStatus.INVALID_INPUT
    np.testing.assert_array_equal(harness.q, q0)
    harness.step(pose0, enable=1.0)
    assert harness.status == IkStatus.OK
    np.testing.assert_allclose(harness.q, q0, atol=1e-12)


# --- clutch ---


def test_planar_clutch_reindexing_gives_no_jump():
    harness = _planar()
    rng = np.random.default_rng(5)
    path = _smooth_path(rng, Q0_PLANAR, np.array([0.3, 0.2, 0.3]), 50)
    for q in path:
        harness.step(_planar_pose(q), enable=1.0)
    q_held = harness.q
    reference = _planar_pose(q_held)
    device = _planar_pose(path[-1])
    # Released: the device moves far (0.2 m, 0.5 rad); the target holds, no failure.
    for s in np.linspace(0.0, 1.0, 10):
        harness.step(device + s * np.array([0.2, -0.15, 0.5]), enable=0.0)
        assert harness.status == IkStatus.DISENGAGED and harness.failed == 0.0
        np.testing.assert_array_equal(harness.q, q_held)
    device = device + np.array([0.2, -0.15, 0.5])
    # Re-engaged: the command continues from the held pose, the target does not move.
    harness.step(device, enable=1.0)
    assert harness.status == IkStatus.OK
    np.testing.assert_allclose(harness.q, q_held, rtol=0, atol=1e-12)
    np.testing.assert_allclose(harness.pose_commanded, reference, rtol=0, atol=1e-12)
    # Further device motion moves the command by the same amount (additive offset).
    delta = np.array([0.01, 0.005, 0.02])
    harness.step(device + delta, enable=1.0)
    np.testing.assert_allclose(harness.pose_commanded, reference + delta, rtol=0, atol=1e-12)
    np.testing.assert_allclose(harness.q, _planar_pose_inverse(reference + delta), atol=1e-12)
    # Control: without the clutch the same device pose is a rejected 0.3+ rad jump.
    unclutched = _planar()
    unclutched.step(_planar_pose(path[0]))
    for q in path[1:]:
        unclutched.step(_planar_pose(q))
    unclutched.step(device)
    assert unclutched.status != IkStatus.OK


def _planar_pose_inverse(pose):
    from telesmooth.arms.planar import planar_3r_inverse_kinematics
    q, reachable = planar_3r_inverse_kinematics(pose[:2], pose[2], AIR_BEARING_ARM, elbow=+1)
    assert reachable
    return q


def test_space_clutch_reindexing_gives_no_jump(kinematics):
    harness = _space()
    rng = np.random.default_rng(6)
    path = _smooth_path(rng, Q0_SPACE, np.full(6, 0.2), 30)
    for q in path:
        harness.step(kinematics.tool_pose(q), enable=1.0)
    q_held = harness.q
    X_reference = kinematics.tool_transform(q_held)
    # Released: the device translates and turns.
    rotation_delta = RotationMatrix(RollPitchYaw(0.3, -0.2, 0.4))
    X_device = kinematics.tool_transform(path[-1])
    X_moved = RigidTransform(rotation_delta.multiply(X_device.rotation()),
                             X_device.translation() + [0.1, 0.05, -0.08])
    device = rigid_transform_to_pose(X_moved)
    harness.step(device, enable=0.0)
    assert harness.status == IkStatus.DISENGAGED
    np.testing.assert_array_equal(harness.q, q_held)
    # Re-engaged: R_off = R_ref R_dev^T, so the commanded pose is the held target's pose.
    harness.step(device, enable=1.0)
    assert harness.status == IkStatus.OK
    np.testing.assert_allclose(harness.q, q_held, rtol=0, atol=1e-12)
    position_m, angle_rad = pose_error(pose_to_rigid_transform(harness.pose_commanded),
                                       X_reference)
    assert position_m < 1e-12 and angle_rad < 1e-12
    # The device moves on: p_cmd = p_ref + dp, R_cmd = R_off R_dev' = R_ref R_dev^T R_dev'.
    small_turn = RotationMatrix(RollPitchYaw(0.02, 0.01, -0.015))
    X_next = RigidTransform(small_turn.multiply(X_moved.rotation()),
                            X_moved.translation() + [0.01, -0.005, 0.004])
    harness.step(rigid_transform_to_pose(X_next), enable=1.0)
    assert harness.status == IkStatus.OK
    expected_rotation = X_reference.rotation().multiply(
        X_moved.rotation().inverse()).multiply(X_next.rotation())
    X_expected = RigidTransform(expected_rotation,
                                X_reference.translation() + [0.01, -0.005, 0.004])
    position_m, angle_rad = pose_error(pose_to_rigid_transform(harness.pose_commanded),
                                       X_expected)
    assert position_m < 1e-12 and angle_rad < 1e-9
    position_m, angle_rad = pose_error(kinematics.tool_transform(harness.q), X_expected)
    assert position_m <= CONFIG.position_tolerance_m
    assert angle_rad <= CONFIG.orientation_tolerance_rad


def test_nan_at_reengagement_keeps_the_reindex_pending():
    harness = _planar()
    harness.step(_planar_pose(Q0_PLANAR), enable=1.0)
    harness.step(_planar_pose(Q0_PLANAR) + 0.3, enable=0.0)
    harness.step([np.nan, 0.0, 0.0], enable=1.0)
    assert harness.status == IkStatus.INVALID_INPUT
    harness.step(_planar_pose(Q0_PLANAR) + 0.3, enable=1.0)  # re-indexed now: no jump
    assert harness.status == IkStatus.OK
    np.testing.assert_allclose(harness.q, Q0_PLANAR, atol=1e-12)


# --- in a simulated diagram: a real operator's session ---


def test_lasa_session_through_the_simulated_system_has_one_sample_of_latency():
    session = lasa_operator_session("Angle", 0)
    poses = np.column_stack([session.xy_m, np.full(session.t_s.size, 0.0)])
    builder = DiagramBuilder()
    dut = builder.AddSystem(InverseKinematicsSystem(
        InverseKinematicsConfig(elbow=session.elbow), arm=AIR_BEARING_ARM_3DOF,
        initial_position_rad=session.q_rad[0]))
    source = builder.AddSystem(TrajectorySource(
        PiecewisePolynomial.ZeroOrderHold(session.t_s, poses.T)))
    builder.Connect(source.get_output_port(), dut.get_pose_desired_input_port())
    q_log = LogVectorOutput(dut.get_q_target_output_port(), builder, PERIOD_S)
    failed_log = LogVectorOutput(dut.get_ik_failed_output_port(), builder, PERIOD_S)
    simulator = Simulator(builder.Build())
    simulator.AdvanceTo(session.t_s[-1])
    root = simulator.get_context()
    q = q_log.FindLog(root).data().T
    assert q.shape == session.q_rad.shape
    assert np.all(failed_log.FindLog(root).data() == 0.0)
    # A log at t_k sees the state before the update at t_k: the target of sample k - 1.
    np.testing.assert_allclose(q[1:], session.q_rad[:-1], rtol=0, atol=1e-12)
    np.testing.assert_array_equal(q[0], session.q_rad[0])


# --- a held command is not solved again ---


@pytest.mark.parametrize("make, pose_size", [(_planar, 3), (_space, 6)], ids=["planar", "space"])
def test_a_repeated_command_is_not_solved_again_and_changes_nothing(make, pose_size, kinematics,
                                                                   monkeypatch):
    """The same command as the last solved one, from the target that solve held or set: the
    answer would be the same, so the solver is not called (counted), and target and status
    stay. After anything that is not a solve outcome (invalid input, a released clutch) the
    same command is solved again."""
    harness = make()
    calls = []
    solve = ik_step_module.ik_solve
    monkeypatch.setattr(ik_step_module, "ik_solve",
                        lambda *args: calls.append(1) or solve(*args))
    q0 = Q0_PLANAR if pose_size == 3 else Q0_SPACE
    reachable = (_planar_pose(q0 + 0.01) if pose_size == 3
                 else kinematics.tool_pose(q0 + 0.01))
    unreachable = np.array([5.0, 0.0, 0.0]) if pose_size == 3 else np.r_[5.0, np.zeros(5)]
    harness.step(reachable, enable=1.0)
    q, status = harness.q, harness.status
    assert status == IkStatus.OK and len(calls) == 1
    for _ in range(5):
        harness.step(reachable)
    assert len(calls) == 1 and harness.status == IkStatus.OK
    np.testing.assert_array_equal(harness.q, q)
    harness.step(unreachable)
    harness.step(unreachable)                 # the failure is kept, not recomputed
    assert len(calls) == 2 and harness.status == IkStatus.UNREACHABLE and harness.failed == 1.0
    np.testing.assert_array_equal(harness.q, q)
    harness.step(np.full(pose_size, np.nan))   # invalid input: not a solve outcome
    harness.step(unreachable)
    assert len(calls) == 3 and harness.status == IkStatus.UNREACHABLE
    harness.step(reachable)
    assert len(calls) == 4 and harness.status == IkStatus.OK
    harness.step(reachable, enable=0.0)       # released, then re-engaged: re-indexed, solved
    harness.step(reachable, enable=1.0)
    assert len(calls) == 5 and harness.status == IkStatus.OK
