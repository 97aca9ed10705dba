"""Tests for telesmooth.arms.planar: planar FK, 3R IK and the arm record."""

import math

import numpy as np
import pytest

from telesmooth.arms.planar import (
    AIR_BEARING_ARM,
    AIR_BEARING_LINK_LENGTHS_M,
    PlanarArm,
    planar_3r_inverse_kinematics,
    planar_3r_inverse_kinematics_point,
    planar_end_effector_angle,
    planar_forward_kinematics,
    planar_pose_point,
)

LENGTHS = AIR_BEARING_LINK_LENGTHS_M  # (0.5, 0.4, 0.2) m


def _angle_difference(a, b):
    """a - b wrapped into [-pi, pi), rad."""
    return np.mod(np.asarray(a) - np.asarray(b) + np.pi, 2.0 * np.pi) - np.pi


def _random_reachable_targets(rng, num, elbow):
    """Targets (xy, phi) built from random in-limit configurations of one branch."""
    q = rng.uniform(np.radians(-165.0), np.radians(165.0), size=(num, 3))
    # Keep the elbow on the requested branch and away from q2 = 0 / pi so the
    # branch is unambiguous; the IK must then recover this configuration.
    q[:, 1] = elbow * rng.uniform(0.05, np.pi - 0.2, size=num)
    xy = planar_forward_kinematics(q, LENGTHS)
    phi = planar_end_effector_angle(q)
    return q, xy, phi


# --- constants ---


def test_air_bearing_arm_constants():
    dut = AIR_BEARING_ARM
    assert dut.link_lengths_m == (0.5, 0.4, 0.2)
    assert dut.joint_names == ("shoulder", "elbow", "wrist")
    assert dut.num_joints == 3
    assert dut.reach_m == pytest.approx(1.1, abs=1e-15)
    np.testing.assert_allclose(dut.joint_lower_rad, [math.radians(-170.0)] * 3, rtol=0, atol=0)
    np.testing.assert_allclose(dut.joint_upper_rad, [math.radians(170.0)] * 3, rtol=0, atol=0)


# --- forward kinematics ---


@pytest.mark.parametrize(
    "q, expected_xy",
    [
        ((0.0, 0.0, 0.0), (1.1, 0.0)),
        ((math.pi / 2, 0.0, 0.0), (0.0, 1.1)),
        ((0.0, math.pi / 2, 0.0), (0.5, 0.6)),
        ((0.0, math.pi / 2, -math.pi / 2), (0.7, 0.4)),
        ((math.pi, 0.0, 0.0), (-1.1, 0.0)),
        ((0.0, math.pi, 0.0), (-0.1, 0.0)),
        ((math.pi / 2, -math.pi / 2, math.pi / 2), (0.4, 0.7)),
    ],
)
def test_forward_kinematics_hand_computed(q, expected_xy):
    dut = planar_forward_kinematics(np.array(q), LENGTHS)
    assert dut.shape == (2,)
    np.testing.assert_allclose(dut, expected_xy, rtol=0, atol=1e-15)


def test_forward_kinematics_any_number_of_joints_and_leading_dims():
    # One link: a circle of radius l.
    np.testing.assert_allclose(
        planar_forward_kinematics(np.array([[math.pi / 6]]), [2.0]),
        [[2.0 * math.cos(math.pi / 6), 2.0 * math.sin(math.pi / 6)]],
        rtol=0,
        atol=1e-15,
    )
    # Five links, leading dims (4, 3): compare with an explicit loop.
    rng = np.random.default_rng(1)
    lengths = rng.uniform(0.1, 1.0, size=5)
    q = rng.uniform(-np.pi, np.pi, size=(4, 3, 5))
    dut = planar_forward_kinematics(q, lengths)
    assert dut.shape == (4, 3, 2)
    expected = np.zeros((4, 3, 2))
    for index in np.ndindex(4, 3):
        theta = 0.0
        for joint in range(5):
            theta += q[index][joint]
            expected[index] += lengths[joint] * np.array([math.cos(theta), math.sin(theta)])
    np.testing.assert_allclose(dut, expected, rtol=0, atol=1e-14)


