"""ArmCollisionModel: signed distances against hand-computed geometry and a 2-D oracle."""

import math

import numpy as np
import pytest

from telesmooth.arms.collision import ArmCollisionModel, CollisionQuery
from telesmooth.arms.description import AIR_BEARING_ARM_3DOF, SPACE_ARM_6DOF
from telesmooth.arms.planar import AIR_BEARING_ARM
from telesmooth.arms.workspace import AIR_BEARING_WORKSPACE, SPACE_ARM_WORKSPACE, Workspace
from telesmooth.datasets.lasa import lasa_operator_session
from telesmooth.systems.collision_checker import CollisionCheckerConfig

# Drake computes capsule distances with FCL's GJK/EPA, which stops at a 1e-6 threshold:
# measured errors against exact geometry reach 5e-6 m (over-estimates) for general poses and
# ~1e-13 m for axis-aligned ones. 1e-5 m is 2000 times below the 0.02 m safety margin.
ATOL_M = 1e-5
# The planar arm's geometry (arms/description.py): link lengths and capsule radii, m.
L1, L2, L3 = 0.5, 0.4, 0.2
R_BASE, R1, R2, R3 = 0.08, 0.05, 0.045, 0.04


@pytest.fixture(scope="module")
def planar_model():
    return ArmCollisionModel(AIR_BEARING_ARM_3DOF, AIR_BEARING_WORKSPACE)


@pytest.fixture(scope="module")
def space_model():
    return ArmCollisionModel(SPACE_ARM_6DOF, SPACE_ARM_WORKSPACE)


# --- hand-computed planar configurations ---


def test_planar_stretched_arm_to_the_far_wall(planar_model):
    # Stretched along +x: link3's end cap reaches 1.1 + r3; the wall's inner face is at
    # bounds_upper_x = 1.2.
    dut = planar_model.query([0.0, 0.0, 0.0])
    wall_x = AIR_BEARING_WORKSPACE.bounds_upper_m[0]
    assert dut.min_distance_m == pytest.approx(wall_x - (L1 + L2 + L3 + R3), abs=ATOL_M)
    assert (dut.body_a, dut.body_b) == ("link3", "wall_x_upper")
    assert not dut.in_collision(0.02)
    assert dut.in_collision(0.07)


def test_planar_wrist_below_the_fixture(planar_model):
    # Elbow at 90 deg, wrist back to 0 deg absolute: link3 runs along y = 0.4 from x = 0.5 to
    # 0.7, under the fixture's lower face y = 0.5 (fixture x in [0.6, 0.9]).
    dut = planar_model.query([0.0, math.pi / 2, -math.pi / 2])
    fixture = AIR_BEARING_WORKSPACE.obstacles[0]
    lower_face_y = fixture.center_m[1] - fixture.size_m[1] / 2
    assert dut.min_distance_m == pytest.approx(lower_face_y - L2 - R3, abs=ATOL_M)
    assert (dut.body_a, dut.body_b) == ("link3", "fixture")


def test_planar_shoulder_rotated_into_the_fixture(planar_model):
    # Stretched at 45 deg: link2's axis (y = x) passes exactly through the fixture's corner
    # edge (0.6, 0.6), and the whole box lies on one side of the axis, so the capsule
    # penetrates by its radius. (Link1, 0.5 m + 0.05 m, cannot reach the fixture, which is
    # 0.78 m from the shoulder; link2 is the link that enters it.)
    dut = planar_model.query([math.pi / 4, 0.0, 0.0])
    assert (dut.body_a, dut.body_b) == ("link2", "fixture")
    assert dut.min_distance_m == pytest.approx(-R2, abs=1e-6)
    assert dut.in_collision(0.0)


def _folded(sin_elbow):
    """Elbow folded past 90 deg with link3 pointing straight down (-y) towards link1.

    q2 = pi - asin(s) puts the wrist at height L2 s over link1's axis; q3 = 3 pi/2 - q2 makes
    the absolute angle of link3 3 pi/2. link3 ends L3 lower, above x in [0, L1], so the gap to
    link1 is L2 s - L3 - R1 - R3.
    """
    q2 = math.pi - math.asin(sin_elbow)
    return [0.0, q2, 1.5 * math.pi - q2], L2 * sin_elbow - L3 - R1 - R3


