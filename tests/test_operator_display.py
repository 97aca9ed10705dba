"""The operator's display geometry (systems/operator_display.py): the wire-frame capsule mesh,
each link's capsule placed as the arm's SDFormat places its visual, and ``ArmDrawing``'s link
frames at known joint angles. Each test's comment says which wrong implementation it
catches."""

import math
import re

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pydrake.math import RigidTransform, RollPitchYaw
from pydrake.multibody.plant import AddMultibodyPlantSceneGraph
from pydrake.systems.framework import DiagramBuilder

from telesmooth.arms.description import (
    AIR_BEARING_ARM_3DOF,
    SPACE_ARM_6DOF,
    LinkDescription,
    _rod_pose,
)
from telesmooth.arms.drake_models import add_arm
from telesmooth.systems.operator_display import (
    PLANNING_RGBA,
    ArmDrawing,
    capsule_mesh,
    link_visual_pose,
)

ARMS = (SPACE_ARM_6DOF, AIR_BEARING_ARM_3DOF)
ALL_LINKS = [(arm.name, link) for arm in ARMS for link in (arm.base,) + arm.links]
# The SDFormat text writes 12 significant digits ("%.12g"): π/2 is written 1.57079632679,
# 4.9e-12 short, and its cosine differs by as much. Poses read back from the text agree to that.
SDF_DIGITS = 1e-11


# --- capsule_mesh ---------------------------------------------------------------------------


def distance_to_axis_segment(points, length):
    """Distance of each point (3, N) to the segment z ∈ [−L/2, L/2] on the z axis."""
    z = np.clip(points[2], -0.5 * length, 0.5 * length)
    return np.sqrt(points[0] ** 2 + points[1] ** 2 + (points[2] - z) ** 2)


MESHES = [(0.05, 0.5, 12, 3), (0.03, 0.04, 12, 3), (0.2, 0.1, 7, 1), (0.045, 0.4, 24, 5)]


@pytest.mark.parametrize("radius, length, around, cap_rings", MESHES)
def test_every_capsule_vertex_lies_on_the_capsule_surface(radius, length, around, cap_rings):
    # Catches: caps centred at the origin instead of the segment's ends, sin and cos swapped
    # in a cap ring (points off the sphere), a cylinder of the diameter instead of the radius.
    vertices, faces = capsule_mesh(radius, length, around=around, cap_rings=cap_rings)
    assert vertices.shape == (3, around * (2 * cap_rings + 2)) and vertices.dtype == float
    np.testing.assert_allclose(distance_to_axis_segment(vertices, length), radius,
                               rtol=0, atol=1e-12)
    # It spans the whole capsule: both poles and both rims of the cylinder.
    assert vertices[2].min() == pytest.approx(-0.5 * length - radius, abs=1e-15)
    assert vertices[2].max() == pytest.approx(0.5 * length + radius, abs=1e-15)
    for rim in (-0.5 * length, 0.5 * length):
        ring = vertices[:, vertices[2] == rim]
        assert ring.shape[1] == around
        np.testing.assert_allclose(np.hypot(ring[0], ring[1]), radius, rtol=0, atol=1e-15)


def face_edges(faces):
    edges = {}
    for face in faces.T:
        for a, b in ((face[0], face[1]), (face[1], face[2]), (face[2], face[0])):
            key = (min(a, b), max(a, b))
            edges[key] = edges.get(key, 0) + 1
    return edges


@pytest.mark.parametrize("radius, length, around, cap_rings", MESHES)
def test_capsule_faces_close_the_surface_except_at_the_degenerate_poles(
        radius, length, around, cap_rings):
    # Catches: an index past the last vertex, a ring that does not wrap (i + 1 without
    # % around: a slit down the side), a quad split that leaves holes or overlaps (an edge
    # used once or three times), a missing ring of faces.
    vertices, faces = capsule_mesh(radius, length, around=around, cap_rings=cap_rings)
    rings = 2 * cap_rings + 2
    assert faces.shape == (3, 2 * around * (rings - 1)) and faces.dtype == np.int32
    assert faces.min() >= 0 and faces.max() < vertices.shape[1]
    assert all(len(set(face)) == 3 for face in faces.T)
    # The poles are rings of `around` coincident vertices (radius r·cos(π/2) ≈ 6e-17): their
    # ring edges are used once, every other edge by exactly two faces.
    poles = set(range(around)) | set(range((rings - 1) * around, rings * around))
    for (a, b), count in face_edges(faces).items():
        expected = 1 if a in poles and b in poles else 2
        assert count == expected, (a, b)
    for pole in (range(around), range((rings - 1) * around, rings * around)):
        np.testing.assert_allclose(np.hypot(*vertices[:2, list(pole)]), 0.0, atol=1e-15)