def test_forward_kinematics_rejects_mismatched_q():
    with pytest.raises(ValueError, match=r"shape \(\.\.\., 3\)"):
        planar_forward_kinematics(np.zeros(2), LENGTHS)
    with pytest.raises(ValueError, match="link_lengths_m"):
        planar_forward_kinematics(np.zeros(0), [])


def test_end_effector_angle_is_sum_of_joint_angles():
    q = np.array([[0.1, 0.2, 0.3], [3.0, 3.0, 3.0]])
    np.testing.assert_allclose(planar_end_effector_angle(q), [0.6, 9.0], rtol=0, atol=1e-15)


# --- inverse kinematics ---


@pytest.mark.parametrize("elbow", [+1, -1])
def test_inverse_kinematics_round_trip_random(elbow):
    rng = np.random.default_rng(20240611 + elbow)
    q_true, xy, phi = _random_reachable_targets(rng, 5000, elbow)
    in_limits = np.all(np.abs(q_true) <= np.radians(170.0), axis=-1)

    q, reachable = planar_3r_inverse_kinematics(xy, phi, AIR_BEARING_ARM, elbow=elbow)

    assert q.shape == (5000, 3) and reachable.shape == (5000,)
    assert np.all(np.isfinite(q))
    # The generated q lies in the limits on this branch, so every target is reachable.
    assert np.all(reachable[in_limits])
    assert in_limits.sum() > 4000
    np.testing.assert_allclose(planar_forward_kinematics(q, LENGTHS), xy, rtol=0, atol=1e-12)
    np.testing.assert_allclose(
        _angle_difference(planar_end_effector_angle(q), phi), 0.0, rtol=0, atol=1e-12
    )
    assert np.all(elbow * q[:, 1] >= 0.0)
    # Same branch, same limits: the IK recovers the generating configuration.
    np.testing.assert_allclose(_angle_difference(q, q_true)[in_limits], 0.0, rtol=0, atol=1e-8)


def test_inverse_kinematics_both_branches_reach_same_pose():
    rng = np.random.default_rng(7)
    _, xy, phi = _random_reachable_targets(rng, 200, +1)
    q_up, ok_up = planar_3r_inverse_kinematics(xy, phi, AIR_BEARING_ARM, elbow=+1)
    q_down, ok_down = planar_3r_inverse_kinematics(xy, phi, AIR_BEARING_ARM, elbow=-1)
    both = ok_up & ok_down
    assert both.sum() > 100
    np.testing.assert_allclose(q_up[both, 1], -q_down[both, 1], rtol=0, atol=1e-12)
    for q in (q_up[both], q_down[both]):
        np.testing.assert_allclose(
            planar_forward_kinematics(q, LENGTHS), xy[both], rtol=0, atol=1e-12
        )


def test_inverse_kinematics_broadcasts_leading_dims_and_scalar_phi():
    rng = np.random.default_rng(3)
    xy = np.array([0.7, 0.1]) + rng.uniform(-0.2, 0.2, size=(4, 5, 2))
    q, reachable = planar_3r_inverse_kinematics(xy, 0.3, AIR_BEARING_ARM)
    assert q.shape == (4, 5, 3) and reachable.shape == (4, 5)
    assert np.all(reachable)
    np.testing.assert_allclose(planar_forward_kinematics(q, LENGTHS), xy, rtol=0, atol=1e-12)
    np.testing.assert_allclose(planar_end_effector_angle(q), 0.3, rtol=0, atol=1e-12)