def test_planar_folded_elbow_just_clear_of_link1_and_margin_behaviour(planar_model):
    q, expected = _folded(0.75)
    assert expected == pytest.approx(0.01, abs=1e-15)
    dut = planar_model.query(q)
    assert (dut.body_a, dut.body_b) == ("link1", "link3")
    assert dut.min_distance_m == pytest.approx(expected, abs=ATOL_M)
    # 0.01 m away: a collision for a 0.02 m margin, not for 0.005 m or contact only.
    assert dut.in_collision(0.02)
    assert dut.in_collision(0.015)
    assert not dut.in_collision(0.005)
    assert not dut.in_collision(0.0)


def test_planar_folded_elbow_link3_hits_link1(planar_model):
    q, expected = _folded(0.6)
    assert expected == pytest.approx(-0.05, abs=1e-15)
    dut = planar_model.query(q)
    assert (dut.body_a, dut.body_b) == ("link1", "link3")
    assert dut.min_distance_m == pytest.approx(expected, abs=ATOL_M)
    assert dut.in_collision(0.0)


# --- a 2-D oracle for the planar arm ---


def _point_segment(p, a, b):
    ab = b - a
    t = np.clip(np.dot(p - a, ab) / np.dot(ab, ab), 0.0, 1.0)
    return float(np.linalg.norm(p - (a + t * ab)))


def _segments_intersect(a, b, c, d):
    def cross(o, p, q):
        return (p[0] - o[0]) * (q[1] - o[1]) - (p[1] - o[1]) * (q[0] - o[0])
    return (cross(a, b, c) * cross(a, b, d) < 0) and (cross(c, d, a) * cross(c, d, b) < 0)


def _segment_segment(a, b, c, d):
    if _segments_intersect(a, b, c, d):
        return 0.0
    return min(_point_segment(a, c, d), _point_segment(b, c, d),
               _point_segment(c, a, b), _point_segment(d, a, b))


def _segment_rectangle(a, b, lower, upper):
    def inside(p):
        return bool(np.all(p >= lower) and np.all(p <= upper))
    if inside(a) or inside(b):
        return 0.0
    corners = [np.array(c) for c in ((lower[0], lower[1]), (upper[0], lower[1]),
                                     (upper[0], upper[1]), (lower[0], upper[1]))]
    edges = [(corners[i], corners[(i + 1) % 4]) for i in range(4)]
    return min(_segment_segment(a, b, c, d) for c, d in edges)


def _planar_oracle(q):
    """Smallest 2-D clearance of the planar arm, m (0 when any pair overlaps in the plane).

    Every capsule lies in the plane z = 0 and every box spans z in [-0.1, 0.1] (more than any
    radius), and the base is a vertical capsule ending at z = 0: for separated pairs the
    closest points are in the plane, so the 3-D distance equals this 2-D one.
    """
    theta = np.cumsum(q)
    joints = [np.zeros(2)]
    for length, angle in zip((L1, L2, L3), theta):
        joints.append(joints[-1] + length * np.array([math.cos(angle), math.sin(angle)]))
    links = {"link1": (joints[0], joints[1], R1), "link2": (joints[1], joints[2], R2),
             "link3": (joints[2], joints[3], R3)}
    gaps = []
    for name in ("link2", "link3"):  # base (a disc in the plane) against non-neighbours
        a, b, r = links[name]
        gaps.append(_point_segment(np.zeros(2), a, b) - R_BASE - r)
    a, b, r = links["link1"]
    c, d, s = links["link3"]
    gaps.append(_segment_segment(a, b, c, d) - r - s)
    for box in AIR_BEARING_WORKSPACE.boxes():
        lower = np.array(box.center_m[:2]) - np.array(box.size_m[:2]) / 2
        upper = np.array(box.center_m[:2]) + np.array(box.size_m[:2]) / 2
        for a, b, r in links.values():
            distance = _segment_rectangle(a, b, lower, upper)
            gaps.append(distance - r if distance > 0.0 else -np.inf)
    return min(gaps)


