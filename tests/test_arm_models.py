"""Arm models: generated files in sync, kinematics against independent formulas, no downloads."""

import pathlib

import numpy as np
import pytest
from pydrake.multibody.plant import AddMultibodyPlantSceneGraph, MultibodyPlant
from pydrake.multibody.tree import ForceElementIndex, RevoluteSpring
from pydrake.systems.framework import DiagramBuilder

from telesmooth.arms.description import (
    AIR_BEARING_ARM_3DOF,
    SPACE_ARM_6DOF,
    ArmDescription,
    JointDescription,
    LinkDescription,
    arm_sdf,
    model_path,
    write_models,
)
from telesmooth.arms.drake_models import add_arm, add_workspace
from telesmooth.arms.planar import AIR_BEARING_ARM, planar_forward_kinematics
from telesmooth.arms.workspace import (
    AIR_BEARING_WORKSPACE,
    SPACE_ARM_WORKSPACE,
    BoxObstacle,
    Workspace,
)

REPO = pathlib.Path(__file__).resolve().parents[1]
ARMS = (SPACE_ARM_6DOF, AIR_BEARING_ARM_3DOF)


def _plant(arm, *, flexible, workspace=None):
    builder = DiagramBuilder()
    plant, scene_graph = AddMultibodyPlantSceneGraph(builder, 0.0)
    add_arm(plant, arm, flexible=flexible)
    if workspace is not None:
        add_workspace(plant, workspace)
    plant.Finalize()
    diagram = builder.Build()
    context = diagram.CreateDefaultContext()
    return plant, scene_graph, diagram, context


@pytest.mark.parametrize("flexible", [False, True])
@pytest.mark.parametrize("arm", ARMS, ids=lambda a: a.name)
def test_committed_models_match_the_generator(arm, flexible):
    assert model_path(arm, flexible=flexible).read_text() == arm_sdf(arm, flexible=flexible)


def test_write_models_writes_four_files(tmp_path):
    paths = write_models(tmp_path)
    assert sorted(p.name for p in paths) == sorted(
        f"{a.name}{s}.sdf" for a in ARMS for s in ("", "_flexible"))
    for path in paths:
        assert path.read_text() == (REPO / "arms" / "models" / path.name).read_text()


def test_no_runtime_download_paths_in_models_or_sources():
    offenders = []
    for path in list((REPO / "arms").rglob("*")) + list((REPO / "systems").rglob("*.py")):
        if path.is_file() and path.suffix in (".sdf", ".urdf", ".py"):
            text = path.read_text()
            if "package://" in text or (path.suffix != ".py" and "drake_models" in text):
                offenders.append(str(path))
    assert offenders == []


@pytest.mark.parametrize("arm", ARMS, ids=lambda a: a.name)
def test_rigid_model_structure_and_limits(arm):
    plant, *_ = _plant(arm, flexible=False)
    assert plant.num_positions() == arm.num_joints
    assert plant.num_actuators() == arm.num_joints
    for joint_description in arm.joints:
        joint = plant.GetJointByName(joint_description.name)
        assert joint.position_lower_limits()[0] == pytest.approx(joint_description.lower_rad)
        assert joint.position_upper_limits()[0] == pytest.approx(joint_description.upper_rad)
    moving = sum(link.mass_kg for link in arm.links) + arm.base.mass_kg
    assert plant.CalcTotalMass(plant.CreateDefaultContext()) == pytest.approx(moving)