def test_inverse_kinematics_stretched_boundary_is_reachable():
    # Fully stretched along +x with phi = 0: q = 0 exactly on the outer boundary.
    q, reachable = planar_3r_inverse_kinematics(np.array([1.1, 0.0]), 0.0, AIR_BEARING_ARM)
    assert bool(reachable)
    np.testing.assert_allclose(q, [0.0, 0.0, 0.0], rtol=0, atol=1e-7)


@pytest.mark.parametrize("elbow", [+1, -1])
def test_inverse_kinematics_flags_points_outside_annulus(elbow):
    # Wrist point = xy - 0.2 [cos phi, sin phi]; 2R annulus is 0.1 <= r <= 0.9 m.
    xy = np.array(
        [
            [1.2, 0.0],  # wrist r = 1.0 > 0.9: too far
            [0.0, 1.5],  # phi = 0: wrist (-0.2, 1.5), r > 0.9
            [0.25, 0.0],  # wrist r = 0.05 < 0.1: too close
            [0.2, 0.0],  # wrist at the base
            [0.9, 0.0],  # wrist r = 0.7: reachable
        ]
    )
    q, reachable = planar_3r_inverse_kinematics(xy, 0.0, AIR_BEARING_ARM, elbow=elbow)
    np.testing.assert_array_equal(reachable, [False, False, False, False, True])
    assert np.all(np.isfinite(q))
    # Documented fallback: stretched (q2 = 0) when too far, folded (|q2| = pi) when too close.
    np.testing.assert_allclose(q[:2, 1], 0.0, rtol=0, atol=1e-15)
    np.testing.assert_allclose(np.abs(q[2:4, 1]), np.pi, rtol=0, atol=1e-15)
    # ... and the orientation is still realised.
    np.testing.assert_allclose(
        _angle_difference(planar_end_effector_angle(q), 0.0), 0.0, rtol=0, atol=1e-12
    )


def test_inverse_kinematics_flags_joint_limit_violation():
    # q = (0, 175 deg, 0) is in the workspace but beyond the elbow's 170 deg limit.
    q_target = np.array([0.0, math.radians(175.0), -math.radians(175.0)])
    xy = planar_forward_kinematics(q_target, LENGTHS)
    phi = planar_end_effector_angle(q_target)
    q, reachable = planar_3r_inverse_kinematics(xy, phi, AIR_BEARING_ARM, elbow=+1)
    assert not bool(reachable)
    # Documented: the exact (unclamped) solution is returned.
    np.testing.assert_allclose(q, q_target, rtol=0, atol=1e-12)

    # Wrist-only violation: the same point with a wider elbow limit but a
    # narrow wrist limit.
    narrow_wrist = PlanarArm(
        link_lengths_m=LENGTHS,
        joint_names=("shoulder", "elbow", "wrist"),
        joint_lower_rad=(-3.0, -3.1, -1.0),
        joint_upper_rad=(3.0, 3.1, 1.0),
    )
    q_target = np.array([0.2, 1.0, 1.5])
    _, reachable = planar_3r_inverse_kinematics(
        planar_forward_kinematics(q_target, LENGTHS), q_target.sum(), narrow_wrist, elbow=+1
    )
    assert not bool(reachable)


def test_inverse_kinematics_uses_in_limit_representative():
    # A wrist joint allowed in [0, 2 pi): an IK angle of -90 deg is returned as 270 deg.
    arm = PlanarArm(
        link_lengths_m=LENGTHS,
        joint_names=("shoulder", "elbow", "wrist"),
        joint_lower_rad=(-3.0, -3.0, 0.0),
        joint_upper_rad=(3.0, 3.0, 2.0 * np.pi - 0.01),
    )
    q_target = np.array([0.3, 0.5, -np.pi / 2])
    q, reachable = planar_3r_inverse_kinematics(
        planar_forward_kinematics(q_target, LENGTHS), q_target.sum(), arm, elbow=+1
    )
    assert bool(reachable)
    np.testing.assert_allclose(q, [0.3, 0.5, 1.5 * np.pi], rtol=0, atol=1e-12)