@pytest.mark.parametrize("radius, length, around, cap_rings", MESHES)
def test_capsule_faces_face_outwards(radius, length, around, cap_rings):
    # Catches: a ring order that folds the mesh back on itself (a cap built the wrong way
    # round), faces wound inconsistently.
    vertices, faces = capsule_mesh(radius, length, around=around, cap_rings=cap_rings)
    a, b, c = (vertices[:, faces[k]] for k in range(3))
    normal = np.cross((b - a).T, (c - a).T).T
    area = np.linalg.norm(normal, axis=0)
    centroid = (a + b + c) / 3.0
    axis_point = np.zeros_like(centroid)
    axis_point[2] = np.clip(centroid[2], -0.5 * length, 0.5 * length)
    outward = np.sum(normal * (centroid - axis_point), axis=0)
    real = area > 1e-12 * radius ** 2          # the poles' zero-area triangles aside
    assert real.sum() == faces.shape[1] - 2 * around
    assert np.all(outward[real] > 0.0)


# --- link_visual_pose -----------------------------------------------------------------------


def pose_from_sdf_text(text):
    """The RigidTransform of an SDFormat ``<pose>`` "x y z roll pitch yaw"."""
    x, y, z, roll, pitch, yaw = (float(v) for v in text.split())
    return RigidTransform(RollPitchYaw(roll, pitch, yaw), [x, y, z])


@pytest.mark.parametrize("arm_name, link", ALL_LINKS,
                         ids=[f"{a}-{link.name}" for a, link in ALL_LINKS])
def test_link_visual_pose_is_the_pose_the_sdf_text_gives_the_visual(arm_name, link):
    # Catches: a display capsule placed differently from the model's (e.g. at the joint
    # rather than the segment's middle, or rolled about another axis).
    expected = pose_from_sdf_text(_rod_pose(link))
    np.testing.assert_allclose(link_visual_pose(link).GetAsMatrix4(),
                               expected.GetAsMatrix4(), rtol=0, atol=SDF_DIGITS)


@pytest.mark.parametrize("arm", ARMS, ids=[arm.name for arm in ARMS])
def test_link_visual_pose_is_the_pose_drake_parses_from_the_arms_sdf(arm):
    # Catches the same as above against the model Drake actually loads (the generated SDF's
    # <visual><pose>, read by Drake's parser, in the body frame).
    builder = DiagramBuilder()
    plant, scene_graph = AddMultibodyPlantSceneGraph(builder, 0.0)
    add_arm(plant, arm, flexible=False)
    plant.Finalize()
    inspector = scene_graph.model_inspector()
    for link in (arm.base,) + arm.links:
        (visual,) = plant.GetVisualGeometriesForBody(plant.GetBodyByName(link.name))
        np.testing.assert_allclose(link_visual_pose(link).GetAsMatrix4(),
                                   inspector.GetPoseInFrame(visual).GetAsMatrix4(),
                                   rtol=0, atol=SDF_DIGITS)


unit_component = st.floats(-1.0, 1.0, allow_nan=False)


@settings(max_examples=200, deadline=None)
@given(segment=st.tuples(unit_component, unit_component, unit_component)
       .filter(lambda s: np.linalg.norm(s) > 1e-3)
       | st.sampled_from([(1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, 1), (0, 0, -1),
                          (0.3, -0.4, 0.0), (-0.2, -0.2, -0.5)]))
