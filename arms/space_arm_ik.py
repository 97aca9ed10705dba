"""Numerical inverse kinematics of the 6-DOF space arm's tool frame (Drake kinematics).

The ground station turns the operator's Cartesian pose command into joint targets at 100 Hz.
For the planar air-bearing arm that is the closed form of :mod:`telesmooth.arms.planar`; for
the 6-DOF arm it is this module: Newton iterations of Drake's differential inverse kinematics
(``DoDifferentialInverseKinematics``, a small QP per iteration) started from the previous
joint target, which is close to the answer because the command moves little in 10 ms.

Pose convention (the haptic recording's ``SPATIAL_POSE_NAMES``): a pose vector is
(x, y, z, roll, pitch, yaw) of the tool frame T in the world frame W, metres and radians,
with R_WT = RollPitchYaw(roll, pitch, yaw) = R_z(yaw) R_y(pitch) R_x(roll) (Drake's
:class:`~pydrake.math.RollPitchYaw`). At zero joint angles the tool frame is parallel to W.

Iteration i (shorthand: X = X_WT(q_i), X_d = desired pose, J = J_WT(q_i) the 6 x n spatial
velocity Jacobian of the tool point, angular rows first, expressed in W):

    e_i = [ log(R_d R(q_i)^T) ; p_d - p(q_i) ]              (rotation vector, position error)
    v_i = argmin of Drake's differential-IK QP with V = e_i, time step 1 and the box
          max(q_lower, q_seed - s) <= q_i + v_i <= min(q_upper, q_seed + s)
    q_{i+1} = q_i + v_i

The QP keeps J v parallel to V (it scales the step by alpha in [0, 1] rather than bend it), so
inside the box this is the Gauss-Newton step and converges quadratically from a near seed;
at the box it stops ("stuck"). The box is the joint limits intersected with the largest joint
step s allowed from the seed, so no answer farther than s from the seed can come out.

Success means: the final residual is within both tolerances and the answer is inside the
limits (and the step box). Failures are results, not exceptions; their status says why
(outside the workspace / near a singularity, against a joint limit, or a step larger than s).
To say why a solve failed, a second run from the seed without any bound is made: if it does
not converge either, the pose is unreachable (or singular) near the seed; if it converges
outside the limits, a joint limit excluded it; otherwise the step bound did. This costs extra
iterations only on failures.

Speed: while the iterations are Gauss–Newton steps inside the box, they run compiled
(:mod:`telesmooth.arms.space_arm_kernel`, the same kinematics written out for the description's
conventions: a few microseconds per iteration instead of ~100 µs through Drake's bindings);
where the step would leave the box, Drake's kinematics and the QP continue from the same
iterate. ``SpaceArmKinematics(arm, compiled=False)`` runs every iteration through Drake.
"""

from __future__ import annotations

import enum
import math
from typing import NamedTuple

import numpy as np
from pydrake.math import RigidTransform, RollPitchYaw
from pydrake.multibody.inverse_kinematics import (
    DifferentialInverseKinematicsParameters,
    DifferentialInverseKinematicsStatus,
    DoDifferentialInverseKinematics,
)
from pydrake.multibody.plant import MultibodyPlant
from pydrake.multibody.tree import JacobianWrtVariable

from telesmooth.arms.description import ArmDescription
from telesmooth.arms.drake_models import add_arm
from telesmooth.arms.joint_vectors import check_joint_vector
from telesmooth.compiled import readonly_copy

__all__ = [
    "SPATIAL_POSE_SIZE",
    "SpaceArmIkError",
    "SpaceArmIkResult",
    "SpaceArmIkStatus",
    "SpaceArmKinematics",
    "pose_error",
    "pose_to_rigid_transform",
    "rigid_transform_to_pose",
    "solve_space_arm_ik",
]

SPATIAL_POSE_SIZE = 6
"""Entries of a pose vector: (x, y, z, roll, pitch, yaw), m and rad."""

# Iterations stop once the residual is below this fraction of the tolerances: one more
# Newton step costs ~0.15 ms and would only polish digits far below the tolerance.
_CONVERGED_FRACTION = 1e-3
# "No bound" for the diagnostic run of a failed solve, rad (the QP wants finite limits).
_UNBOUNDED_RAD = 1e6