def test_inverse_kinematics_validation():
    two_link = PlanarArm((0.5, 0.4), ("a", "b"), (-1.0, -1.0), (1.0, 1.0))
    with pytest.raises(ValueError, match="arm.num_joints = 2"):
        planar_3r_inverse_kinematics(np.zeros(2), 0.0, two_link)
    with pytest.raises(ValueError, match="elbow = 0"):
        planar_3r_inverse_kinematics(np.zeros(2), 0.0, AIR_BEARING_ARM, elbow=0)
    with pytest.raises(ValueError, match=r"xy has shape \(3,\)"):
        planar_3r_inverse_kinematics(np.zeros(3), 0.0, AIR_BEARING_ARM)
    with pytest.raises(ValueError, match="xy contains non-finite"):
        planar_3r_inverse_kinematics(np.array([np.nan, 0.0]), 0.0, AIR_BEARING_ARM)
    with pytest.raises(ValueError, match="phi_rad = inf"):
        planar_3r_inverse_kinematics(np.array([0.7, 0.0]), np.inf, AIR_BEARING_ARM)


# --- PlanarArm validation ---


def _arm(**overrides):
    fields = dict(
        link_lengths_m=(0.5, 0.4, 0.2),
        joint_names=("shoulder", "elbow", "wrist"),
        joint_lower_rad=(-1.0, -1.0, -1.0),
        joint_upper_rad=(1.0, 1.0, 1.0),
    )
    fields.update(overrides)
    return PlanarArm(**fields)


@pytest.mark.parametrize(
    "overrides, message",
    [
        (
            {"link_lengths_m": (0.5, -0.4, 0.2)},
            r"link_lengths_m\[1\] = -0.4 for joint 1 \('elbow'\) must be positive",
        ),
        (
            {"link_lengths_m": (0.5, 0.4, 0.0)},
            r"link_lengths_m\[2\] = 0.0 for joint 2 \('wrist'\) must be positive",
        ),
        (
            {"link_lengths_m": (math.inf, 0.4, 0.2)},
            r"link_lengths_m\[0\] = inf for joint 0 \('shoulder'\) must be positive",
        ),
        (
            {"link_lengths_m": (0.5, math.nan, 0.2)},
            r"link_lengths_m\[1\] = nan for joint 1 \('elbow'\) must be positive",
        ),
        (
            {"joint_lower_rad": (-1.0, 1.5, -1.0)},
            r"joint_lower_rad\[1\] = 1.5 for joint 1 \('elbow'\) "
            r"must be below joint_upper_rad\[1\] = 1.0",
        ),
        (
            {"joint_upper_rad": (1.0, 1.0, -1.0)},
            r"joint_lower_rad\[2\] = -1.0 for joint 2 \('wrist'\) must be below",
        ),
        ({"joint_lower_rad": (math.nan, -1.0, -1.0)},
         r"joint_lower_rad\[0\] = nan for joint 0 \('shoulder'\) must be finite or -inf"),
        ({"joint_upper_rad": (1.0, -math.inf, 1.0)},
         r"joint_upper_rad\[1\] = -inf for joint 1 \('elbow'\) must be finite or \+inf"),
        ({"joint_names": ("shoulder", "elbow")}, "joint_names = .* has 2 entries"),
        ({"joint_lower_rad": (-1.0,) * 4}, "joint_lower_rad = .* has 4 entries"),
        ({"joint_names": ("a", "b", "a")}, r"joint_names\[2\] = 'a' repeats"),
        ({"joint_names": ("a", "", "c")}, r"joint_names\[1\] = ''"),
        (
            dict(link_lengths_m=(), joint_names=(), joint_lower_rad=(), joint_upper_rad=()),
            "at least one link",
        ),
    ],
)
def test_planar_arm_validation_messages(overrides, message):
    with pytest.raises(ValueError, match=message):
        _arm(**overrides)


