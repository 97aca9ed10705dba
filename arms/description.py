"""Arm descriptions (our own numbers) and their SDFormat models, rigid and flexible.

The paper's DH table and masses are lost; every number here is OURS, chosen to be plausible
for a ~1.1 m space manipulator and for the laboratory air-bearing set-up. They are not the
paper's values.

Two arms are described as plain data (:class:`ArmDescription`):

* :data:`SPACE_ARM_6DOF`: a 6-DOF space manipulator (shoulder yaw, shoulder pitch, elbow
  pitch, wrist pitch, wrist yaw, wrist roll) on a 0.2 m pedestal. With the yaw and roll
  joints locked at zero the three pitch joints move the arm in the pedestal's x-z plane with
  link lengths 0.5, 0.4 and 0.2 m: this is the air-bearing configuration.
* :data:`AIR_BEARING_ARM_3DOF`: that air-bearing configuration as its own planar model: the
  arm laid on its side on air bearings, three joints about vertical axes (+z), links along
  +x at zero, the same link lengths and joint names as :mod:`telesmooth.arms.planar`.

From a description :func:`arm_sdf` writes an SDFormat model, either

* rigid: one actuated revolute joint per joint; used by the inverse kinematics and by the
  collision checker (the pre-simulator), or
* flexible: each joint is a motor-side actuated joint ``<name>_motor`` (rotor inertia, gear
  ratio and the plant's PD gains in ``drake:`` tags) driving a small rotor body, in series with
  a passive link-side joint ``<name>_deflection`` carrying a spring and a damper. The link
  angle is motor angle + deflection. Used by the onboard plant.

Kinematic conventions: each link's frame sits on its joint axis; at zero joint angles every
frame is parallel to the model frame and a link's geometry is a capsule from its frame origin
along ``segment_m`` (the vector to the next joint, or to the tool point for the last link).
Links that always overlap near a joint are excluded from collision with
``drake:collision_filter_group`` (consecutive links, plus any pair listed in
``extra_filtered_pairs``); Drake's automatic parent/child filter does not cover the flexible
model, where rotor bodies sit between the links.

The committed files under ``arms/models/`` are generated from this module by
``python -m telesmooth.arms.description``; a test checks they are in sync.
"""

from __future__ import annotations

import dataclasses
import math
import pathlib
from collections.abc import Sequence

import numpy as np

__all__ = [
    "AIR_BEARING_ARM_3DOF",
    "ARMS",
    "ArmDescription",
    "DRIVE_FIELDS",
    "PLANT_PRESETS",
    "JointDescription",
    "LinkDescription",
    "MODELS_DIRECTORY",
    "SPACE_ARM_6DOF",
    "arm_sdf",
    "drive_preset",
    "model_path",
    "with_drive",
    "write_models",
]

MODELS_DIRECTORY = pathlib.Path(__file__).resolve().parent / "models"
"""Where the generated SDFormat files are committed."""


@dataclasses.dataclass(frozen=True)
class LinkDescription:
    """One rigid link: a solid capsule-like rod.

    Attributes:
        name: Body name in the model.
        mass_kg: Mass, kg (> 0).
        radius_m: Radius of the rod and of its collision capsule, m (> 0).
        segment_m: Vector from this link's joint to the next joint (or the tool point), in the
            link frame at zero angles, m; shape (3,). Its length is the link length.
        color_rgba: Visual colour.
    """

    name: str
    mass_kg: float
    radius_m: float
    segment_m: tuple[float, float, float]
    color_rgba: tuple[float, float, float, float] = (0.85, 0.85, 0.88, 1.0)

    @property
    def length_m(self) -> float:
        return float(np.linalg.norm(self.segment_m))

    def inertia_about_center(self) -> np.ndarray:
        """Rotational inertia of a solid cylinder (length, radius) about its centre, kg·m², 3x3.

        I_axial = m r²/2; I_transverse = m (3 r² + l²)/12; rotated so the axis is ``segment_m``.
        """
        m, r, length = self.mass_kg, self.radius_m, self.length_m
        axial = 0.5 * m * r * r
        transverse = m * (3.0 * r * r + length * length) / 12.0
        u = np.asarray(self.segment_m, dtype=float) / max(length, 1e-12)
        return transverse * np.eye(3) + (axial - transverse) * np.outer(u, u)