def test_link_visual_pose_puts_the_capsule_axis_along_the_segment_centred_on_it(segment):
    # Catches sign errors the shipped arms cannot show (their segments lie along +x, +z, −z
    # only): a yaw of atan2(x, y) or −atan2(y, x), a pitch measured from the xy plane.
    segment = np.asarray(segment, dtype=float)
    link = LinkDescription("rod", 1.0, 0.02, tuple(segment))
    pose = link_visual_pose(link)
    u = segment / np.linalg.norm(segment)
    np.testing.assert_allclose(pose.rotation().matrix()[:, 2], u, rtol=0, atol=1e-15)
    np.testing.assert_allclose(pose.translation(), 0.5 * segment, rtol=0, atol=1e-15)
    # A capsule of the link's length from the joint to the segment's end:
    np.testing.assert_allclose(pose.multiply([0.0, 0.0, -0.5 * link.length_m]), 0.0,
                               atol=1e-15)
    np.testing.assert_allclose(pose.multiply([0.0, 0.0, 0.5 * link.length_m]), segment,
                               rtol=0, atol=1e-15)
    expected = pose_from_sdf_text(_rod_pose(link))
    np.testing.assert_allclose(pose.GetAsMatrix4(), expected.GetAsMatrix4(), rtol=0,
                               atol=SDF_DIGITS)


# --- ArmDrawing -----------------------------------------------------------------------------


class RecordingMeshcat:
    """Records what ArmDrawing sends: objects, meshes and the last transform of each path."""

    def __init__(self):
        self.objects, self.meshes, self.transforms = {}, {}, {}
        self.calls = 0

    def Delete(self, path):
        self.calls += 1

    def SetObject(self, path, shape, rgba):
        self.calls += 1
        self.objects[path] = shape

    def SetTriangleMesh(self, path, vertices, faces, rgba, wireframe=False):
        self.calls += 1
        self.meshes[path] = (np.array(vertices), np.array(faces), wireframe)

    def SetTransform(self, path, transform):
        self.calls += 1
        self.transforms[path] = transform


def test_arm_drawing_puts_each_wire_frame_capsule_on_its_link_and_the_links_at_q():
    # Catches: the capsule mesh not the link's (radius or length swapped), visuals placed
    # without link_visual_pose, link frames from another pose than the joint angles'.
    meshcat = RecordingMeshcat()
    arm = AIR_BEARING_ARM_3DOF
    drawing = ArmDrawing(meshcat, arm, "/test/received", rgba=PLANNING_RGBA, wireframe=True)
    for link in (arm.base,) + arm.links:
        vertices, faces, wireframe = meshcat.meshes[f"/test/received/{link.name}/visual"]
        expected_vertices, expected_faces = capsule_mesh(link.radius_m, link.length_m)
        np.testing.assert_array_equal(vertices, expected_vertices)
        np.testing.assert_array_equal(faces, expected_faces)
        assert wireframe
        np.testing.assert_array_equal(
            meshcat.transforms[f"/test/received/{link.name}/visual"].GetAsMatrix4(),
            link_visual_pose(link).GetAsMatrix4())
    q = np.array([0.3, -1.1, 0.7])
    drawing.draw(q)
    # The planar arm by hand: each link frame at the end of the previous segment, turned by
    # the sum of the joint angles so far about z.
    origin, angle = np.zeros(3), 0.0
    for link, qi in zip(arm.links, q):
        angle += qi
        expected = RigidTransform(RollPitchYaw(0.0, 0.0, angle), origin)
        np.testing.assert_allclose(meshcat.transforms[f"/test/received/{link.name}"]
                                   .GetAsMatrix4(), expected.GetAsMatrix4(), rtol=0,
                                   atol=1e-14)
        origin = origin + link.length_m * np.array([math.cos(angle), math.sin(angle), 0.0])
    np.testing.assert_array_equal(meshcat.transforms["/test/received/base"].GetAsMatrix4(),
                                  np.eye(4))
    calls = meshcat.calls
    drawing.draw([0.3, math.nan, 0.7])          # nothing for a non-finite q
    assert meshcat.calls == calls


def test_arm_drawing_solid_draws_drake_capsules_of_the_links_size():
    # Catches: a solid drawing with the wire-frame's mesh, or capsules of another size.
    meshcat = RecordingMeshcat()
    ArmDrawing(meshcat, SPACE_ARM_6DOF, "/test/planning", rgba=PLANNING_RGBA)
    assert not meshcat.meshes
    for link in (SPACE_ARM_6DOF.base,) + SPACE_ARM_6DOF.links:
        shape = meshcat.objects[f"/test/planning/{link.name}/visual"]
        assert (shape.radius(), shape.length()) == (link.radius_m, link.length_m)