def test_planar_distances_match_the_2d_oracle_on_random_configurations(planar_model):
    rng = np.random.default_rng(7)
    lower, upper = np.array(AIR_BEARING_ARM.joint_lower_rad), np.array(
        AIR_BEARING_ARM.joint_upper_rad)
    num_free = num_colliding = 0
    horizon = planar_model.distance_horizon_m
    for q in rng.uniform(lower, upper, size=(400, 3)):
        expected = _planar_oracle(q)
        dut = planar_model.query(q)
        if expected > 1e-6:
            num_free += 1
            assert dut.min_distance_m == pytest.approx(min(expected, horizon), abs=ATOL_M)
        elif expected < -1e-6:
            num_colliding += 1
            assert dut.min_distance_m < 0.0
    # Both kinds occur, so both branches above were exercised.
    assert num_free >= 40 and num_colliding >= 40


def test_lasa_angle_demo_0_is_collision_free(planar_model):
    session = lasa_operator_session("Angle", 0)
    distances = np.array([planar_model.query(q).min_distance_m for q in session.q_rad])
    k = int(np.argmin(distances))
    closest = planar_model.query(session.q_rad[k])
    # Measured 0.1720 m (link1/link3, the elbow's sharpest fold); independent 2-D oracle:
    assert distances[k] == pytest.approx(_planar_oracle(session.q_rad[k]), abs=ATOL_M)
    assert distances[k] == pytest.approx(0.1720, abs=5e-4)
    assert (closest.body_a, closest.body_b) == ("link1", "link3")
    assert distances[k] > CollisionCheckerConfig().safety_margin_m


def test_horizon_caps_the_reported_distance():
    # The arm alone: the nearest unfiltered pair (base/link2 at zeros) is 0.5 - R_BASE - R2
    # = 0.375 m away, beyond the 0.2 m horizon.
    dut = ArmCollisionModel(AIR_BEARING_ARM_3DOF, Workspace())
    assert dut.query([0.0, 0.0, 0.0]) == CollisionQuery(0.2, "", "")
    near = ArmCollisionModel(AIR_BEARING_ARM_3DOF, AIR_BEARING_WORKSPACE, distance_horizon_m=0.05)
    assert near.query([0.0, 0.0, 0.0]) == CollisionQuery(0.05, "", "")  # 0.06 m > 0.05 m


def test_checked_pairs_exclude_neighbours_and_the_welded_scene(planar_model):
    pairs = set(planar_model.candidate_pairs)
    for pair in AIR_BEARING_ARM_3DOF.filtered_pairs():
        assert pair not in pairs
    assert ("link1", "link3") in pairs and ("base", "link2") in pairs
    # Base and walls are welded to the world: never checked against each other.
    assert not any(a == "base" and b.startswith(("wall", "fixture")) for a, b in pairs)
    walls_and_boxes = [box.name for box in AIR_BEARING_WORKSPACE.boxes()]
    assert len(pairs) == 3 + 3 * len(walls_and_boxes)  # base-2, base-3, 1-3 + links x boxes


# --- the 6-DOF arm ---


def test_space_arm_at_rest_is_free(space_model):
    # Stretched along +x: link3 ends at 0.9 m, link5 starts at 0.9 + 0.12 = 1.02 m.
    dut = space_model.query(np.zeros(6))
    assert (dut.body_a, dut.body_b) == ("link3", "link5")
    assert dut.min_distance_m == pytest.approx(1.02 - 0.9 - 0.045 - 0.035, abs=ATOL_M)


def test_space_arm_yawed_next_to_the_payload(space_model):
    # Stretched at yaw 23 deg (height 0.45 m, inside the payload's z-span [0, 0.7]), the
    # payload's corner edge (0.75, 0.4) is the nearest feature, its foot on link3:
    # d = |0.4 cos(yaw) - 0.75 sin(yaw)| - r3.
    yaw = math.radians(23.0)
    dut = space_model.query([yaw, 0, 0, 0, 0, 0])
    foot = 0.75 * math.cos(yaw) + 0.4 * math.sin(yaw)
    assert 0.5 < foot < 0.9  # on link3
    assert (dut.body_a, dut.body_b) == ("link3", "payload")
    expected = 0.4 * math.cos(yaw) - 0.75 * math.sin(yaw) - 0.045
    assert dut.min_distance_m == pytest.approx(expected, abs=ATOL_M)
    assert not dut.in_collision(0.02) and dut.in_collision(0.05)