@dataclasses.dataclass(frozen=True)
class JointDescription:
    """A revolute joint and, for the flexible model, its drive-train.

    Attributes:
        name: Joint name (the name used by every joint-space signal in telesmooth).
        axis: Unit rotation axis in the parent link frame at zero angles; shape (3,).
        lower_rad, upper_rad: Position limits, rad.
        max_effort_n_m: Motor torque limit, N·m (> 0): the plant's PD output is clamped to it.
        stiffness_n_m_per_rad: Link-side spring stiffness of the flexible model, N·m/rad.
        damping_n_m_s_per_rad: Link-side damping of the flexible model, N·m·s/rad.
        motor_kp_n_m_per_rad: Proportional gain of the motor-side servo (plant PD), N·m/rad.
        motor_kd_n_m_s_per_rad: Derivative gain of the motor-side servo, N·m·s/rad.
        rotor_inertia_kg_m2: Rotor inertia before the gear, kg·m²; the reflected inertia is
            rotor_inertia·gear_ratio².
        gear_ratio: Gear ratio (dimensionless).
    """

    name: str
    axis: tuple[float, float, float]
    lower_rad: float
    upper_rad: float
    max_effort_n_m: float
    stiffness_n_m_per_rad: float
    damping_n_m_s_per_rad: float
    motor_kp_n_m_per_rad: float
    motor_kd_n_m_s_per_rad: float
    rotor_inertia_kg_m2: float = 1e-4
    gear_ratio: float = 100.0


@dataclasses.dataclass(frozen=True)
class ArmDescription:
    """A serial arm: a fixed base, then (joint i, link i) pairs, base to tip.

    Attributes:
        name: Model name (also the Drake model-instance name).
        base: The fixed base link (its frame is the model frame).
        base_to_first_joint_m: Position of the first joint in the base frame, m.
        joints: Joint descriptions, base to tip.
        links: Link descriptions, one per joint; ``links[i]`` is moved by ``joints[i]``.
        tool_frame: Name of the tool frame, fixed at the end of the last link's segment.
        extra_filtered_pairs: Link-name pairs excluded from collision besides consecutive
            links (e.g. the compact wrist).
        rotor_mass_kg: Mass of each rotor body of the flexible model, kg.
        rotor_body_inertia_kg_m2: Principal inertia of each rotor body, kg·m².
        notes: Where the numbers come from.
    """

    name: str
    base: LinkDescription
    base_to_first_joint_m: tuple[float, float, float]
    joints: tuple[JointDescription, ...]
    links: tuple[LinkDescription, ...]
    tool_frame: str = "tool"
    extra_filtered_pairs: tuple[tuple[str, str], ...] = ()
    rotor_mass_kg: float = 0.2
    rotor_body_inertia_kg_m2: float = 1e-3
    notes: str = ""

    def __post_init__(self) -> None:
        if len(self.joints) != len(self.links) or not self.joints:
            raise ValueError(
                f"ArmDescription {self.name!r}: {len(self.joints)} joints but "
                f"{len(self.links)} links; need one link per joint"
            )
        names = [j.name for j in self.joints]
        if len(set(names)) != len(names):
            raise ValueError(f"ArmDescription {self.name!r}: joint names {names!r} repeat")
        for joint in self.joints:
            if not joint.lower_rad < joint.upper_rad:
                raise ValueError(
                    f"joint {joint.name!r}: lower_rad = {joint.lower_rad!r} must be below "
                    f"upper_rad = {joint.upper_rad!r}"
                )

    @property
    def num_joints(self) -> int:
        return len(self.joints)

    @property
    def joint_names(self) -> tuple[str, ...]:
        return tuple(j.name for j in self.joints)

    @property
    def joint_lower_rad(self) -> np.ndarray:
        return np.array([j.lower_rad for j in self.joints])

    @property
    def joint_upper_rad(self) -> np.ndarray:
        return np.array([j.upper_rad for j in self.joints])

    def link_origins_m(self) -> np.ndarray:
        """Frame origin of each link in the model frame at zero angles, m; shape (n, 3)."""
        origins = [np.asarray(self.base_to_first_joint_m, dtype=float)]
        for link in self.links[:-1]:
            origins.append(origins[-1] + np.asarray(link.segment_m, dtype=float))
        return np.array(origins)

    def tool_origin_m(self) -> np.ndarray:
        """Tool point in the model frame at zero angles, m; shape (3,)."""
        return self.link_origins_m()[-1] + np.asarray(self.links[-1].segment_m, dtype=float)

    def filtered_pairs(self) -> tuple[tuple[str, str], ...]:
        """Link pairs excluded from collision: base/link0, consecutive links, extra pairs."""
        bodies = [self.base.name] + [link.name for link in self.links]
        pairs = [(bodies[i], bodies[i + 1]) for i in range(len(bodies) - 1)]
        return tuple(pairs) + tuple(self.extra_filtered_pairs)