@pytest.mark.parametrize("arm", ARMS, ids=lambda a: a.name)
def test_flexible_model_has_motor_and_spring_per_joint(arm):
    plant, *_ = _plant(arm, flexible=True)
    assert plant.num_positions() == 2 * arm.num_joints
    assert plant.num_actuators() == arm.num_joints
    springs = [plant.get_force_element(ForceElementIndex(i))
               for i in range(plant.num_force_elements())]
    springs = {s.joint().name(): s for s in springs if isinstance(s, RevoluteSpring)}
    for description in arm.joints:
        actuator = plant.GetJointActuatorByName(f"{description.name}_motor")
        assert actuator.default_rotor_inertia() == pytest.approx(description.rotor_inertia_kg_m2)
        assert actuator.default_gear_ratio() == pytest.approx(description.gear_ratio)
        gains = actuator.get_controller_gains()
        assert (gains.p, gains.d) == pytest.approx((description.motor_kp_n_m_per_rad,
                                                    description.motor_kd_n_m_s_per_rad))
        assert actuator.effort_limit() == pytest.approx(description.max_effort_n_m)
        spring = springs[f"{description.name}_deflection"]
        assert spring.default_stiffness() == pytest.approx(description.stiffness_n_m_per_rad)
        deflection = plant.GetJointByName(f"{description.name}_deflection")
        assert deflection.default_damping() == pytest.approx(description.damping_n_m_s_per_rad)


def _rod_inertia_by_quadrature(link: LinkDescription) -> np.ndarray:
    """Oracle: inertia of a solid cylinder about its centre by midpoint quadrature."""
    m, r, length = link.mass_kg, link.radius_m, link.length_m
    rho = m / (np.pi * r * r * length)
    n = 60
    s = (np.arange(n) + 0.5) / n
    z = (s - 0.5) * length
    radius = s * r
    angle = s * 2.0 * np.pi
    Z, R, A = np.meshgrid(z, radius, angle, indexing="ij")
    dv = (length / n) * (r / n) * (2 * np.pi / n) * R
    x, y = R * np.cos(A), R * np.sin(A)
    points = np.stack([x, y, Z], axis=-1).reshape(-1, 3)
    weights = (rho * dv).reshape(-1)
    r2 = np.sum(points**2, axis=1)
    inertia_local = (np.eye(3) * np.sum(weights * r2)
                     - np.einsum("i,ij,ik->jk", weights, points, points))
    u = np.asarray(link.segment_m, dtype=float) / length
    # rotation taking +z to u
    v = np.cross([0.0, 0.0, 1.0], u)
    c = u[2]
    if np.linalg.norm(v) < 1e-12:
        rot = np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])
    else:
        vx = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
        rot = np.eye(3) + vx + vx @ vx / (1.0 + c)
    return rot @ inertia_local @ rot.T


@pytest.mark.parametrize("link", SPACE_ARM_6DOF.links + (SPACE_ARM_6DOF.base,),
                         ids=lambda link: link.name)
def test_link_inertia_matches_quadrature(link):
    np.testing.assert_allclose(link.inertia_about_center(), _rod_inertia_by_quadrature(link),
                               rtol=2e-3, atol=1e-9 * link.mass_kg)


def test_plant_reads_back_our_inertia():
    plant, *_ = _plant(SPACE_ARM_6DOF, flexible=False)
    for link in SPACE_ARM_6DOF.links:
        body = plant.GetBodyByName(link.name)
        spatial = body.default_spatial_inertia()
        np.testing.assert_allclose(spatial.get_com(), 0.5 * np.asarray(link.segment_m),
                                   atol=1e-12)
        about_com = spatial.Shift(spatial.get_com()).CalcRotationalInertia().CopyToFullMatrix3()
        np.testing.assert_allclose(about_com, link.inertia_about_center(), rtol=1e-9,
                                   atol=1e-12)


def test_air_bearing_model_matches_the_planar_arm():
    assert AIR_BEARING_ARM_3DOF.joint_names == AIR_BEARING_ARM.joint_names
    np.testing.assert_allclose([link.length_m for link in AIR_BEARING_ARM_3DOF.links],
                               AIR_BEARING_ARM.link_lengths_m)
    np.testing.assert_allclose(AIR_BEARING_ARM_3DOF.joint_lower_rad,
                               AIR_BEARING_ARM.joint_lower_rad)
    np.testing.assert_allclose(AIR_BEARING_ARM_3DOF.joint_upper_rad,
                               AIR_BEARING_ARM.joint_upper_rad)


