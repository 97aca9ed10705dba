"""Ground-side link status from the onboard telemetry (LinkMonitor, link_status)."""

import numpy as np
import pytest
from process_fixtures import worker_port

from telesmooth.lcm_types import lcmt_onboard_joint_status
from telesmooth.systems.link_monitor import (
    LINK_STATUSES,
    ONBOARD_COUNTS,
    LinkMonitor,
    LinkMonitorConfig,
    link_status,
)

CONFIG = LinkMonitorConfig(poll_period_s=0.05, telemetry_timeout_s=1.0, max_unacknowledged=4)


@pytest.mark.parametrize("age, unacked, mode, rejected, expected", [
    (None, 0, 0, False, "no-telemetry"),
    (0.1, 0, 0, False, "ok"),
    (0.1, 4, 0, False, "ok"),
    (0.1, 5, 0, False, "degraded"),
    (0.1, 0, 1, False, "degraded"),
    (0.1, 0, 0, True, "degraded"),
    (1.01, 0, 0, False, "lost"),
    (1.01, 9, 2, True, "lost"),
])
def test_link_status_table(age, unacked, mode, rejected, expected):
    assert LINK_STATUSES[link_status(telemetry_age_s=age, unacknowledged=unacked,
                                     guard_mode=mode, rejected_recently=rejected,
                                     params=CONFIG.params())] == expected


def _telemetry(session, last_seq, *, mode=0, invalid=0, accepted=0):
    msg = lcmt_onboard_joint_status()
    msg.last_command_session_id, msg.last_command_seq = session, last_seq
    msg.guard_mode, msg.rejected_invalid_count, msg.accepted_count = mode, invalid, accepted
    return msg


def test_monitor_follows_the_telemetry():
    dut = LinkMonitor(CONFIG, session_id=7)
    context = dut.CreateDefaultContext()
    outputs = {name: dut.GetOutputPort(name) for name in
               ("link_status", "telemetry_age", "unacknowledged", "onboard_guard_mode",
                "onboard_counts")}

    def poll(t, msg=None, count=None, sent=-1):
        context.SetTime(t)
        if msg is not None:
            dut.GetInputPort("telemetry").FixValue(context, msg)
        if count is not None:
            dut.GetInputPort("telemetry_count").FixValue(context, [count])
        dut.GetInputPort("sequence_number").FixValue(context, [sent])
        dut.CalcForcedDiscreteVariableUpdate(context, context.get_mutable_discrete_state())
        return {name: port.Eval(context).copy() for name, port in outputs.items()}

    out = poll(0.0, _telemetry(0, -1), 0)
    assert LINK_STATUSES[int(out["link_status"][0])] == "no-telemetry"
    assert out["telemetry_age"][0] == -1.0
    out = poll(1.0, _telemetry(7, 10, accepted=11), 1, sent=12)
    assert LINK_STATUSES[int(out["link_status"][0])] == "ok"
    assert out["unacknowledged"][0] == 2
    np.testing.assert_array_equal(out["onboard_counts"], [11, 0, 0, 0, 0, 0, 0])
    assert len(ONBOARD_COUNTS) == 7 and ONBOARD_COUNTS[-1] == "session"
    # The robot's last command is from another (older) session: everything is unacknowledged.
    out = poll(1.1, _telemetry(6, 40), 2, sent=12)
    assert out["unacknowledged"][0] == 13
    assert LINK_STATUSES[int(out["link_status"][0])] == "degraded"
    # A new rejection (or a guard that is not tracking) degrades the link.
    out = poll(1.2, _telemetry(7, 12, invalid=1), 3, sent=12)
    assert LINK_STATUSES[int(out["link_status"][0])] == "degraded"
    out = poll(1.3, _telemetry(7, 12, invalid=1), 4, sent=12)
    assert LINK_STATUSES[int(out["link_status"][0])] == "ok"
    out = poll(1.4, _telemetry(7, 12, mode=1, invalid=1), 5, sent=12)
    assert LINK_STATUSES[int(out["link_status"][0])] == "degraded"
    assert out["onboard_guard_mode"][0] == 1
    # No telemetry for longer than the timeout: lost.
    out = poll(2.5, sent=16)
    assert LINK_STATUSES[int(out["link_status"][0])] == "lost"
    assert out["telemetry_age"][0] == pytest.approx(1.1)


