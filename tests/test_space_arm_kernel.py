"""The compiled Newton iterations of the 6-DOF IK against Drake's kinematics.

Oracles: Drake's MultibodyPlant (``CalcRelativeTransform``, ``CalcJacobianSpatialVelocity``,
``RotationMatrix.ToAngleAxis``) for the kinematics, and ``solve_space_arm_ik`` run with every
iteration through Drake (``SpaceArmKinematics(arm, compiled=False)``) for the solver: the same
statuses, the same iteration counts and the same joint angles to round-off, on random reachable
poses, on poses where the Gauss–Newton step leaves the box (the QP takes over), and on
unreachable, limit-violating and too-far poses.
"""

import math
from types import SimpleNamespace

import numpy as np
import pytest
from pydrake.math import RotationMatrix

from telesmooth.arms.description import SPACE_ARM_6DOF
from telesmooth.arms.space_arm_ik import (
    SpaceArmIkStatus,
    SpaceArmKinematics,
    solve_space_arm_ik,
)
from telesmooth.arms.space_arm_kernel import DONE, NEEDS_QP, _angle_axis, tool_kinematics
from telesmooth.compiled import readonly_copy

ARM = SPACE_ARM_6DOF
LOWER, UPPER = ARM.joint_lower_rad, ARM.joint_upper_rad


@pytest.fixture(scope="module")
def both():
    return SpaceArmKinematics(ARM), SpaceArmKinematics(ARM, compiled=False)


def test_kinematics_equal_drakes_at_random_joint_angles(both):
    _, drake = both
    axes = readonly_copy([joint.axis for joint in ARM.joints])
    origins = readonly_copy(ARM.link_origins_m())
    tool = readonly_copy(ARM.links[-1].segment_m)
    rng = np.random.default_rng(0)
    rotation, position, jacobian = np.empty((3, 3)), np.empty(3), np.empty((6, 6))
    for _ in range(50):
        q = rng.uniform(-math.pi, math.pi, 6)
        tool_kinematics(q, axes, origins, tool, rotation, position, jacobian)
        X = drake.tool_transform(q)
        np.testing.assert_allclose(rotation, X.rotation().matrix(), rtol=0, atol=1e-14)
        np.testing.assert_allclose(position, X.translation(), rtol=0, atol=1e-14)
        np.testing.assert_allclose(jacobian, drake._tool_jacobian(), rtol=0, atol=1e-14)


@pytest.mark.parametrize("angle", [0.0, 1e-12, 1e-6, 0.3, 2.0, math.pi - 1e-6, math.pi])
def test_angle_axis_equals_drakes(angle):
    rng = np.random.default_rng(int(1e6 * angle) % 1000)
    for _ in range(20):
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        R = _rotation(axis, angle)
        out = np.empty(3)
        theta = _angle_axis(np.ascontiguousarray(R), out)
        expected = RotationMatrix(R).ToAngleAxis()
        assert theta == pytest.approx(expected.angle(), abs=1e-13)
        if angle < math.pi - 1e-3:       # at pi the axis sign is arbitrary: compare θu only then
            np.testing.assert_allclose(out, expected.angle() * expected.axis(), atol=1e-13)
        else:
            np.testing.assert_allclose(np.abs(out), np.abs(expected.angle() * expected.axis()),
                                       atol=1e-6)


def _rotation(axis, angle):
    x, y, z = axis
    K = np.array([[0, -z, y], [z, 0, -x], [-y, x, 0]])
    return np.eye(3) + math.sin(angle) * K + (1 - math.cos(angle)) * K @ K


def _agree(compiled_result, drake_result):
    q, success, error = compiled_result
    q_ref, success_ref, error_ref = drake_result
    assert success == success_ref
    assert error.status == error_ref.status
    assert error.iterations == error_ref.iterations
    np.testing.assert_allclose(q, q_ref, rtol=0, atol=1e-9)
    assert error.position_m == pytest.approx(error_ref.position_m, abs=1e-9)
    assert error.orientation_rad == pytest.approx(error_ref.orientation_rad, abs=1e-9)


def test_random_reachable_poses_give_drakes_answers(both):
    compiled, drake = both
    rng = np.random.default_rng(2)
    for _ in range(200):
        q_true = rng.uniform(0.9 * LOWER, 0.9 * UPPER)
        seed = np.clip(q_true + rng.uniform(-0.05, 0.05, 6), LOWER, UPPER)
        pose = drake.tool_pose(q_true)
        _agree(solve_space_arm_ik(compiled, pose, seed, max_joint_step_rad=0.2),
               solve_space_arm_ik(drake, pose, seed, max_joint_step_rad=0.2))


def test_where_the_step_leaves_the_box_the_qp_takes_over_as_in_drakes_path(both, monkeypatch):
    compiled, drake = both
    outcomes = []
    kernel = compiled._kernel

    def recorded(*args):
        result = kernel.newton_kernel(*args)
        outcomes.append(result[0])
        return result

    monkeypatch.setattr(compiled, "_kernel", SimpleNamespace(
        newton_kernel=recorded, DONE=kernel.DONE))
    rng = np.random.default_rng(3)
    statuses = set()
    for _ in range(200):
        q_true = rng.uniform(0.9 * LOWER, 0.9 * UPPER)
        # Seeds up to 0.2 rad away with a 0.15 rad step bound: some answers are out of the
        # box, and some full Newton steps overshoot it on the way to an answer inside.
        seed = np.clip(q_true + rng.uniform(-0.2, 0.2, 6), LOWER, UPPER)
        pose = drake.tool_pose(q_true)
        result = solve_space_arm_ik(compiled, pose, seed, max_joint_step_rad=0.15)
        _agree(result, solve_space_arm_ik(drake, pose, seed, max_joint_step_rad=0.15))
        statuses.add(result.error.status)
    # The cases bite: the QP took over, and successes and step-bound failures both occur.
    assert NEEDS_QP in outcomes and DONE in outcomes
    assert {SpaceArmIkStatus.SUCCESS, SpaceArmIkStatus.JOINT_STEP} <= statuses


def test_unreachable_and_limit_violating_poses_fail_as_in_drakes_path(both):
    compiled, drake = both
    seed = np.array([0.1, 0.5, 1.0, 0.2, 0.4, 0.3])
    far = np.append(drake.tool_pose(seed)[:3] * 10.0, drake.tool_pose(seed)[3:])
    result = solve_space_arm_ik(compiled, far, seed)
    assert result.error.status == SpaceArmIkStatus.UNREACHABLE
    _agree(result, solve_space_arm_ik(drake, far, seed))
    beyond = seed.copy()
    beyond[0] = UPPER[0] + 0.05
    near_limit = seed.copy()
    near_limit[0] = UPPER[0] - 0.01
    pose = drake.tool_pose(beyond)
    result = solve_space_arm_ik(compiled, pose, near_limit)
    assert result.error.status == SpaceArmIkStatus.JOINT_LIMIT
    _agree(result, solve_space_arm_ik(drake, pose, near_limit))