@pytest.mark.parametrize("flexible", [False, True])
def test_planar_model_tool_point_equals_planar_forward_kinematics(flexible):
    plant, _, diagram, context = _plant(AIR_BEARING_ARM_3DOF, flexible=flexible)
    plant_context = plant.GetMyContextFromRoot(context)
    rng = np.random.default_rng(0)
    tool = plant.GetFrameByName("tool")
    for _ in range(20):
        q = rng.uniform(-2.5, 2.5, 3)
        if flexible:
            deflection = rng.uniform(-0.1, 0.1, 3)
            for name, motor, spring in zip(AIR_BEARING_ARM_3DOF.joint_names, q - deflection,
                                           deflection):
                plant.GetJointByName(f"{name}_motor").set_angle(plant_context, motor)
                plant.GetJointByName(f"{name}_deflection").set_angle(plant_context, spring)
        else:
            plant.SetPositions(plant_context, q)
        p = plant.CalcPointsPositions(plant_context, tool, np.zeros(3), plant.world_frame())
        expected = planar_forward_kinematics(q, AIR_BEARING_ARM.link_lengths_m)
        np.testing.assert_allclose(p.ravel(), [expected[0], expected[1], 0.0], atol=1e-12)


def test_space_arm_with_yaw_and_roll_locked_moves_in_a_plane_like_the_planar_arm():
    """The air-bearing configuration: pitch joints = planar joints in the x-z plane."""
    plant, _, diagram, context = _plant(SPACE_ARM_6DOF, flexible=False)
    plant_context = plant.GetMyContextFromRoot(context)
    tool = plant.GetFrameByName("tool")
    shoulder = SPACE_ARM_6DOF.link_origins_m()[1]
    rng = np.random.default_rng(1)
    for _ in range(20):
        pitches = rng.uniform(-1.5, 1.5, 3)
        plant.SetPositions(plant_context, [0.0, *pitches, 0.0, 0.0])
        p = plant.CalcPointsPositions(plant_context, tool, np.zeros(3), plant.world_frame())
        planar = planar_forward_kinematics(pitches, AIR_BEARING_ARM.link_lengths_m)
        np.testing.assert_allclose(p.ravel(), shoulder + [planar[0], 0.0, planar[1]],
                                   atol=1e-12)


@pytest.mark.parametrize("flexible", [False, True])
@pytest.mark.parametrize("arm,workspace", [(SPACE_ARM_6DOF, SPACE_ARM_WORKSPACE),
                                           (AIR_BEARING_ARM_3DOF, AIR_BEARING_WORKSPACE)],
                         ids=["space_arm", "air_bearing_arm"])
def test_zero_pose_is_collision_free_and_neighbours_are_filtered(arm, workspace, flexible):
    plant, scene_graph, diagram, context = _plant(arm, flexible=flexible, workspace=workspace)
    query = scene_graph.get_query_output_port().Eval(scene_graph.GetMyContextFromRoot(context))
    inspector = query.inspector()
    assert not query.HasCollisions()
    names = set()
    for a, b in inspector.GetCollisionCandidates():
        body_a = plant.GetBodyFromFrameId(inspector.GetFrameId(a)).name()
        body_b = plant.GetBodyFromFrameId(inspector.GetFrameId(b)).name()
        names.add(frozenset((body_a, body_b)))
    for pair in arm.filtered_pairs():
        assert frozenset(pair) not in names
    # Non-neighbours still collide: e.g. link1 with link3.
    assert frozenset(("link1", "link3")) in names