def test_space_arm_stretched_into_the_payload(space_model):
    # Yaw 45 deg: the axis y = x crosses the payload (x in [0.45, 0.75], y in [0.4, 0.7]);
    # the shallowest way out is perpendicular to the axis, past the corner (0.45, 0.7):
    # depth = (0.7 - 0.45)/sqrt(2) + r3.
    dut = space_model.query([math.pi / 4, 0, 0, 0, 0, 0])
    assert (dut.body_a, dut.body_b) == ("link3", "payload")
    assert dut.min_distance_m == pytest.approx(-(0.25 / math.sqrt(2) + 0.045), abs=1e-6)


def test_space_arm_shoulder_pitched_down_into_the_pedestal(space_model):
    # Shoulder pitch -90 deg: link2 (r 0.05) points down the pedestal's axis (base, r 0.08),
    # coaxial overlap; the way out is sideways by r2 + r_base. Coaxial capsules are the
    # degenerate case of the penetration solver, hence 1e-5.
    dut = space_model.query([0, -math.pi / 2, 0, 0, 0, 0])
    assert (dut.body_a, dut.body_b) == ("base", "link2")
    assert dut.min_distance_m == pytest.approx(-(0.05 + 0.08), abs=1e-5)


def test_space_arm_wrist_poses_clear_the_default_margin():
    """The compact wrist (link3/link5 are not filtered) must not trip the 0.02 m margin."""
    dut = ArmCollisionModel(SPACE_ARM_6DOF, SPACE_ARM_WORKSPACE)
    margin = CollisionCheckerConfig().safety_margin_m
    assert not dut.query(np.zeros(6)).in_collision(margin)
    for wrist_pitch in np.radians([-90, -45, 45, 90]):
        for wrist_yaw in np.radians([-90, 0, 90]):
            q = [0.0, 0.3, -0.6, wrist_pitch, wrist_yaw, 0.5]
            assert not dut.query(q).in_collision(margin), (wrist_pitch, wrist_yaw)


# --- validation ---


def test_query_rejects_non_finite_and_wrong_size(planar_model):
    with pytest.raises(ValueError,
                       match=r"q_rad\[1\] = nan for joint 1 \('elbow'\) must be finite"):
        planar_model.query([0.0, np.nan, 0.0])
    with pytest.raises(ValueError, match=r"q_rad\[2\] = inf for joint 2 \('wrist'\)"):
        planar_model.query([0.0, 0.0, np.inf])
    with pytest.raises(ValueError, match=r"shape \(2,\); expected \(3,\)"):
        planar_model.query([0.0, 0.0])


def test_constructor_validation():
    with pytest.raises(ValueError, match=r"distance_horizon_m = -0.1 must be positive"):
        ArmCollisionModel(AIR_BEARING_ARM_3DOF, AIR_BEARING_WORKSPACE, distance_horizon_m=-0.1)
    with pytest.raises(ValueError, match=r"distance_horizon_m = nan"):
        ArmCollisionModel(AIR_BEARING_ARM_3DOF, AIR_BEARING_WORKSPACE, distance_horizon_m=np.nan)
    with pytest.raises(ValueError, match=r"body 'link9' is neither"):
        ArmCollisionModel(AIR_BEARING_ARM_3DOF, AIR_BEARING_WORKSPACE,
                          extra_filtered_pairs=[("link1", "link9")])
    with pytest.raises(ValueError, match=r"extra_filtered_pairs\[0\] = 'link1' must be a pair"):
        ArmCollisionModel(AIR_BEARING_ARM_3DOF, AIR_BEARING_WORKSPACE,
                          extra_filtered_pairs=["link1"])
    with pytest.raises(ValueError, match=r"margin_m = nan must be finite"):
        CollisionQuery(0.1, "a", "b").in_collision(float("nan"))


def test_extra_filter_removes_the_pair():
    dut = ArmCollisionModel(AIR_BEARING_ARM_3DOF, AIR_BEARING_WORKSPACE,
                            extra_filtered_pairs=[("link1", "link3")])
    assert ("link1", "link3") not in dut.candidate_pairs
    q, _ = _folded(0.6)  # link3 inside link1: no longer reported
    assert dut.query(q).min_distance_m > 0.0