def _deg(value: float) -> float:
    return math.radians(value)


_PITCH = (0.0, -1.0, 0.0)  # about −y: positive angles raise the arm in the x-z plane

SPACE_ARM_6DOF = ArmDescription(
    name="space_arm",
    base=LinkDescription("base", 20.0, 0.08, (0.0, 0.0, 0.2), (0.3, 0.3, 0.35, 1.0)),
    base_to_first_joint_m=(0.0, 0.0, 0.2),
    joints=(
        JointDescription("shoulder_yaw", (0.0, 0.0, 1.0), _deg(-170), _deg(170), 300.0,
                         2000.0, 2.0, 10000.0, 200.0),
        JointDescription("shoulder_pitch", _PITCH, _deg(-120), _deg(120), 300.0,
                         2000.0, 2.0, 10000.0, 200.0),
        JointDescription("elbow_pitch", _PITCH, _deg(-150), _deg(150), 150.0,
                         1000.0, 1.0, 5000.0, 141.0),
        JointDescription("wrist_pitch", _PITCH, _deg(-120), _deg(120), 50.0,
                         200.0, 0.2, 1000.0, 63.0),
        JointDescription("wrist_yaw", (0.0, 0.0, 1.0), _deg(-120), _deg(120), 30.0,
                         100.0, 0.1, 500.0, 45.0),
        JointDescription("wrist_roll", (1.0, 0.0, 0.0), _deg(-170), _deg(170), 10.0,
                         20.0, 0.02, 100.0, 20.0),
    ),
    links=(
        LinkDescription("link1", 6.0, 0.07, (0.0, 0.0, 0.25)),
        LinkDescription("link2", 5.0, 0.05, (0.5, 0.0, 0.0)),
        LinkDescription("link3", 3.5, 0.045, (0.4, 0.0, 0.0)),
        LinkDescription("link4", 1.2, 0.04, (0.12, 0.0, 0.0)),
        LinkDescription("link5", 0.8, 0.035, (0.04, 0.0, 0.0)),
        LinkDescription("link6", 0.5, 0.03, (0.04, 0.0, 0.0), (0.9, 0.5, 0.1, 1.0)),
    ),
    extra_filtered_pairs=(("link4", "link6"),),
    notes=(
        "Our values (the paper's DH table is lost): 0.2 m pedestal, 0.25 m shoulder column, "
        "0.5 m upper arm, 0.4 m forearm, 0.2 m wrist + tool; 17 kg moving mass; springs "
        "20-2000 N·m/rad keep sqrt(k/I)·h below 0.5 at a 1 ms plant step; motor servos "
        "kp = 5 k, kd = 2 sqrt(kp J_reflected) (critically damped motor, ringing link)."
    ),
)
"""The 6-DOF space manipulator (our numbers)."""