def pose_to_rigid_transform(pose) -> RigidTransform:
    """X_WT from a pose vector (x, y, z, roll, pitch, yaw), m and rad.

    Raises:
        ValueError: If ``pose`` does not have six finite entries.
    """
    pose = _validated_pose(pose)
    return RigidTransform(RollPitchYaw(pose[3:]), pose[:3])


def rigid_transform_to_pose(X_WT: RigidTransform) -> np.ndarray:
    """Pose vector (x, y, z, roll, pitch, yaw) of ``X_WT``, m and rad; shape (6,).

    Roll-pitch-yaw is Drake's: pitch in [-pi/2, pi/2], roll and yaw in [-pi, pi]; at
    pitch = +-pi/2 the split between roll and yaw is arbitrary but the rotation is exact.
    """
    return np.concatenate(
        [X_WT.translation(), RollPitchYaw(X_WT.rotation()).vector()]
    )


def pose_error(X_WT: RigidTransform, X_WT_desired: RigidTransform) -> tuple[float, float]:
    """(|p_d - p|, angle of R_d R^T): position error in m and orientation error in rad."""
    position_m = float(np.linalg.norm(X_WT_desired.translation() - X_WT.translation()))
    rotation = X_WT_desired.rotation().multiply(X_WT.rotation().inverse())
    return position_m, float(rotation.ToAngleAxis().angle())


def _validated_pose(pose) -> np.ndarray:
    try:
        pose = np.asarray(pose, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"pose = {pose!r} must be (x, y, z, roll, pitch, yaw)") from None
    if pose.shape != (SPATIAL_POSE_SIZE,):
        raise ValueError(
            f"pose has shape {pose.shape}; expected ({SPATIAL_POSE_SIZE},) = "
            "(x_m, y_m, z_m, roll_rad, pitch_rad, yaw_rad)"
        )
    names = ("x_m", "y_m", "z_m", "roll_rad", "pitch_rad", "yaw_rad")
    for name, value in zip(names, pose):
        if not math.isfinite(value):
            raise ValueError(f"pose {name} = {float(value)!r} must be finite")
    return pose


