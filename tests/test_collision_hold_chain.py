"""End to end through the built diagrams: the operator drives the pre-simulator into an obstacle.

The Defaults LASA drawing passes under a probe box we add to the table. Checked on the whole
chain (haptic source → IK → collision checker → FIFO → smoother → uplink → robot), not on a
single system:

* the pre-simulator's newest target does collide (the scene is a real test);
* during the hold every packet is exactly the packet sent before the hold (nothing queued before
  the collision reaches the robot);
* no packet, and no pose the robot's links ever take (100 Hz), comes within the safety margin;
* over LCM the hold packets carry ``MODE_HOLD`` and only those.
"""

import numpy as np
import pytest
from pydrake.lcm import DrakeLcm
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder

from telesmooth.arms.collision import ArmCollisionModel
from telesmooth.diagrams.channels import TELEOP_JOINT_COMMAND
from telesmooth.diagrams.offline import validate_joint_path
from telesmooth.diagrams.scenario import load_scenario
from telesmooth.diagrams.simulation import simulate
from telesmooth.diagrams.teleoperation import MakeGroundDiagram, MakeOnboardDiagram
from telesmooth.lcm_types import lcmt_teleop_joint_command

PROBE = """{workspace: {obstacles: [
    {name: fixture, center_m: [0.75, 0.55, 0.0], size_m: [0.3, 0.1, 0.2]},
    {name: probe, center_m: [0.68, 0.25, 0.0], size_m: [0.2, 0.06, 0.2]}],
  bounds_lower_m: [-0.4, -0.8, -0.1], bounds_upper_m: [1.2, 0.8, 0.1], planar: true}}"""
DURATION_S = 17.0


@pytest.fixture(scope="module")
def scenario():
    return load_scenario(scenario_text=PROBE)


@pytest.fixture(scope="module")
def record(scenario):
    return simulate(scenario, duration_s=DURATION_S)


def _hold_ticks(record):
    ticks = np.flatnonzero(record.holding > 0.5)
    assert ticks.size >= 3, "the probe must stop the operator for a while"
    # One contiguous hold in this scene.
    np.testing.assert_array_equal(ticks, np.arange(ticks[0], ticks[-1] + 1))
    return ticks


def test_the_pre_simulator_really_collides(scenario, record):
    margin = scenario.collision_checker.safety_margin_m
    assert record.min_distance_m.min() < 0.0 < margin
    assert np.any(record.collision_detected > 0.5)


def test_hold_sends_exactly_the_packet_before_the_collision(record):
    ticks = _hold_ticks(record)
    # Logged at tick k: the tick's own values; packet k was formed at that tick.
    np.testing.assert_allclose(record.tick_t_s[ticks], 0.25 * ticks, atol=1e-9)
    before = record.q_sent[ticks[0] - 1]
    for k in ticks:
        np.testing.assert_array_equal(record.q_sent[k], before, err_msg=f"packet {k}")
    # ... and the packets before the hold were moving (so holding is a real stop).
    assert np.abs(record.q_sent[ticks[0] - 1] - record.q_sent[ticks[0] - 5]).max() > 1e-3


def test_nothing_unsafe_reaches_the_robot(scenario, record):
    margin = scenario.collision_checker.safety_margin_m
    violations = validate_joint_path(record.q_sent, record.packet_t_s, scenario,
                                     start_position=record.q_sent[0], check_fd_limits=False)
    assert violations == []
    model = ArmCollisionModel(scenario.arm_description, scenario.workspace_or_default,
                              distance_horizon_m=scenario.collision_checker.distance_horizon_m)
    # The flexible links as they really moved, every 10 ms.
    distances = [model.query(q).min_distance_m for q in record.q_link]
    assert min(distances) > margin / 2
    # The pre-simulator was inside the probe; the robot stayed clear of it by a wide margin.
    assert min(distances) - record.min_distance_m.min() > margin


def test_hold_packets_go_up_the_link_marked_hold(scenario, record):
    lcm = DrakeLcm("memq://")
    messages = []
    lcm.Subscribe(TELEOP_JOINT_COMMAND,
                  lambda data: messages.append(lcmt_teleop_joint_command.decode(data)))
    ground = MakeGroundDiagram(scenario, lcm=lcm)
    onboard = MakeOnboardDiagram(scenario, lcm=lcm)
    builder = DiagramBuilder()
    builder.AddSystem(ground.diagram)
    builder.AddSystem(onboard.diagram)
    simulator = Simulator(builder.Build())
    simulator.AdvanceTo(DURATION_S)
    lcm.HandleSubscriptions(0)
    by_seq = {m.seq: m for m in messages if m.seq >= 0}
    ticks = set(_hold_ticks(record).tolist())
    assert ticks <= set(by_seq)
    for seq, message in by_seq.items():
        expected = (lcmt_teleop_joint_command.MODE_HOLD if seq in ticks
                    else lcmt_teleop_joint_command.MODE_TRACK)
        assert message.mode == expected, f"packet {seq}"
        if seq < record.q_sent.shape[0]:
            np.testing.assert_array_equal(message.joint_position_smoothed, record.q_sent[seq])
