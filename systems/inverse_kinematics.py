"""Inverse kinematics of the ground station: the operator's pose command becomes joint targets.

This is the "task plan manager" stage (docs/method.md §5.1): at the haptic rate (100 Hz) it turns
the operator's Cartesian pose command into the newest joint target ``q_target``, which feeds the
pre-simulator's collision checker and, through the 0.75 s delay FIFO and the smoother, the
robot. It is the first place where a command can be unsafe, so it never passes one on: an
unreachable, limit-violating, too-large-jump or non-finite command is not converted; the
previous valid target is held and ``ik_failed`` is raised.

The operator's clutch (``enable``) is handled here too: while it is released the target
holds; when it re-engages the clutch offset is re-indexed so that the commanded pose continues
from the held target's pose (haptic re-indexing), with no jump.

Both arms are supported: the planar air-bearing arm (3 joints about +z; closed-form 3R IK
of :mod:`telesmooth.arms.planar`) and the 6-DOF space arm (Newton / differential IK on the
rigid Drake plant, :mod:`telesmooth.arms.space_arm_ik`).
"""

from __future__ import annotations

import dataclasses
import functools
import math

import numpy as np
from pydrake.common.eigen_geometry import Quaternion
from pydrake.math import RollPitchYaw, RotationMatrix
from pydrake.systems.framework import LeafSystem

from telesmooth.arms.description import ArmDescription
from telesmooth.arms.ik_step import (
    IkInputs,
    IkParams,
    IkState,
    IkStatus,
    ik_failed,
    ik_initial_state,
    ik_step,
)
from telesmooth.arms.joint_vectors import check_joint_vector
from telesmooth.arms.planar import (
    PlanarArm,
    planar_end_effector_angle,
    planar_forward_kinematics,
)
from telesmooth.arms.space_arm_ik import SpaceArmKinematics, solve_space_arm_ik
from telesmooth.datasets.haptic_recording import PLANAR_POSE_NAMES, SPATIAL_POSE_NAMES
from telesmooth.systems.codec_state import CodecState
from telesmooth.systems.timing import check_period

__all__ = [
    "IkStatus",
    "InverseKinematicsConfig",
    "InverseKinematicsSystem",
    "apply_clutch_offset",
    "clutch_offset",
    "planar_arm_from_description",
]

_PLANAR_OFFSET_SIZE = 3  # (dx, dy, dphi)
_SPATIAL_OFFSET_SIZE = 7  # (dx, dy, dz, qw, qx, qy, qz): p_off and R_off as a unit quaternion


@dataclasses.dataclass(frozen=True)
class InverseKinematicsConfig:
    """Settings of :class:`InverseKinematicsSystem`.

    Attributes:
        period_s: Update period, s (the haptic rate: 0.01 s = 100 Hz).
        elbow: Elbow branch of the planar arm's closed-form IK, +1 (q_elbow >= 0) or -1;
            ignored by the 6-DOF arm, whose branch is the one nearest the previous target.
        max_joint_step_rad: Largest accepted change of any joint between two consecutive
            targets, rad (> 0); a larger jump is a failure (held). 0.2 rad per 10 ms is
            20 rad/s, far beyond any joint's speed: only branch flips and glitches trip it.
        position_tolerance_m: Largest accepted position residual |p_cmd - p(q)|, m (> 0).
        orientation_tolerance_rad: Largest accepted orientation residual, rad (> 0): the
            angle of R_cmd R(q)^T (6-DOF) or |phi_cmd - phi(q)| modulo 2 pi (planar).
        max_iterations: Most Newton iterations per update of the 6-DOF IK (>= 1); tracking a
            smooth command needs 2.

    Raises:
        ValueError: If a field is out of range; the message names the field and the value.
    """

    period_s: float = 0.01
    elbow: int = +1
    max_joint_step_rad: float = 0.2
    position_tolerance_m: float = 1e-4
    orientation_tolerance_rad: float = 1e-3
    max_iterations: int = 10

    def __post_init__(self) -> None:
        check_period("InverseKinematicsConfig.period_s", self.period_s)
        if isinstance(self.elbow, bool) or self.elbow not in (1, -1):
            raise ValueError(f"InverseKinematicsConfig.elbow = {self.elbow!r} must be +1 or -1")
        for name in ("max_joint_step_rad", "position_tolerance_m", "orientation_tolerance_rad"):
            value = getattr(self, name)
            if (isinstance(value, bool) or not isinstance(value, (int, float))
                    or not math.isfinite(value) or value <= 0.0):
                raise ValueError(
                    f"InverseKinematicsConfig.{name} = {value!r} must be positive and finite"
                )
        if (isinstance(self.max_iterations, bool)
                or not isinstance(self.max_iterations, (int, np.integer))
                or self.max_iterations < 1):
            raise ValueError(
                f"InverseKinematicsConfig.max_iterations = {self.max_iterations!r} must be an "
                "integer >= 1"
            )