AIR_BEARING_ARM_3DOF = ArmDescription(
    name="air_bearing_arm",
    base=LinkDescription("base", 30.0, 0.08, (0.0, 0.0, -0.1), (0.3, 0.3, 0.35, 1.0)),
    base_to_first_joint_m=(0.0, 0.0, 0.0),
    joints=(
        JointDescription("shoulder", (0.0, 0.0, 1.0), _deg(-170), _deg(170), 150.0,
                         500.0, 0.5, 2000.0, 89.0),
        JointDescription("elbow", (0.0, 0.0, 1.0), _deg(-170), _deg(170), 100.0,
                         300.0, 0.3, 1500.0, 77.0),
        JointDescription("wrist", (0.0, 0.0, 1.0), _deg(-170), _deg(170), 40.0,
                         100.0, 0.1, 750.0, 55.0),
    ),
    links=(
        LinkDescription("link1", 6.0, 0.05, (0.5, 0.0, 0.0)),
        LinkDescription("link2", 4.0, 0.045, (0.4, 0.0, 0.0)),
        LinkDescription("link3", 1.5, 0.04, (0.2, 0.0, 0.0), (0.9, 0.5, 0.1, 1.0)),
    ),
    notes=(
        "The 6-DOF arm's pitch joints laid on their side on air bearings (yaw and roll "
        "locked): joints about +z, link lengths 0.5/0.4/0.2 m as telesmooth.arms.planar; "
        "motor servos kp = 4-7.5 k, critically damped. Our values, not the paper's."
    ),
)
"""The air-bearing configuration as a planar 3-joint model (our numbers)."""

ARMS: dict[str, ArmDescription] = {
    "space_arm": SPACE_ARM_6DOF,
    "air_bearing_arm": AIR_BEARING_ARM_3DOF,
}
"""The arms by the name a scenario's ``arm`` and :attr:`FlexibleArmConfig.arm` give: the one
registry of arms."""


DRIVE_FIELDS = ("stiffness_n_m_per_rad", "damping_n_m_s_per_rad", "rotor_inertia_kg_m2",
                "motor_kp_n_m_per_rad", "motor_kd_n_m_s_per_rad")
"""The drive-train parameters of a joint that a scenario can set (the plant's vibration)."""

PLANT_PRESETS = ("lab", "lightweight")
"""Named sets of drive parameters: ``"lab"``, each arm's own numbers above (the laboratory
set-up: lowest lightly damped mode 2.66 Hz with damping ratio 0.072 at the default start pose of
the air-bearing arm); ``"lightweight"``, a lightweight space arm: springs 10× softer and
dampers about half as strong, lowest lightly damped mode 0.90 Hz with damping ratio 0.020
(air-bearing arm at its default start pose) and 1.24 Hz with 0.021 (6-DOF arm at the
OneOfEverything start pose). For scale: the shuttle arm's unloaded first mode is 0.35-0.71 Hz
depending on configuration. The modes depend on the pose:
:func:`telesmooth.arms.modes.plant_modes` computes them."""

_LIGHTWEIGHT_DRIVES = {
    "space_arm": {"stiffness_n_m_per_rad": (200.0, 200.0, 100.0, 20.0, 10.0, 2.0),
                  "damping_n_m_s_per_rad": (1.0, 1.0, 0.5, 0.1, 0.05, 0.01)},
    "air_bearing_arm": {"stiffness_n_m_per_rad": (50.0, 30.0, 10.0),
                        "damping_n_m_s_per_rad": (0.3, 0.18, 0.06)},
}


def with_drive(arm: ArmDescription, **values) -> ArmDescription:
    """``arm`` with the drive parameters of its joints replaced.

    Args:
        arm: The arm.
        **values: Field of :data:`DRIVE_FIELDS` → one value per joint, base to tip.

    Raises:
        ValueError: for an unknown field or a wrong number of values.
    """
    unknown = sorted(set(values) - set(DRIVE_FIELDS))
    if unknown:
        raise ValueError(f"unknown drive field(s) {unknown}; known: {list(DRIVE_FIELDS)}")
    for field, per_joint in values.items():
        if len(per_joint) != arm.num_joints:
            raise ValueError(f"{field} has {len(per_joint)} values; the arm {arm.name!r} has "
                             f"{arm.num_joints} joints")
    joints = tuple(
        dataclasses.replace(joint, **{field: float(per_joint[index])
                                      for field, per_joint in values.items()})
        for index, joint in enumerate(arm.joints))
    return dataclasses.replace(arm, joints=joints)


def drive_preset(arm: ArmDescription, preset: str) -> ArmDescription:
    """``arm`` with the drive parameters of a named preset (:data:`PLANT_PRESETS`)."""
    if preset not in PLANT_PRESETS:
        raise ValueError(f"preset = {preset!r} must be one of {PLANT_PRESETS}")
    if preset == "lab":
        return arm
    return with_drive(arm, **_LIGHTWEIGHT_DRIVES[arm.name])