class SpaceArmKinematics:
    """The rigid arm as a kinematics-only MultibodyPlant plus one scratch context.

    This is the "plant/context cache" of :func:`solve_space_arm_ik`: building the plant costs
    tens of milliseconds, so it is built once. Every call overwrites the context's positions,
    so results never depend on earlier calls; do not share an instance between threads.

    Args:
        arm: The arm (its committed rigid model is loaded; no SceneGraph, no collision).
        compiled: Run the Gauss–Newton iterations compiled
            (:mod:`telesmooth.arms.space_arm_kernel`; the default), Drake's kinematics
            taking over only where the differential-IK QP is needed. False: every iteration
            through Drake (the reference the compiled path is tested against).

    Raises:
        ValueError: If the loaded model's joints do not match ``arm.joint_names`` or the tool
            frame ``arm.tool_frame`` is missing.
    """

    def __init__(self, arm: ArmDescription, *, compiled: bool = True) -> None:
        if not isinstance(arm, ArmDescription):
            raise ValueError(f"arm = {arm!r} must be an ArmDescription")
        plant = MultibodyPlant(time_step=0.0)
        instance = add_arm(plant, arm, flexible=False)
        plant.Finalize()
        if plant.num_positions() != arm.num_joints or plant.num_velocities() != arm.num_joints:
            raise ValueError(
                f"arm {arm.name!r}: the loaded model has {plant.num_positions()} positions but "
                f"the description has {arm.num_joints} joints {arm.joint_names!r}"
            )
        # Joint order of the description vs the plant; here q and v coincide (revolute joints).
        self._index = np.empty(arm.num_joints, dtype=int)
        for i, name in enumerate(arm.joint_names):
            if not plant.HasJointNamed(name, instance):
                raise ValueError(f"arm {arm.name!r}: joint {name!r} is missing from the model")
            joint = plant.GetJointByName(name, instance)
            if joint.position_start() != joint.velocity_start():
                raise ValueError(f"arm {arm.name!r}: joint {name!r} has q and v misaligned")
            self._index[i] = joint.position_start()
        if not plant.HasFrameNamed(arm.tool_frame, instance):
            raise ValueError(f"arm {arm.name!r}: tool frame {arm.tool_frame!r} is missing")
        self._arm = arm
        self._plant = plant
        self._context = plant.CreateDefaultContext()
        self._tool = plant.GetFrameByName(arm.tool_frame, instance)
        self._world = plant.world_frame()
        self._q_plant = np.zeros(arm.num_joints)
        self._lower = arm.joint_lower_rad
        self._upper = arm.joint_upper_rad
        n = arm.num_joints
        self._params = DifferentialInverseKinematicsParameters(n, n)
        self._params.set_time_step(1.0)
        # The kernel's constants (the conventions of arms/description.py, which the loaded
        # model follows): joint axes, link origins at zero angles, the tool's offset.
        self._kernel = None
        if compiled:
            from telesmooth.arms import space_arm_kernel

            self._kernel = space_arm_kernel
            self._kernel_constants = (
                readonly_copy([joint.axis for joint in arm.joints]),
                readonly_copy(arm.link_origins_m()),
                readonly_copy(arm.links[-1].segment_m))

    @property
    def arm(self) -> ArmDescription:
        return self._arm

    @property
    def num_joints(self) -> int:
        return self._arm.num_joints

    @property
    def joint_lower_rad(self) -> np.ndarray:
        return self._lower.copy()

    @property
    def joint_upper_rad(self) -> np.ndarray:
        return self._upper.copy()

    @property
    def plant(self) -> MultibodyPlant:
        """The kinematics-only plant (read only; its context is private)."""
        return self._plant

    def _set_positions(self, q: np.ndarray) -> None:
        self._q_plant[self._index] = q
        self._plant.SetPositions(self._context, self._q_plant)

    def tool_transform(self, q_rad) -> RigidTransform:
        """X_WT(q): forward kinematics of the tool frame, q in ``arm.joint_names`` order."""
        self._set_positions(np.asarray(q_rad, dtype=float))
        return self._plant.CalcRelativeTransform(self._context, self._world, self._tool)

    def tool_pose(self, q_rad) -> np.ndarray:
        """Pose vector (x, y, z, roll, pitch, yaw) of the tool at ``q_rad``; shape (6,)."""
        return rigid_transform_to_pose(self.tool_transform(q_rad))

    def _tool_jacobian(self) -> np.ndarray:
        """J_WT at the context's positions: (6, n), [angular; translational], columns in
        ``arm.joint_names`` order."""
        jacobian = self._plant.CalcJacobianSpatialVelocity(
            self._context, JacobianWrtVariable.kV, self._tool, np.zeros(3),
            self._world, self._world,
        )
        return jacobian[:, self._index]


class SpaceArmIkStatus(enum.IntEnum):
    """Outcome of :func:`solve_space_arm_ik`."""

    SUCCESS = 0
    """Residual within both tolerances, inside the limits and the step box."""
    UNREACHABLE = 1
    """No solution near the seed even without bounds: outside the workspace, at a
    singularity, or more than ``max_iterations`` Newton steps away."""
    JOINT_LIMIT = 2
    """The solution near the seed (found without bounds) violates a joint limit."""
    JOINT_STEP = 3
    """The solution near the seed is inside the limits but farther than the largest allowed
    joint step from the seed."""


class SpaceArmIkError(NamedTuple):
    """How far the answer of :func:`solve_space_arm_ik` is from the desired pose.

    Attributes:
        position_m: |p_d - p(q)|, m.
        orientation_rad: Angle of R_d R(q)^T, rad, in [0, pi].
        status: Why the solve succeeded or failed.
        iterations: Newton iterations taken (0 when the seed already satisfied the pose).
    """

    position_m: float
    orientation_rad: float
    status: SpaceArmIkStatus
    iterations: int


class SpaceArmIkResult(NamedTuple):
    """Result of :func:`solve_space_arm_ik`: unpacks as ``q, success, error``.

    Attributes:
        q_rad: The last iterate, rad, shape (n,), in ``arm.joint_names`` order; always
            finite and inside the limits, but only a valid target when ``success``.
        success: True if ``error.status`` is SUCCESS.
        error: Residual, status and iteration count.
    """

    q_rad: np.ndarray
    success: bool
    error: SpaceArmIkError