def planar_arm_from_description(arm: ArmDescription) -> PlanarArm:
    """The :class:`PlanarArm` of a 3-joint arm whose joints all turn about +z.

    The description must put the first joint on the base frame's z axis and every link's
    segment along +x at zero angles (as :data:`AIR_BEARING_ARM_3DOF` does); then the tool
    point in the base frame is ``planar_forward_kinematics(q, link lengths)``.

    Raises:
        ValueError: If the arm is not such a planar 3R arm (the message says which part).
    """
    if arm.num_joints != 3:
        raise ValueError(f"arm {arm.name!r} has {arm.num_joints} joints; a planar arm needs 3")
    for joint in arm.joints:
        if tuple(joint.axis) != (0.0, 0.0, 1.0):
            raise ValueError(
                f"arm {arm.name!r}: joint {joint.name!r} axis = {joint.axis!r} must be (0, 0, 1)"
            )
    if tuple(arm.base_to_first_joint_m[:2]) != (0.0, 0.0):
        raise ValueError(
            f"arm {arm.name!r}: base_to_first_joint_m = {arm.base_to_first_joint_m!r} must lie "
            "on the base's z axis"
        )
    for link in arm.links:
        if link.segment_m[1] != 0.0 or link.segment_m[2] != 0.0 or link.segment_m[0] <= 0.0:
            raise ValueError(
                f"arm {arm.name!r}: link {link.name!r} segment_m = {link.segment_m!r} must point "
                "along +x"
            )
    return PlanarArm(
        link_lengths_m=tuple(link.segment_m[0] for link in arm.links),
        joint_names=arm.joint_names,
        joint_lower_rad=tuple(arm.joint_lower_rad),
        joint_upper_rad=tuple(arm.joint_upper_rad),
    )


def _quaternion_wxyz(rotation: RotationMatrix) -> np.ndarray:
    return rotation.ToQuaternion().wxyz()


def _rotation_from_wxyz(wxyz: np.ndarray) -> RotationMatrix:
    wxyz = np.asarray(wxyz, dtype=float)
    return RotationMatrix(Quaternion(wxyz / np.linalg.norm(wxyz)))


def clutch_offset(pose_reference, pose_device, *, planar: bool) -> np.ndarray:
    """The clutch offset that maps the device pose now onto the reference pose.

    Planar (poses (x, y, phi)):  offset = pose_reference - pose_device = (dx, dy, dphi).
    6-DOF (poses (x, y, z, roll, pitch, yaw)): p_off = p_ref - p_dev and
    R_off = R_ref R_dev^T, returned as (dx, dy, dz, qw, qx, qy, qz).

    With this offset :func:`apply_clutch_offset` maps ``pose_device`` to ``pose_reference``
    (to rounding), so re-engaging the clutch does not move the command.
    """
    reference = np.asarray(pose_reference, dtype=float)
    device = np.asarray(pose_device, dtype=float)
    if planar:
        return reference - device
    rotation_reference = RotationMatrix(RollPitchYaw(reference[3:]))
    rotation_device = RotationMatrix(RollPitchYaw(device[3:]))
    # R_off = R_ref R_dev^T
    rotation_offset = rotation_reference.multiply(rotation_device.inverse())
    return np.concatenate([reference[:3] - device[:3], _quaternion_wxyz(rotation_offset)])