def test_workspace_walls_enclose_the_bounds():
    walls = {w.name: w for w in SPACE_ARM_WORKSPACE.walls()}
    assert len(walls) == 6
    upper_x = walls["wall_x_upper"]
    assert upper_x.center_m[0] - 0.5 * upper_x.size_m[0] == pytest.approx(1.25)
    assert len(AIR_BEARING_WORKSPACE.walls()) == 4


@pytest.mark.parametrize("kwargs,match", [
    (dict(name="b", center_m=(0, 0), size_m=(1, 1, 1)), "center_m"),
    (dict(name="b", center_m=(0, 0, 0), size_m=(1, -1, 1)), r"size_m.y = -1.0"),
    (dict(name="b", center_m=(0, float("nan"), 0), size_m=(1, 1, 1)), r"center_m.y = nan"),
    (dict(name="", center_m=(0, 0, 0), size_m=(1, 1, 1)), "name"),
])
def test_box_obstacle_validation(kwargs, match):
    with pytest.raises(ValueError, match=match):
        BoxObstacle(**kwargs)


def test_workspace_validation():
    with pytest.raises(ValueError, match=r"bounds_lower_m.z = 2.0 must be below"):
        Workspace(bounds_lower_m=(0, 0, 2), bounds_upper_m=(1, 1, 1))
    with pytest.raises(ValueError, match="given together"):
        Workspace(bounds_lower_m=(0, 0, 0))
    box = BoxObstacle("a", (0, 0, 0), (1, 1, 1))
    with pytest.raises(ValueError, match="unique"):
        Workspace(obstacles=(box, box))


def test_arm_description_validation():
    link = LinkDescription("l", 1.0, 0.1, (1.0, 0.0, 0.0))
    joint = JointDescription("j", (0, 0, 1), 1.0, -1.0, 1.0, 1.0, 0.0, 1.0, 0.0)
    with pytest.raises(ValueError, match=r"joint 'j': lower_rad = 1.0 must be below"):
        ArmDescription("x", link, (0, 0, 0), (joint,), (link,))
    with pytest.raises(ValueError, match="one link per joint"):
        ArmDescription("x", link, (0, 0, 0), (), (link,))


def test_add_arm_loads_an_edited_description_not_the_committed_file():
    import dataclasses
    longer = dataclasses.replace(
        AIR_BEARING_ARM_3DOF,
        links=(dataclasses.replace(AIR_BEARING_ARM_3DOF.links[0], segment_m=(0.6, 0.0, 0.0)),)
        + AIR_BEARING_ARM_3DOF.links[1:])
    plant = MultibodyPlant(0.0)
    add_arm(plant, longer, flexible=False)
    plant.Finalize()
    context = plant.CreateDefaultContext()
    tip = plant.CalcPointsPositions(context, plant.GetFrameByName("tool"), np.zeros(3),
                                    plant.world_frame())
    assert tip[0, 0] == pytest.approx(0.6 + 0.4 + 0.2)


def test_lifted_planar_poses_are_reached_by_the_lifted_planar_joints():
    from pydrake.math import RollPitchYaw, RotationMatrix

    from telesmooth.arms.air_bearing import planar_joints_to_space_arm, planar_pose_to_space_arm
    from telesmooth.arms.space_arm_ik import SpaceArmKinematics

    kinematics = SpaceArmKinematics(SPACE_ARM_6DOF)
    rng = np.random.default_rng(2)
    for _ in range(10):
        q = rng.uniform(-1.2, 1.2, 3)
        xy = planar_forward_kinematics(q, AIR_BEARING_ARM.link_lengths_m)
        pose = [xy[0], xy[1], float(np.sum(q))]
        lifted = planar_pose_to_space_arm(pose)
        X = kinematics.tool_transform(planar_joints_to_space_arm(q))
        np.testing.assert_allclose(X.translation(), lifted[:3], atol=1e-12)
        R = RotationMatrix(RollPitchYaw(lifted[3:])).matrix()
        np.testing.assert_allclose(X.rotation().matrix(), R, atol=1e-12)
