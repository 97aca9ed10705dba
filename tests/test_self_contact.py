"""The self-contact certificate and the playback that runs without collision geometry.

Oracles: exact signed distances from Drake's SceneGraph (an independent query at every
configuration), the link lengths and radii of the arm descriptions (the bounds R_J by hand),
and the run of the plant with its geometry (a certified run must be the same to the bit; a
run with contact must differ, and then the geometry's run is the one returned).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from pydrake.geometry import Box, Capsule, Cylinder, Ellipsoid, HalfSpace, Sphere
from pydrake.systems.framework import DiagramBuilder

from telesmooth.arms.description import AIR_BEARING_ARM_3DOF, SPACE_ARM_6DOF
from telesmooth.arms.self_contact import (
    CLEARANCE_M,
    _bounding_radius,
    self_contact_certificate,
)
from telesmooth.diagrams.offline_playback import AddPathPlayback, play_path, simulate_playback
from telesmooth.diagrams.scenario import LoadScenario
from telesmooth.systems.flexible_arm import FlexibleArmConfig, FlexibleJointArm

PLANAR = AIR_BEARING_ARM_3DOF


def _positions(certificate, q_link, deflection=None):
    """Plant positions (motor, deflection per joint) for link angles ``q_link``."""
    q_link = np.asarray(q_link, dtype=float)
    deflection = np.zeros_like(q_link) if deflection is None else np.asarray(deflection)
    q = np.empty(certificate.num_positions)
    q[0::2] = q_link - deflection
    q[1::2] = deflection
    return q


def test_the_bounds_are_the_link_lengths_of_the_planar_arm():
    certificate = self_contact_certificate(PLANAR)
    link1, link2, link3 = (link.length_m for link in PLANAR.links)
    r2, r3 = PLANAR.links[1].radius_m, PLANAR.links[2].radius_m
    expected = {
        ("base", "link2"): {"shoulder": link1 + link2 + r2, "elbow": link2 + r2},
        ("base", "link3"): {"shoulder": link1 + link2 + link3 + r3,
                            "elbow": link2 + link3 + r3, "wrist": link3 + r3},
        ("link1", "link3"): {"elbow": link2 + link3 + r3, "wrist": link3 + r3},
    }
    radii = certificate.radii()
    assert len(radii) == 3
    for (name_a, name_b), joints in radii.items():
        key = (name_a.split("::")[1].removesuffix("_collision"),
               name_b.split("::")[1].removesuffix("_collision"))
        want = expected[key]
        # Motor and deflection joint share their axis: the same bound for both.
        assert set(joints) == {f"{j}_{part}" for j in want for part in ("motor", "deflection")}
        for joint, radius in joints.items():
            assert radius == pytest.approx(want[joint.rsplit("_", 1)[0]], abs=1e-12)


@pytest.mark.parametrize("arm", [PLANAR, SPACE_ARM_6DOF], ids=lambda arm: arm.name)
def test_a_distance_moves_no_more_than_the_bound(arm):
    # |d(q') − d(q)| ≤ Σ_J R_J |q'_J − q_J| for every pair, from exact distances.
    certificate = self_contact_certificate(arm)
    assert not certificate.reason
    rng = np.random.default_rng(3)
    radii = [np.array(list(joints.values())) for joints in certificate.radii().values()]
    pairs = certificate._pairs
    slack = []
    for _ in range(300):
        q = rng.uniform(-3.0, 3.0, certificate.num_positions)
        step = rng.normal(scale=rng.choice([0.01, 0.1, 0.5]), size=q.size)
        d0, d1 = certificate.distances(q), certificate.distances(q + step)
        moved = np.abs(step[certificate._position_index])
        for p, pair in enumerate(pairs):
            slack.append(moved[pair.joints] @ radii[p] - abs(d1[p] - d0[p]))
    assert min(slack) >= -1e-9


def test_a_run_at_rest_far_from_contact_is_certified_below_its_true_distance():
    certificate = self_contact_certificate(PLANAR)
    q = _positions(certificate, [0.3, 0.4, -0.2])
    true = certificate.distances(q).min()
    check = certificate.check(np.tile(q, (300, 1)), np.zeros((300, 6)), 0.01)
    assert check.certified
    assert CLEARANCE_M < check.min_clearance_m <= true


def test_a_folded_pose_is_not_certified():
    certificate = self_contact_certificate(PLANAR)
    q = _positions(certificate, [0.0, 2.6, 1.9])
    assert certificate.distances(q).min() < 0.0     # link3 lies across link1
    check = certificate.check(np.tile(q, (30, 1)), np.zeros((30, 6)), 0.01)
    assert not check.certified and check.min_clearance_m < 0.0
    assert check.pair == ("air_bearing_arm::link1_collision", "air_bearing_arm::link3_collision")


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_run_bound_is_below_every_distance_between_the_samples(seed):
    # A smooth motion with a 14 Hz deflection, sampled every 10 ms (positions and exact
    # velocities); the exact distances on a 1 ms grid must all lie above the run's bound.
    certificate = self_contact_certificate(PLANAR)
    rng = np.random.default_rng(seed)
    amplitude = rng.uniform(0.3, 0.9, 3)
    phase = rng.uniform(0, 2 * math.pi, 3)
    centre = np.array([0.0, 1.6, 1.0]) + rng.uniform(-0.2, 0.2, 3)

    def state(t):
        t = np.asarray(t)[:, None]
        link = centre + amplitude * np.sin(0.8 * t + phase)
        link_rate = 0.8 * amplitude * np.cos(0.8 * t + phase)
        bend = 0.01 * np.sin(2 * math.pi * 14.0 * t + phase)
        bend_rate = 0.01 * 2 * math.pi * 14.0 * np.cos(2 * math.pi * 14.0 * t + phase)
        q = np.empty((t.shape[0], 6))
        v = np.empty_like(q)
        q[:, 0::2], q[:, 1::2] = link - bend, bend
        v[:, 0::2], v[:, 1::2] = link_rate - bend_rate, bend_rate
        return q, v

    q, v = state(np.arange(0.0, 8.0, 0.01))
    check = certificate.check(q, v, 0.01)
    fine, _ = state(np.arange(0.0, 8.0 + 0.01, 0.001))
    truth = min(certificate.distances(row).min() for row in fine)
    assert check.min_clearance_m <= truth


@pytest.mark.parametrize("shape, radius", [
    (Sphere(0.2), 0.2), (Capsule(0.1, 0.6), 0.4), (Cylinder(0.3, 0.8), 0.5),
    (Box(0.2, 0.3, 0.6), 0.35), (Ellipsoid(0.1, 0.4, 0.2), 0.4)])
def test_bounding_radii_are_the_closed_forms(shape, radius):
    assert _bounding_radius(shape, "g") == pytest.approx(radius, rel=1e-12)


def test_an_unbounded_shape_is_refused_with_its_name():
    with pytest.raises(ValueError, match="'floor' is a HalfSpace"):
        _bounding_radius(HalfSpace(), "floor")


def test_a_plant_without_geometry_needs_the_continuous_plant():
    with pytest.raises(ValueError, match="contact_geometry=False needs the continuous plant"):
        FlexibleJointArm(FlexibleArmConfig(time_step_s=0.001), contact_geometry=False)
    arm = FlexibleJointArm(FlexibleArmConfig(), contact_geometry=False)
    assert arm.scene_graph is None and not arm.HasOutputPort("query_object")
    assert arm.plant.num_positions() == 6


# -- playback ------------------------------------------------------------------------------

def _geometry_run(scenario, packets, q_start, duration):
    builder = DiagramBuilder()
    _, _, robot, loggers = AddPathPlayback(builder, scenario, packets, q_start=q_start)
    return simulate_playback(builder.Build(), robot, loggers, duration)[1]


def _same(logs, other):
    assert logs.keys() == other.keys()
    for name in logs:
        for field, value in vars(logs[name]).items():
            np.testing.assert_array_equal(value, getattr(other[name], field), err_msg=name)


def test_a_certified_playback_is_the_run_with_geometry_to_the_bit():
    scenario = LoadScenario(scenario_text="{}")
    q_start = np.array([0.2, 0.5, -0.3])
    packets = q_start + np.outer(np.minimum(np.arange(16), 8) / 8.0, [0.3, -0.2, 0.4])
    logs, check = play_path(scenario, packets, q_start=q_start, duration_s=5.0)
    assert check.certified and check.min_clearance_m > 0.1
    _same(logs, _geometry_run(scenario, packets, q_start, 5.0))


def test_a_playback_into_self_contact_is_run_again_with_geometry():
    scenario = LoadScenario(scenario_text="{}")
    certificate = self_contact_certificate(scenario.arm_description)
    q_start, folded = np.array([0.0, 2.0, 0.6]), np.array([0.0, 2.6, 1.9])
    assert certificate.distances(_positions(certificate, q_start)).min() > 0.05
    assert certificate.distances(_positions(certificate, folded)).min() < -0.05
    packets = q_start + np.outer(np.minimum(np.arange(12), 4) / 4.0, folded - q_start)
    # Link3 reaches link1 at about 1.0 s; the contact is stiff (small steps): 0.1 s of it.
    duration = 1.1
    logs, check = play_path(scenario, packets, q_start=q_start, duration_s=duration)
    assert not check.certified and check.min_clearance_m < 0.0
    with_geometry = _geometry_run(scenario, packets, q_start, duration)
    _same(logs, with_geometry)
    # Contact acted: without the geometry, link3 passes through link1.
    builder = DiagramBuilder()
    _, _, robot, loggers = AddPathPlayback(builder, scenario, packets, q_start=q_start,
                                           contact_geometry=False)
    free = simulate_playback(builder.Build(), robot, loggers, duration)[1]
    gap = np.abs(free["tracker"].q_link - with_geometry["tracker"].q_link).max()
    assert gap > 0.02


def test_a_discrete_plant_is_played_with_its_geometry_and_no_check():
    scenario = LoadScenario(scenario_text="{onboard: {time_step_s: 0.005}}")
    q_start = np.zeros(3)
    logs, check = play_path(scenario, np.tile(q_start, (4, 1)), q_start=q_start,
                            duration_s=1.0)
    assert check is None and "plant_state" not in logs


def test_samples_near_a_pair_are_refined_before_a_run_is_refused():
    # A fast shoulder sweep of the folded arm (link3 15 cm from the base): bounds from anchors
    # 0.25 s apart are not clear, closer anchors are, and the run is certified.
    certificate = self_contact_certificate(PLANAR)
    t = np.arange(0.0, 2.0, 0.01)
    q = np.zeros((t.size, 6))
    v = np.zeros_like(q)
    q[:, 0::2] = np.array([-1.5, 2.3, 1.0]) + np.outer(t, [1.0, 0.0, 0.0])
    v[:, 0] = 1.0
    truth = min(certificate.distances(row).min() for row in q)
    check = certificate.check(q, v, 0.01)
    assert check.certified and check.min_clearance_m <= truth
    assert t.size // 25 + 1 < check.exact_queries < t.size


def test_a_run_with_a_non_finite_state_is_refused():
    certificate = self_contact_certificate(PLANAR)
    q = np.zeros((10, 6))
    q[4, 2] = np.nan
    with pytest.raises(ValueError, match="must be finite"):
        certificate.check(q, np.zeros((10, 6)), 0.01)
