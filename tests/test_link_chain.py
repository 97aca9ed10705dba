"""The whole chain with the uplink going through a faulty link (in process): a fault matrix.

Each case runs the real builders (MakeTeleoperationDiagram with ``link`` faults: sender →
LinkChannel → JointCommandReceiver → LinkGuard → plant) and checks, from the logs alone:

* nothing unsafe reached the robot: every command the guard issued is finite and inside the
  joint limits; every accepted command is one the ground sent (same seq, same positions),
  accepted in strictly increasing order (no stale or duplicate packet is ever accepted);
* nothing accepted was lost: every command accepted while the guard tracks, directly after
  the packet before it, is commanded at once; with the link in order it is the packet bit
  for bit (the ground is online-hard: within the limits), after a gap (a lost or held-back
  packet) the limiter's step towards it;
* everything that reaches the robot stays within the FD acceleration and jerk limits,
  whatever the link does to the packets: the guard enforces them itself.
"""

import numpy as np
import pytest
from pydrake.systems.analysis import Simulator

from telesmooth.diagrams.scenario import LoadScenario
from telesmooth.diagrams.teleoperation import MakeTeleoperationDiagram, uplink_packets
from telesmooth.systems.link_guard import MODE_TRACK, fd_limits_ratio

BASE = ("{haptic: {source: synthetic, synthetic: {duration_s: 5.0, hold_start_s: 0.5, "
        "hold_end_s: 0.5}}, settle_s: 2.0, smoother: {method: online-hard}, "
        "link: {faults: %s}}")

# name → (faults, order kept: the whole command sequence must then be within the limits)
CASES = {
    "none": ("{}", True),
    "delay 2 s": ("{delay_s: 2.0}", True),
    "duplicates 50 %": ("{duplicate_probability: 0.5, seed: 3}", True),
    "loss 30 %": ("{loss_probability: 0.3, seed: 1}", False),
    "jitter 0.2 s": ("{jitter_s: 0.2, seed: 2}", False),
    "reorder 30 %": ("{reorder_probability: 0.3, reorder_delay_s: 0.3, seed: 4}", False),
    "outage 1.5 s": ("{outages: [[1.5, 3.0]]}", True),
    "everything": ("{delay_s: 1.0, jitter_s: 0.1, loss_probability: 0.2, "
                   "duplicate_probability: 0.2, reorder_probability: 0.1, "
                   "outages: [[2.0, 2.8]], seed: 5}", False),
}


def _run(faults):
    scenario = LoadScenario(scenario_text=BASE % faults)
    handles = MakeTeleoperationDiagram(scenario)
    simulator = Simulator(handles.diagram)
    simulator.Initialize()
    simulator.AdvanceTo(9.0)
    context = simulator.get_context()
    logs = {name: handles.logs[name].FindLog(context) for name in handles.logs}
    return scenario, handles, context, logs


@pytest.fixture(scope="module", params=list(CASES), ids=list(CASES))
def case(request):
    faults, ordered = CASES[request.param]
    return request.param, ordered, *_run(faults)


def _changes(values):
    """Indices of the rows where a logged counter changes (and row 0)."""
    values = np.asarray(values)
    return np.flatnonzero(np.r_[True, np.diff(values) != 0])