def test_planar_arm_normalises_to_tuples_and_allows_infinite_limits():
    dut = _arm(
        link_lengths_m=np.array([0.5, 0.4, 0.2]),
        joint_lower_rad=[-math.inf, -1.0, -1.0],
        joint_upper_rad=[math.inf, 1.0, 1.0],
    )
    assert dut.link_lengths_m == (0.5, 0.4, 0.2)
    assert isinstance(dut.joint_lower_rad, tuple)
    same = _arm(joint_lower_rad=(-math.inf, -1.0, -1.0), joint_upper_rad=(math.inf, 1.0, 1.0))
    assert dut == same and hash(dut) == hash(same)
    with pytest.raises(AttributeError):
        dut.link_lengths_m = (1.0, 1.0, 1.0)


# --- one target at a time (the 100 Hz ground-station path) ---


@pytest.mark.parametrize("elbow", [1, -1])
@pytest.mark.parametrize("arm", [
    AIR_BEARING_ARM,
    PlanarArm(link_lengths_m=(0.3, 0.7, 0.1), joint_names=("a", "b", "c"),
              joint_lower_rad=(-1.0, -math.inf, -2.0), joint_upper_rad=(1.5, math.inf, 0.5)),
])
def test_point_inverse_kinematics_equals_the_vectorised_one(elbow, arm):
    """Oracle: the vectorised function, on targets reachable, outside the annulus (both
    sides), on its boundary and violating limits; joint angles to 1e-12 rad (numpy's and
    libm's trigonometric functions may round differently), the flag exactly."""
    rng = np.random.default_rng(11)
    reach = sum(arm.link_lengths_m)
    targets = [(float(x), float(y), float(phi)) for x, y, phi in zip(
        rng.uniform(-1.2 * reach, 1.2 * reach, 400), rng.uniform(-1.2 * reach, 1.2 * reach, 400),
        rng.uniform(-7.0, 7.0, 400))]
    targets += [(reach, 0.0, 0.0), (0.0, 0.0, 0.0), (-0.1, 0.05, 3.0)]
    flags = set()
    for x, y, phi in targets:
        q_vector, reachable_vector = planar_3r_inverse_kinematics(
            np.array([x, y]), phi, arm, elbow=elbow)
        q_point, reachable_point = planar_3r_inverse_kinematics_point(x, y, phi, arm,
                                                                      elbow=elbow)
        assert reachable_point == bool(reachable_vector)
        np.testing.assert_allclose(q_point, q_vector, rtol=0, atol=1e-12)
        flags.add(reachable_point)
    assert flags == {True, False}          # both cases were exercised


def test_point_inverse_kinematics_validation():
    with pytest.raises(ValueError, match=r"must be finite"):
        planar_3r_inverse_kinematics_point(0.5, math.nan, 0.0, AIR_BEARING_ARM)
    with pytest.raises(ValueError, match=r"elbow = 0 must be"):
        planar_3r_inverse_kinematics_point(0.5, 0.1, 0.0, AIR_BEARING_ARM, elbow=0)
    two_link = PlanarArm(link_lengths_m=(1.0, 1.0), joint_names=("a", "b"),
                         joint_lower_rad=(-1.0, -1.0), joint_upper_rad=(1.0, 1.0))
    with pytest.raises(ValueError, match=r"needs exactly 3 joints"):
        planar_3r_inverse_kinematics_point(0.5, 0.1, 0.0, two_link)


def test_pose_point_is_forward_kinematics_and_angle():
    rng = np.random.default_rng(2)
    for q in rng.uniform(-3.0, 3.0, (100, 3)):
        x, y, phi = planar_pose_point(q, LENGTHS)
        np.testing.assert_allclose([x, y], planar_forward_kinematics(q, LENGTHS),
                                   rtol=0, atol=1e-14)
        assert phi == planar_end_effector_angle(q)
    with pytest.raises(ValueError):
        planar_pose_point([0.1, 0.2], LENGTHS)     # one angle per link