def solve_space_arm_ik(
    kinematics: SpaceArmKinematics,
    pose,
    q_seed,
    *,
    position_tolerance_m: float = 1e-4,
    orientation_tolerance_rad: float = 1e-3,
    max_joint_step_rad: float = math.inf,
    max_iterations: int = 10,
) -> SpaceArmIkResult:
    """Joint angles that put the tool at ``pose``, found by Newton iterations from ``q_seed``.

    See the module docstring for the iteration. The seed should be the previous target: the
    answer is the solution the iteration reaches from the seed (the branch nearest the seed,
    away from singularities), never one farther than ``max_joint_step_rad`` from it in any
    joint.

    Args:
        kinematics: The plant/context cache of the arm (6 or more joints).
        pose: Desired tool pose: a :class:`~pydrake.math.RigidTransform` X_WT, or a pose vector
            (x, y, z, roll, pitch, yaw), m and rad.
        q_seed: Start of the iteration, rad, shape (n,); finite and inside the joint limits.
        position_tolerance_m: Largest accepted position residual, m (> 0).
        orientation_tolerance_rad: Largest accepted orientation residual, rad (> 0).
        max_joint_step_rad: Largest accepted |q - q_seed| in any joint, rad (> 0; inf for
            no bound).
        max_iterations: Most Newton iterations (>= 1).

    Returns:
        ``SpaceArmIkResult(q_rad, success, error)``; a failure is a result, not an exception.

    Raises:
        ValueError: On invalid arguments: a non-finite pose entry, a seed of the wrong size,
            non-finite or outside the limits (named joint and value), non-positive
            tolerances, step or iteration count, or an arm with fewer than 6 joints.
    """
    arm = kinematics.arm
    n = arm.num_joints
    if n < SPATIAL_POSE_SIZE:
        raise ValueError(
            f"arm {arm.name!r} has {n} joints; a full 6-D pose needs at least 6"
        )
    for name, value in (
        ("position_tolerance_m", position_tolerance_m),
        ("orientation_tolerance_rad", orientation_tolerance_rad),
        ("max_joint_step_rad", max_joint_step_rad),
    ):
        if not (value > 0.0) or math.isnan(value) or (
            value == math.inf and name != "max_joint_step_rad"
        ):
            raise ValueError(f"{name} = {value!r} must be positive and finite")
    if isinstance(max_iterations, bool) or not isinstance(max_iterations, (int, np.integer)) \
            or max_iterations < 1:
        raise ValueError(f"max_iterations = {max_iterations!r} must be an integer >= 1")
    X_desired = pose if isinstance(pose, RigidTransform) else pose_to_rigid_transform(pose)
    lower, upper = kinematics._lower, kinematics._upper
    q_seed = check_joint_vector("q_seed", q_seed, arm.joint_names, lower=lower, upper=upper)

    tolerances = (position_tolerance_m, orientation_tolerance_rad)
    # The step box: joint limits intersected with |q - q_seed| <= s.
    box_lower = np.maximum(lower, q_seed - max_joint_step_rad)
    box_upper = np.minimum(upper, q_seed + max_joint_step_rad)
    q, position_m, orientation_rad, iterations = _newton(
        kinematics, X_desired, q_seed, box_lower, box_upper, tolerances, max_iterations)

    if position_m <= position_tolerance_m and orientation_rad <= orientation_tolerance_rad:
        status = SpaceArmIkStatus.SUCCESS
    else:
        # Why? Iterate again from the seed with no bounds at all: no convergence means the
        # pose is out of reach (or singular); otherwise the unbounded answer shows which
        # bound excluded it. Costs extra iterations on failures only.
        q_free, free_position_m, free_orientation_rad, free_iterations = _newton(
            kinematics, X_desired, q_seed, np.full(n, -_UNBOUNDED_RAD),
            np.full(n, _UNBOUNDED_RAD), tolerances, max_iterations)
        iterations += free_iterations
        if not (free_position_m <= position_tolerance_m
                and free_orientation_rad <= orientation_tolerance_rad):
            status = SpaceArmIkStatus.UNREACHABLE
        elif np.any(q_free < lower) or np.any(q_free > upper):
            status = SpaceArmIkStatus.JOINT_LIMIT
        elif np.any(q_free < box_lower) or np.any(q_free > box_upper):
            status = SpaceArmIkStatus.JOINT_STEP
        else:  # the bounded run stalled although an answer inside the box exists
            status = SpaceArmIkStatus.UNREACHABLE
    error = SpaceArmIkError(position_m, orientation_rad, status, iterations)
    return SpaceArmIkResult(q, status == SpaceArmIkStatus.SUCCESS, error)