def test_with_a_nonce_the_session_follows_the_robots_epoch_and_last_session():
    from telesmooth.link.session import next_session, session_counter, session_id

    nonce = 0x1234abcd
    dut = LinkMonitor(CONFIG, session_nonce=nonce)
    context = dut.CreateDefaultContext()

    def poll(t, msg, count, sent=-1):
        context.SetTime(t)
        dut.GetInputPort("telemetry").FixValue(context, msg)
        dut.GetInputPort("telemetry_count").FixValue(context, [count])
        dut.GetInputPort("sequence_number").FixValue(context, [sent])
        dut.CalcForcedDiscreteVariableUpdate(context, context.get_mutable_discrete_state())
        return {name: dut.GetOutputPort(name).Eval(context)[0] for name in
                ("onboard_epoch", "session_id", "stream_distance", "robot_session",
                 "unacknowledged")}

    assert poll(0.0, lcmt_onboard_joint_status(), 0)["onboard_epoch"] == 0.0
    # First telemetry: epoch 2^51 + 5, the robot last accepted counter 3 of another run.
    other = session_id(3, 99)
    msg = _telemetry(other, 20)
    msg.onboard_epoch, msg.stream_distance_rad = 2**51 + 5, 0.0123
    out = poll(0.1, msg, 1, sent=4)
    mine = next_session(other, nonce)
    assert (out["onboard_epoch"], out["session_id"]) == (2**51 + 5, mine)
    assert session_counter(mine) == 4 and mine & 0xFFFFFFFF == nonce
    assert out["stream_distance"] == 0.0123 and out["robot_session"] == other
    assert out["unacknowledged"] == 5             # none of ours accepted yet
    # The robot accepts ours: the session stays (same epoch).
    accepted = _telemetry(mine, 4)
    accepted.onboard_epoch = 2**51 + 5
    out = poll(0.2, accepted, 2, sent=5)
    assert out["session_id"] == mine and out["unacknowledged"] == 1
    # The robot restarted: a new epoch, nothing accepted there yet: counter 1.
    restarted = _telemetry(0, -1)
    restarted.onboard_epoch = 77
    out = poll(0.3, restarted, 3, sent=6)
    assert (out["onboard_epoch"], out["session_id"]) == (77, session_id(1, nonce))
    # Without a nonce (in-process) nothing follows the telemetry.
    fixed = LinkMonitor(CONFIG, session_id=9, onboard_epoch=0)
    fixed_context = fixed.CreateDefaultContext()
    fixed.GetInputPort("telemetry").FixValue(fixed_context, msg)
    fixed.GetInputPort("telemetry_count").FixValue(fixed_context, [1])
    fixed.GetInputPort("sequence_number").FixValue(fixed_context, [0])
    fixed.CalcForcedDiscreteVariableUpdate(fixed_context,
                                           fixed_context.get_mutable_discrete_state())
    assert fixed.GetOutputPort("session_id").Eval(fixed_context)[0] == 9
    assert fixed.GetOutputPort("onboard_epoch").Eval(fixed_context)[0] == 0


def test_config_errors_name_the_field():
    with pytest.raises(ValueError, match="max_unacknowledged = -1"):
        LinkMonitorConfig(max_unacknowledged=-1)
    with pytest.raises(ValueError, match="telemetry_timeout_s"):
        LinkMonitorConfig(telemetry_timeout_s=0.0)


def _status(q):
    from telesmooth.lcm_types import lcmt_onboard_joint_status

    msg = lcmt_onboard_joint_status()
    msg.num_joints = len(q)
    msg.joint_position_link = list(q)
    msg.joint_position_motor = list(q)
    msg.joint_position_commanded = list(q)
    msg.joint_velocity_link = msg.joint_velocity_motor = [0.0] * len(q)
    return msg.encode()


def test_a_restarted_ground_takes_only_valid_telemetry_as_the_robot_pose():
    """processes.robot_commanded_pose: garbage, another type, NaN, a wrong joint count and a
    pose beyond the joint limits on ONBOARD_JOINT_STATUS are skipped; the valid pose is taken;
    with no valid telemetry it gives None (the ground then starts from the scenario)."""
    import threading
    import time

    import lcm

    from telesmooth.diagrams.scenario import LoadScenario
    from telesmooth.lcm_types.channels import ONBOARD_JOINT_STATUS
    from telesmooth.scripts.processes import robot_commanded_pose

    scenario = LoadScenario()
    arm = scenario.arm_description
    url = f"udpm://239.255.76.67:{worker_port(7300)}?ttl=0"
    valid = 0.5 * (arm.joint_lower_rad + arm.joint_upper_rad) + 0.01
    beyond = np.array(arm.joint_upper_rad, dtype=float) + 0.1
    bad = [b"garbage", b"\x00" * 40, _status([np.nan] * arm.num_joints),
           _status([0.1] * (arm.num_joints + 1)), _status(beyond)]

    def publish(packets, stop):
        bus = lcm.LCM(url)
        while not stop.is_set():
            for data in packets:
                bus.publish(ONBOARD_JOINT_STATUS, data)
                time.sleep(0.01)

    for packets, expected in ((bad, None), (bad + [_status(valid)], valid)):
        stop = threading.Event()
        thread = threading.Thread(target=publish, args=(packets, stop), daemon=True)
        thread.start()
        try:
            pose = robot_commanded_pose(url, scenario, wait_s=1.0)
        finally:
            stop.set()
            thread.join(timeout=5)
        if expected is None:
            assert pose is None
        else:
            np.testing.assert_array_equal(pose, expected)