def _fmt(values: Sequence[float]) -> str:
    return " ".join(f"{float(v):.12g}" for v in values)


def _inertial_xml(link: LinkDescription, indent: str) -> str:
    center = 0.5 * np.asarray(link.segment_m, dtype=float)
    inertia = link.inertia_about_center()
    return (
        f"{indent}<inertial>\n"
        f"{indent}  <pose>{_fmt(center)} 0 0 0</pose>\n"
        f"{indent}  <mass>{link.mass_kg:.12g}</mass>\n"
        f"{indent}  <inertia><ixx>{inertia[0, 0]:.12g}</ixx><ixy>{inertia[0, 1]:.12g}</ixy>"
        f"<ixz>{inertia[0, 2]:.12g}</ixz><iyy>{inertia[1, 1]:.12g}</iyy>"
        f"<iyz>{inertia[1, 2]:.12g}</iyz><izz>{inertia[2, 2]:.12g}</izz></inertia>\n"
        f"{indent}</inertial>\n"
    )


def _rod_pose(link: LinkDescription) -> str:
    """Pose of a z-aligned capsule/cylinder so that it lies along ``segment_m``."""
    segment = np.asarray(link.segment_m, dtype=float)
    center = 0.5 * segment
    u = segment / link.length_m
    # Rotation taking +z to u, written as roll-pitch-yaw (fixed axes X, then Y, then Z).
    pitch = math.atan2(math.hypot(u[0], u[1]), u[2])
    yaw = math.atan2(u[1], u[0]) if math.hypot(u[0], u[1]) > 1e-12 else 0.0
    return f"{_fmt(center)} 0 {pitch:.12g} {yaw:.12g}"


def _link_xml(link: LinkDescription, origin: np.ndarray, *, collision: bool) -> str:
    pose = _rod_pose(link)
    geometry = (
        f"<capsule><radius>{link.radius_m:.12g}</radius>"
        f"<length>{link.length_m:.12g}</length></capsule>"
    )
    text = f'    <link name="{link.name}">\n      <pose>{_fmt(origin)} 0 0 0</pose>\n'
    text += _inertial_xml(link, "      ")
    text += (
        f'      <visual name="{link.name}_visual">\n        <pose>{pose}</pose>\n'
        f"        <geometry>{geometry}</geometry>\n"
        f"        <material><diffuse>{_fmt(link.color_rgba)}</diffuse></material>\n"
        "      </visual>\n"
    )
    if collision:
        text += (
            f'      <collision name="{link.name}_collision">\n        <pose>{pose}</pose>\n'
            f"        <geometry>{geometry}</geometry>\n      </collision>\n"
        )
    return text + "    </link>\n"


def _rotor_xml(name: str, origin: np.ndarray, mass: float, inertia: float) -> str:
    return (
        f'    <link name="{name}">\n      <pose>{_fmt(origin)} 0 0 0</pose>\n'
        f"      <inertial><mass>{mass:.12g}</mass><inertia><ixx>{inertia:.12g}</ixx>"
        f"<iyy>{inertia:.12g}</iyy><izz>{inertia:.12g}</izz></inertia></inertial>\n"
        "    </link>\n"
    )


def _axis_xml(joint: JointDescription, *, lower, upper, effort, dynamics: str = "") -> str:
    return (
        f"      <axis><xyz>{_fmt(joint.axis)}</xyz>\n"
        f"        <limit><lower>{lower:.12g}</lower><upper>{upper:.12g}</upper>"
        f"<effort>{effort:.12g}</effort></limit>{dynamics}\n      </axis>\n"
    )