def test_nothing_unsafe_reached_the_robot_and_nothing_accepted_was_lost(case):
    name, ordered, scenario, handles, context, logs = case
    arm = scenario.arm_description
    seq, _, states = uplink_packets(handles, context)
    n = arm.num_joints
    sent = {int(k): state[:n] for k, state in zip(seq, states)}

    guard_q = logs["guard_q_commanded"].data().T
    assert np.all(np.isfinite(guard_q))
    assert np.all(guard_q >= arm.joint_lower_rad) and np.all(guard_q <= arm.joint_upper_rad)

    count = logs["accepted_count"].data()[0]
    accepted_rows = _changes(count)[1:]
    accepted_seq = logs["last_command_seq"].data()[0][accepted_rows].astype(int)
    q_accepted = logs["q_accepted"].data().T
    assert len(accepted_rows) >= 10, name
    assert np.all(np.diff(accepted_seq) > 0), name          # never stale, never a duplicate
    for row, k in zip(accepted_rows, accepted_seq):
        np.testing.assert_array_equal(q_accepted[row], sent[k])   # what the ground sent
    mode = logs["guard_mode"].data()[0]
    commands = logs["guard_command_count"].data()[0]
    passed = 0
    for j, row in enumerate(accepted_rows[1:], start=1):
        # Accepted while tracking, directly after the packet before it: commanded at once,
        # and with the link in order, unchanged.
        consecutive = (accepted_seq[j] == accepted_seq[j - 1] + 1
                       and count[row] == count[row - 1] + 1)
        if consecutive and mode[row - 1] == MODE_TRACK and mode[row] == MODE_TRACK:
            assert commands[row] == commands[row - 1] + 1, (name, row)
            if ordered:
                np.testing.assert_array_equal(guard_q[row], q_accepted[row])
            passed += 1
    if name in ("none", "delay 2 s", "duplicates 50 %"):
        assert passed >= 10, name   # the check above really ran

    # The link did what it was told, and the receiver counted it.
    counts = handles.onboard.link.counts(handles.onboard.link.GetMyContextFromRoot(context))
    rejected = dict(zip(("invalid", "auth", "duplicate", "stale", "undecodable"),
                        logs["rejection_counts"].data()[:, -1].astype(int)))
    assert rejected["invalid"] == rejected["auth"] == rejected["undecodable"] == 0
    assert counts["delivered"] == count[-1] + rejected["duplicate"] + rejected["stale"]
    if "duplicates" in name:
        assert counts["duplicated"] > 0 and rejected["duplicate"] == counts["duplicated"]
    if "loss" in name:
        assert counts["lost"] > 0


def test_the_guard_keeps_the_limits(case):
    name, ordered, scenario, handles, context, logs = case
    commands_log = logs["guard_command_count"].data()[0]
    rows = _changes(commands_log)
    commands = logs["guard_q_commanded"].data().T[rows]
    mode = logs["guard_mode"].data()[0][rows]
    a_max = scenario.smoother.max_acceleration_rad_per_s2
    j_max = scenario.smoother.max_jerk_rad_per_s3
    dt = scenario.uplink.period_s
    distance = logs["guard_stream_distance"].data()[0][rows]
    # The guard keeps the limits itself, so the whole command sequence is within them in
    # every case; no stop fell back to the hold (a velocity step, reported).
    assert not np.any(logs["guard_stop_outcome"].data()[0] >= 3), name
    ratio = fd_limits_ratio(commands, dt, a_max, j_max)
    assert ratio.acceleration <= 1 + 1e-6 and ratio.jerk <= 1 + 1e-6, (name, ratio)
    if ordered and "outage" not in name:
        np.testing.assert_array_equal(distance, 0.0)   # every packet passed unchanged
    if "outage" in name or name == "everything":
        # The silence made a stop; the robot was away from the stream and the guard said how
        # far (the distance then closes as it re-joins).
        assert np.max(distance) > 1e-3 and distance[-1] < np.max(distance), name
    if "outage" in name:
        # It ramped down (stopping, held), then re-joins within the limits: with the
        # scenario's a_max = 0.05 rad/s², catching up 1.5 s of operator motion takes longer
        # than the run, but the gap to the accepted command closes.
        assert {1, 3} <= set(mode.astype(int))
        accepted = logs["q_accepted"].data().T[rows]
        resuming = np.flatnonzero(mode == 3)
        gap = np.abs(accepted - commands).max(axis=1)
        assert gap[resuming[-1]] < gap[resuming[:4]].max()


def test_without_faults_the_robot_gets_exactly_the_direct_chain():
    deployed = LoadScenario(scenario_text=BASE % "{}")
    assert deployed.chain == "deployed"       # the default
    direct = LoadScenario(scenario_text=(BASE % "{}")[:-1] + ", chain: paper}")
    _, handles, context, logs = _run("{}")
    seq, _, states = uplink_packets(handles, context)
    rows = _changes(logs["guard_command_count"].data()[0])[1:]
    commands = logs["guard_q_commanded"].data().T[rows]
    n = commands.shape[1]
    # Every packet from the first reaches the robot unchanged, in order.
    np.testing.assert_array_equal(commands[:len(seq)], states[:len(commands), :n])
    # The packets themselves are the direct chain's (the link path does not touch the ground).
    direct_handles = MakeTeleoperationDiagram(direct)
    simulator = Simulator(direct_handles.diagram)
    simulator.Initialize()
    simulator.AdvanceTo(9.0)
    direct_seq, _, direct_states = uplink_packets(direct_handles, simulator.get_context())
    np.testing.assert_array_equal(direct_seq, seq)
    np.testing.assert_array_equal(direct_states, states)