def apply_clutch_offset(pose_device, offset, *, planar: bool) -> np.ndarray:
    """The commanded pose: the device pose moved by the clutch offset.

    Planar: pose_cmd = pose_dev + offset. 6-DOF: p_cmd = p_dev + p_off, R_cmd = R_off R_dev,
    returned as (x, y, z, roll, pitch, yaw) with Drake's roll-pitch-yaw of R_cmd.
    """
    device = np.asarray(pose_device, dtype=float)
    offset = np.asarray(offset, dtype=float)
    if planar:
        return device + offset
    # R_cmd = R_off R_dev
    rotation = _rotation_from_wxyz(offset[3:]).multiply(RotationMatrix(RollPitchYaw(device[3:])))
    return np.concatenate([device[:3] + offset[:3], RollPitchYaw(rotation).vector()])


class InverseKinematicsSystem(LeafSystem):
    r"""Operator pose command → joint target at the haptic rate, holding on any failure.

    .. pydrake_system::

        name: InverseKinematicsSystem
        input_ports:
        - pose_desired
        - enable (optional)
        - q_anchor (optional)
        - anchor (optional)
        output_ports:
        - q_target
        - ik_failed
        - ik_status
        - pose_commanded

    Ports (n = number of joints; m = 3 for the planar arm, 6 for the 6-DOF arm):

    - ``pose_desired``: the operator's (haptic device's) pose command, (m,). Planar arm:
      (x_m, y_m, phi_rad), the tool point in the base frame, m, and the absolute angle of the
      last link, rad. 6-DOF arm: (x_m, y_m, z_m, roll_rad, pitch_rad, yaw_rad) of the tool
      frame in the world, m and rad, R = RollPitchYaw(roll, pitch, yaw) (Drake's convention,
      R_z(yaw) R_y(pitch) R_x(roll)).
    - ``enable``: the clutch, (1,): engaged when > 0.5. Unconnected: always engaged.
    - ``q_anchor``, ``anchor``: optional, (n,) rad and (1,): when the clutch re-engages while
      ``anchor`` > 0.5 (the delay FIFO holds the robot: after a collision or the operator's
      stop), the target first jumps to ``q_anchor`` (the robot's commanded pose, the
      uplink's ``q_sent``; ignored unless finite and within the limits) and the hand is
      re-indexed there, so that the robot resumes from where it stopped instead of
      driving to the target it held. Unconnected: the target continues from where it held.
    - ``q_target``: the joint target, rad, (n,), ordered as ``arm.joint_names``; always
      finite, within the joint limits, and a valid IK solution of some accepted command.
    - ``ik_failed``: 1.0 if the last update rejected the command and held the target
      (unreachable, limit-violating, a jump > ``max_joint_step_rad``, non-finite input),
      else 0.0; (1,). Not raised while the clutch is released (holding is intended then).
    - ``ik_status``: the :class:`IkStatus` of the last update as a float, (1,).
    - ``pose_commanded``: the command after the clutch offset, (m,), same units as
      ``pose_desired``; the last finite command attempted, even if it was rejected.

    State (:class:`~telesmooth.arms.ik_step.IkState`, one discrete vector): q_target (n);
    clutch offset (planar: dx, dy, dphi; 6-DOF: dx, dy, dz and R_off as a unit quaternion qw,
    qx, qy, qz); previous enable e (1); ik_status (1; ik_failed is derived from it);
    pose_commanded (m). Updated by :func:`~telesmooth.arms.ik_step.ik_step`, which holds the
    rule below; the system evaluates the inputs and gives the step the kinematics as callables
    (forward kinematics and the 6-DOF solve run the rigid Drake plant).

    Update at t_k = k·period_s (offset 0), with u = pose_desired(t_k), e_k = enable(t_k):

        if e_k is not finite:     hold q; failed, INVALID_INPUT; e ← 0
        elif e_k <= 0.5:          hold q; not failed, DISENGAGED; e ← 0
        elif u is not finite:     hold q; failed, INVALID_INPUT (e unchanged)
        else:
            if e_{k-1} = 0:       offset ← clutch_offset(FK(q), u)   (re-index, no jump)
            pose_cmd = apply_clutch_offset(u, offset)
            if e_{k-1} = 1 and pose_cmd equals the last solved pose_commanded (bit for bit):
                                  q and the status unchanged (the same solve again)
            else:
                q' = IK(pose_cmd, seed q)
                accept q ← q' iff IK succeeded, q' within limits, |q' − q|_∞ <=
                max_joint_step_rad and the residual is within the tolerances; otherwise hold
                q and fail with the reason
            e ← 1

    Clutch offset (planar: additive in x, y and phi; 6-DOF: additive position, rotation
    R_cmd = R_off R_dev with R_off = R_ref R_dev,nowᵀ at re-engagement). The reference pose
    is FK of the held target — the last accepted command — so clutching also recovers from a
    rejected (e.g. unreachable) command. The initial state is engaged (e = 1) with a zero
    offset: an operator who never clutches commands absolute poses.

    IK: planar, the closed form of :func:`~telesmooth.arms.planar.planar_3r_inverse_kinematics`
    on the configured elbow branch (limits checked there). 6-DOF,
    :func:`~telesmooth.arms.space_arm_ik.solve_space_arm_ik` seeded with the held target,
    bounded to the joint limits and to ``max_joint_step_rad`` around the seed.

    Before the first update (t < 0, or a context never updated): q_target =
    ``initial_position_rad``, ik_failed = 0, ik_status = OK, pose_commanded = its FK pose.
    No output depends directly on an input (all are state), so the system can close loops.
    """

    def __init__(
        self,
        config: InverseKinematicsConfig = InverseKinematicsConfig(),
        *,
        arm: ArmDescription,
        initial_position_rad,
    ) -> None:
        """Validates the arguments and declares ports, state and the periodic update.

        Args:
            config: Rates, elbow branch, tolerances, largest joint step.
            arm: The arm: a planar 3R arm about +z (e.g. ``AIR_BEARING_ARM_3DOF``) or a 6-joint
                arm with a tool frame (e.g. ``SPACE_ARM_6DOF``).
            initial_position_rad: The robot's joint angles at t = 0, rad, (n,): the first
                held target and the first IK seed.

        Raises:
            ValueError: If ``config`` is not an InverseKinematicsConfig, the arm is neither
                kind, or ``initial_position_rad`` has the wrong size, a non-finite entry or an
                entry outside the joint limits (the message names the joint and the value).
        """
        super().__init__()
        if not isinstance(config, InverseKinematicsConfig):
            raise ValueError(f"config = {config!r} must be an InverseKinematicsConfig")
        if not isinstance(arm, ArmDescription):
            raise ValueError(f"arm = {arm!r} must be an ArmDescription")
        self._config = config
        self._arm = arm
        n = arm.num_joints
        self._planar = all(tuple(j.axis) == (0.0, 0.0, 1.0) for j in arm.joints) and n == 3
        if self._planar:
            self._planar_arm = planar_arm_from_description(arm)
            self._kinematics = None
            self._pose_names = PLANAR_POSE_NAMES
            offset0 = np.zeros(_PLANAR_OFFSET_SIZE)
        elif n == 6:
            self._planar_arm = None
            # Plant/context cache of the 6-DOF IK, fully overwritten by every call (the
            # STYLE §9.2 exception for scratch contexts); no simulation state lives here.
            self._kinematics = SpaceArmKinematics(arm)
            self._pose_names = SPATIAL_POSE_NAMES
            offset0 = np.array([0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0])
        else:
            raise ValueError(
                f"arm {arm.name!r} with joints {arm.joint_names!r} is neither a planar 3R arm "
                "(three joints about +z) nor a 6-joint arm"
            )
        self._lower = arm.joint_lower_rad
        self._upper = arm.joint_upper_rad
        q0 = check_joint_vector("initial_position_rad", initial_position_rad, arm.joint_names,
                                lower=self._lower, upper=self._upper)
        m = len(self._pose_names)

        self._pose_desired_input = self.DeclareVectorInputPort("pose_desired", m)
        self._enable_input = self.DeclareVectorInputPort("enable", 1)
        self._q_anchor_input = self.DeclareVectorInputPort("q_anchor", n)
        self._anchor_input = self.DeclareVectorInputPort("anchor", 1)

        self._params = IkParams(
            lower_rad=self._lower, upper_rad=self._upper,
            max_joint_step_rad=config.max_joint_step_rad,
            position_tolerance_m=config.position_tolerance_m,
            orientation_tolerance_rad=config.orientation_tolerance_rad,
            forward_kinematics=self.forward_kinematics_pose,
            clutch_offset=functools.partial(clutch_offset, planar=self._planar),
            apply_clutch_offset=functools.partial(apply_clutch_offset, planar=self._planar),
            planar_arm=self._planar_arm, elbow=config.elbow,
            space_solve=None if self._planar else functools.partial(
                solve_space_arm_ik, self._kinematics,
                position_tolerance_m=config.position_tolerance_m,
                orientation_tolerance_rad=config.orientation_tolerance_rad,
                max_joint_step_rad=config.max_joint_step_rad,
                max_iterations=config.max_iterations))
        self._state = CodecState(self, ik_initial_state(q0, offset0,
                                                        self.forward_kinematics_pose(q0)))
        self._status_index = self._state.codec.field_slice("status").start
        self.DeclarePeriodicDiscreteUpdateEvent(config.period_s, 0.0, self._update)

        self._q_target_output = self._state.output("q_target", "q")
        self._ik_failed_output = self.DeclareVectorOutputPort(
            "ik_failed", 1, self._calc_ik_failed, prerequisites_of_calc={self.xd_ticket()})
        self._ik_status_output = self.DeclareVectorOutputPort(
            "ik_status", 1, self._calc_ik_status, prerequisites_of_calc={self.xd_ticket()})
        self._pose_commanded_output = self._state.output("pose_commanded", "pose_commanded")

    # -- accessors ------------------------------------------------------------------------

    @property
    def config(self) -> InverseKinematicsConfig:
        return self._config

    @property
    def arm(self) -> ArmDescription:
        return self._arm

    @property
    def is_planar(self) -> bool:
        """True for the planar 3R arm (pose (x, y, phi)), False for the 6-DOF arm."""
        return self._planar

    @property
    def pose_names(self) -> tuple[str, ...]:
        """Names (and units) of the pose entries: PLANAR_ or SPATIAL_POSE_NAMES."""
        return self._pose_names

    def get_pose_desired_input_port(self):
        return self._pose_desired_input

    def get_enable_input_port(self):
        return self._enable_input

    def get_q_anchor_input_port(self):
        return self._q_anchor_input

    def get_anchor_input_port(self):
        return self._anchor_input

    def get_q_target_output_port(self):
        return self._q_target_output

    def get_ik_failed_output_port(self):
        return self._ik_failed_output

    def get_ik_status_output_port(self):
        return self._ik_status_output

    def get_pose_commanded_output_port(self):
        return self._pose_commanded_output

    def forward_kinematics_pose(self, q_rad) -> np.ndarray:
        """The pose (in this system's pose convention) of the tool at joint angles ``q_rad``.

        Planar: (x, y, phi) with phi = sum(q) (not wrapped). 6-DOF: (x, y, z, roll, pitch,
        yaw) of the tool frame from the rigid Drake plant.
        """
        q = np.asarray(q_rad, dtype=float)
        if self._planar:
            xy = planar_forward_kinematics(q, self._planar_arm.link_lengths_m)
            return np.array([xy[0], xy[1], float(planar_end_effector_angle(q))])
        return self._kinematics.tool_pose(q)

    # -- the update -----------------------------------------------------------------------

    def ik_state(self, context) -> IkState:
        """The stage, as :func:`~telesmooth.arms.ik_step.ik_step` left it."""
        return self._state.get(context)

    def _update(self, context, discrete_state) -> None:
        before = self._state.get(context)
        enable = self._enable_input.Eval(context)[0] if self._enable_input.HasValue(context) \
            else 1.0
        engaging = enable > 0.5     # False for NaN too: the step then reads no other input
        pose = (self._pose_desired_input.Eval(context)
                if engaging and self._pose_desired_input.HasValue(context) else None)
        anchor = q_anchor = None
        if engaging and not before.engaged:   # the anchor matters only when re-engaging
            if self._anchor_input.HasValue(context):
                anchor = self._anchor_input.Eval(context)[0]
            if self._q_anchor_input.HasValue(context):
                q_anchor = self._q_anchor_input.Eval(context)
        state = ik_step(self._params, before, IkInputs(pose, enable, anchor, q_anchor))
        if state is not before:     # most updates of a still hand or a released clutch
            self._state.store(discrete_state, state)

    def _calc_ik_failed(self, context, output) -> None:
        status = IkStatus(int(self._state.vector(context)[self._status_index]))
        output.SetAtIndex(0, float(ik_failed(status)))

    def _calc_ik_status(self, context, output) -> None:
        output.SetAtIndex(0, self._state.vector(context)[self._status_index])