def arm_sdf(arm: ArmDescription, *, flexible: bool) -> str:
    """SDFormat text of ``arm``: rigid (one actuated joint per joint) or flexible (see module).

    The base is welded to the world; the tool frame ``arm.tool_frame`` is attached to the
    last link at the end of its segment.
    """
    origins = arm.link_origins_m()
    kind = "flexible" if flexible else "rigid"
    text = (
        '<?xml version="1.0"?>\n'
        "<!-- Generated by `python -m telesmooth.arms.description`; do not edit by hand. -->\n"
        f"<!-- {arm.name} ({kind}). {arm.notes} -->\n"
        '<sdf version="1.9" xmlns:drake="http://drake.mit.edu">\n'
        f'  <model name="{arm.name}">\n'
    )
    text += _link_xml(arm.base, np.zeros(3), collision=True)
    text += (
        '    <joint name="weld_base" type="fixed"><parent>world</parent>'
        "<child>base</child></joint>\n"
    )
    parent = arm.base.name
    for joint, link, origin in zip(arm.joints, arm.links, origins):
        text += _link_xml(link, origin, collision=True)
        if not flexible:
            text += f'    <joint name="{joint.name}" type="revolute">\n'
            text += f"      <parent>{parent}</parent><child>{link.name}</child>\n"
            text += _axis_xml(joint, lower=joint.lower_rad, upper=joint.upper_rad,
                              effort=joint.max_effort_n_m)
            text += "    </joint>\n"
        else:
            rotor = f"{joint.name}_rotor"
            text += _rotor_xml(rotor, origin, arm.rotor_mass_kg, arm.rotor_body_inertia_kg_m2)
            text += f'    <joint name="{joint.name}_motor" type="revolute">\n'
            text += f"      <parent>{parent}</parent><child>{rotor}</child>\n"
            text += _axis_xml(joint, lower=joint.lower_rad, upper=joint.upper_rad,
                              effort=joint.max_effort_n_m)
            text += (
                f"      <drake:rotor_inertia>{joint.rotor_inertia_kg_m2:.12g}"
                f"</drake:rotor_inertia>\n"
                f"      <drake:gear_ratio>{joint.gear_ratio:.12g}</drake:gear_ratio>\n"
                f'      <drake:controller_gains p="{joint.motor_kp_n_m_per_rad:.12g}" '
                f'd="{joint.motor_kd_n_m_s_per_rad:.12g}"/>\n'
                "    </joint>\n"
            )
            dynamics = (
                f"\n        <dynamics><damping>{joint.damping_n_m_s_per_rad:.12g}</damping>"
                f"<spring_stiffness>{joint.stiffness_n_m_per_rad:.12g}</spring_stiffness>"
                "<spring_reference>0</spring_reference></dynamics>"
            )
            text += f'    <joint name="{joint.name}_deflection" type="revolute">\n'
            text += f"      <parent>{rotor}</parent><child>{link.name}</child>\n"
            text += _axis_xml(joint, lower=-1.0, upper=1.0, effort=0.0, dynamics=dynamics)
            text += "    </joint>\n"
        parent = link.name
    tool = np.asarray(arm.links[-1].segment_m, dtype=float)
    text += (
        f'    <frame name="{arm.tool_frame}" attached_to="{arm.links[-1].name}">\n'
        f"      <pose relative_to=\"{arm.links[-1].name}\">{_fmt(tool)} 0 0 0</pose>\n"
        "    </frame>\n"
    )
    for index, (body_a, body_b) in enumerate(arm.filtered_pairs()):
        group = f"filter_{index}_{body_a}_{body_b}"
        text += (
            f'    <drake:collision_filter_group name="{group}">\n'
            f"      <drake:member>{body_a}</drake:member>\n"
            f"      <drake:member>{body_b}</drake:member>\n"
            f"      <drake:ignored_collision_filter_group>{group}"
            "</drake:ignored_collision_filter_group>\n"
            "    </drake:collision_filter_group>\n"
        )
    return text + "  </model>\n</sdf>\n"


def model_path(arm: ArmDescription, *, flexible: bool) -> pathlib.Path:
    """Path of the committed SDFormat file of ``arm``."""
    suffix = "_flexible" if flexible else ""
    return MODELS_DIRECTORY / f"{arm.name}{suffix}.sdf"


def write_models(directory: pathlib.Path | None = None) -> list[pathlib.Path]:
    """(Re)writes the rigid and flexible SDFormat files of both arms; returns their paths."""
    written = []
    for arm in (SPACE_ARM_6DOF, AIR_BEARING_ARM_3DOF):
        for flexible in (False, True):
            path = model_path(arm, flexible=flexible)
            if directory is not None:
                path = pathlib.Path(directory) / path.name
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_text(arm_sdf(arm, flexible=flexible))
            written.append(path)
    return written


if __name__ == "__main__":
    for written_path in write_models():
        print(written_path)