def test_the_sdf_pose_text_parser_reads_what_rod_pose_writes():
    # Catches: a parser helper that misreads the text (the SDF comparisons above would then
    # compare nothing meaningful). By hand: link2 of the 6-DOF arm lies along +x (0.5 m).
    text = _rod_pose(SPACE_ARM_6DOF.links[1])
    assert re.fullmatch(r"0\.25 0 0 0 1\.57079632679 0", text)
    pose = pose_from_sdf_text(text)
    np.testing.assert_allclose(pose.rotation().matrix()[:, 2], [1.0, 0.0, 0.0], atol=1e-11)


# --- OperatorDisplay: the sent commands' finite differences --------------------------------


class QuietMeshcat(RecordingMeshcat):
    """RecordingMeshcat that also takes the display's other calls (camera, lines, buttons)."""

    def __getattr__(self, name):
        return lambda *args, **kwargs: None


def test_the_displayed_fd_ratios_count_every_packet_a_hold_repeats_and_restart_after_a_gap():
    # Catches: packets recorded only when q_sent changes (a hold's repeated packets dropped,
    # so the differences span unequal times and a finished motion still shows its
    # acceleration), a packet counted once per display frame instead of once, differences
    # taken across a missed sequence number.
    from telesmooth.systems.operator_display import OperatorDisplay

    period, a_max, j_max = 0.25, np.array([2.0, 1.0, 1.0]), np.array([4.0, 1.0, 1.0])
    display = OperatorDisplay(QuietMeshcat(), AIR_BEARING_ARM_3DOF,
                              pose_names=("x_m", "y_m", "phi_rad"), period_s=0.04,
                              uplink_period_s=period, max_acceleration=a_max,
                              max_jerk=j_max, residual_warning_m=1e-4,
                              distance_horizon_m=0.15)
    context = display.CreateDefaultContext()

    def send(sequence, q0, frames=3):
        display.get_input("q_sent").FixValue(context, [q0, 0.0, 0.0])
        display.get_input("sent_sequence").FixValue(context, [float(sequence)])
        for _ in range(frames):                   # the display sees each packet many times
            display.ForcedPublish(context)
        status = display.status(context)
        return status.acceleration_ratio[0], status.jerk_ratio[0]

    # Joint 0 at 0, 0.01, 0.03, 0.06: second differences 0.01, third 0 (by hand).
    for k, q0 in enumerate((0.0, 0.01, 0.03)):
        send(k, q0)
    acc, jerk = send(3, 0.06)
    assert display.status(context).distance_horizon_m == 0.15    # for "≥ 150 mm clear"
    assert acc == pytest.approx(0.01 / period**2 / 2.0, rel=1e-12)
    assert jerk == pytest.approx(0.0, abs=1e-9)
    # Held at 0.06: every 4 packets later all differences over the last packets still
    # include the stop at 0.06 (0.06 − 2·0.06 + 0.03 = −0.03 is the largest second one).
    acc, jerk = send(4, 0.06)
    assert acc == pytest.approx(0.03 / period**2 / 2.0, rel=1e-12)
    # A gap (sequence 6 missing): the history starts afresh, nothing to difference yet.
    acc, jerk = send(7, 0.5)
    assert (acc, jerk) == (0.0, 0.0)
    acc, jerk = send(8, 0.5)
    assert (acc, jerk) == (0.0, 0.0)
    acc, jerk = send(9, 0.5)
    assert (acc, jerk) == (0.0, 0.0)


def test_the_page_says_which_drawing_is_which():
    """The legend rows are on the page (Meshcat knows a button by each name: counting its
    clicks would raise otherwise), each short enough for the control panel."""
    from pydrake.geometry import Meshcat, MeshcatParams

    from telesmooth.systems.operator_display import LEGEND, OperatorDisplay

    meshcat = Meshcat(MeshcatParams(host="127.0.0.1"))
    OperatorDisplay(meshcat, AIR_BEARING_ARM_3DOF, pose_names=("x_m", "y_m", "phi_rad"),
                    period_s=0.04, uplink_period_s=0.25, max_acceleration=np.ones(3),
                    max_jerk=np.ones(3), residual_warning_m=1e-4)
    assert len(LEGEND) == 2 and all(len(row) <= 40 for row in LEGEND)
    assert [meshcat.GetButtonClicks(row) for row in LEGEND] == [0, 0]