def _newton(kinematics, X_desired, q_seed, box_lower, box_upper, tolerances, max_iterations):
    """Differential-IK Newton iterations inside [box_lower, box_upper] (module docstring).

    For a 6-joint arm the Jacobian is square: inside the box the QP's step is the
    Gauss-Newton step J⁻¹e itself (J v = α e with α = 1, nothing left to minimise), so it
    is computed with one 6×6 solve, and the QP runs only when that step would leave the
    box (or J is singular). The same iterates to the QP's tolerance, at a fraction of the
    cost (the QP was ~0.4 ms of the ~0.8 ms per iteration). Those Gauss–Newton iterations run
    compiled when ``kinematics`` has the kernel; Drake's path takes over from the kernel's
    last iterate when the QP is needed.

    Returns:
        (q, position error m, orientation error rad, iterations) at the last iterate.
    """
    position_tolerance_m, orientation_tolerance_rad = tolerances
    n = q_seed.size
    rotation_desired = X_desired.rotation()
    translation_desired = X_desired.translation()
    q = q_seed.copy()
    iterations = 0
    if kinematics._kernel is not None:
        # The same iterations compiled, as long as they are Gauss–Newton steps inside the box.
        kernel = kinematics._kernel
        outcome, position_m, orientation_rad, iterations = kernel.newton_kernel(
            rotation_desired.matrix(), translation_desired, box_lower, box_upper,
            *kinematics._kernel_constants, _CONVERGED_FRACTION * position_tolerance_m,
            _CONVERGED_FRACTION * orientation_tolerance_rad, max_iterations, q)
        if outcome == kernel.DONE:
            return q, position_m, orientation_rad, iterations
    params = kinematics._params
    params.set_joint_position_limits((box_lower, box_upper))
    zero_velocity = np.zeros(n)
    while True:
        X = kinematics.tool_transform(q)
        # e = [log(R_d R^T); p_d - p], the spatial "velocity" that closes the gap in unit time.
        rotation = rotation_desired.multiply(X.rotation().inverse()).ToAngleAxis()
        translation_error = translation_desired - X.translation()
        position_m = math.sqrt(float(translation_error @ translation_error))
        orientation_rad = float(rotation.angle())
        if (position_m <= _CONVERGED_FRACTION * position_tolerance_m
                and orientation_rad <= _CONVERGED_FRACTION * orientation_tolerance_rad):
            break
        if iterations >= max_iterations:
            break
        error_twist = np.concatenate([rotation.axis() * orientation_rad, translation_error])
        jacobian = kinematics._tool_jacobian()
        step = _gauss_newton_step(jacobian, error_twist, q, box_lower, box_upper)
        if step is None:
            result = DoDifferentialInverseKinematics(
                q, zero_velocity, error_twist, jacobian, params
            )
            if result.status != DifferentialInverseKinematicsStatus.kSolutionFound:
                break  # stuck against the box, or no QP solution
            step = np.asarray(result.joint_velocities, dtype=float).reshape(n)
            if not np.all(np.isfinite(step)):  # never seen; stop at the last finite iterate
                break
        iterations += 1
        # The QP meets the box to solver precision; clip so the answer is inside exactly.
        q = np.clip(q + step, box_lower, box_upper)
    return q, position_m, orientation_rad, iterations


def _gauss_newton_step(jacobian, error_twist, q, box_lower, box_upper):
    """J⁻¹e if J is square and invertible and q + J⁻¹e stays inside the box, else None."""
    if jacobian.shape[0] != jacobian.shape[1]:
        return None
    try:
        step = np.linalg.solve(jacobian, error_twist)
    except np.linalg.LinAlgError:
        return None
    target = q + step
    if not (np.all(np.isfinite(step)) and np.all(target >= box_lower)
            and np.all(target <= box_upper)):
        return None
    return step
