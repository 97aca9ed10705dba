"""Freshness through real processes: no replay across an onboard restart, no lock-out by a
session from the future, a restarted ground accepted at once.

One bus (udpm, ttl=0, this host). This test holds the uplink key (as a faulty ground would)
and listens to the bus. In order:

1. onboard process 1 starts; ground 1 runs; every packet it sent is captured;
2. while ground 1 runs, the test publishes a signed command addressed to the robot's epoch
   (read from its telemetry) with a session counter far ahead: it is refused ("session") and
   ground 1 goes on being accepted;
3. ground 1 ends, ground 2 starts: its first packet is accepted within a second of being on
   the bus (measured on the wall clock from this test's own view of the bus and telemetry);
4. onboard process 1 is stopped and onboard process 2 started: every captured packet of
   both grounds is replayed to it, and none is accepted (all "session").
"""

import json
import time

import lcm
import numpy as np
import pytest
from process_fixtures import (
    PROCESS_TEST_TIMEOUT_S,
    BusPump,
    CliProcess,
    bus_urls,
    read_rows,
)

from telesmooth.diagrams.scenario import LoadScenario
from telesmooth.lcm_types import lcmt_onboard_joint_status, lcmt_teleop_joint_command
from telesmooth.lcm_types.channels import ONBOARD_JOINT_STATUS, TELEOP_JOINT_COMMAND
from telesmooth.link.auth import generate_key_file, sign
from telesmooth.link.session import session_counter, session_id

pytestmark = pytest.mark.process

SCENARIO_TEXT = ("{haptic: {source: synthetic, synthetic: {duration_s: 6.0, hold_start_s: 0.5,"
                 " hold_end_s: 0.5}}, settle_s: 0.0, smoother: {method: online-hard}}")


class _Bus(BusPump):
    """This test's view of the bus: commands (with their wall-clock arrival) and telemetry."""

    def __init__(self, url):
        self.commands = []          # (monotonic time, bytes, decoded)
        self.telemetry = []         # (monotonic time, decoded)
        self.bus = lcm.LCM(url)
        self.bus.subscribe(TELEOP_JOINT_COMMAND, self._command).set_queue_capacity(10_000)
        self.bus.subscribe(ONBOARD_JOINT_STATUS, self._status).set_queue_capacity(10_000)
        super().__init__(self.bus)

    def _command(self, _channel, data):
        self.commands.append((time.monotonic(), bytes(data),
                              lcmt_teleop_joint_command.decode(data)))

    def _status(self, _channel, data):
        self.telemetry.append((time.monotonic(), lcmt_onboard_joint_status.decode(data)))

    def latest_status(self, timeout_s=PROCESS_TEST_TIMEOUT_S):
        deadline = time.monotonic() + timeout_s
        while not self.telemetry and time.monotonic() < deadline:
            time.sleep(0.05)
        assert self.telemetry, "no onboard telemetry"
        return self.telemetry[-1][1]


def _signed_command(names, key, *, seq, session, epoch, q):
    msg = lcmt_teleop_joint_command()
    msg.seq, msg.session_id, msg.onboard_epoch = seq, session, epoch
    msg.num_joints = len(names)
    msg.joint_name = list(names)
    msg.joint_position_smoothed = [float(v) for v in q]
    msg.joint_velocity_smoothed = [0.0] * len(names)
    return sign(msg, key)


@pytest.fixture(scope="module")
def session_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("sessions")
    url, _ = bus_urls(7900)
    key_path = out / "uplink.key"
    key = generate_key_file(key_path)
    names = LoadScenario(scenario_text=SCENARIO_TEXT).arm_description.joint_names
    common = ["--scenario-text", SCENARIO_TEXT, "--uplink-key", str(key_path), "--lcm-url", url]
    bus = _Bus(url)
    processes = []

    def start(args, name):
        process = CliProcess(args, out / f"{name}.log")
        processes.append(process)
        return process

    result = {}
    try:
        onboard = start(["onboard", "--duration", "900", "--out", str(out / "onboard1")]
                        + common, "onboard1")
        onboard.wait_for("onboard: listening", PROCESS_TEST_TIMEOUT_S)
        epoch1 = bus.latest_status().onboard_epoch
        ground1 = start(["ground", "--duration", "7", "--resume-wait", "120"] + common,
                        "ground1")
        ground1.wait_for("ground: publishing", PROCESS_TEST_TIMEOUT_S)
        # 2. While ground 1 runs: a signed command with a session counter far ahead.
        deadline = time.monotonic() + 60
        while bus.latest_status().accepted_count < 4 and time.monotonic() < deadline:
            time.sleep(0.1)
        status = bus.latest_status()
        assert status.accepted_count >= 4, "ground 1 was never accepted"
        far = session_id(session_counter(status.last_command_session_id) + 1000, 12345)
        q_far = np.asarray(status.joint_position_commanded) + 0.2
        bus.bus.publish(TELEOP_JOINT_COMMAND, _signed_command(
            names, key, seq=0, session=far, epoch=status.onboard_epoch, q=q_far).encode())
        injected_at = time.monotonic()
        assert ground1.wait(timeout=PROCESS_TEST_TIMEOUT_S) == 0, ground1.log_path.read_text()
        result["ground1_session"] = status.last_command_session_id
        result["injected_at"] = injected_at
        result["far_session"] = far
        # 3. A restarted ground.
        ground2 = start(["ground", "--duration", "4", "--resume-wait", "120"] + common,
                        "ground2")
        assert ground2.wait(timeout=PROCESS_TEST_TIMEOUT_S) == 0, ground2.log_path.read_text()
        time.sleep(2.0)
        assert onboard.stop(timeout_s=PROCESS_TEST_TIMEOUT_S) == 0, onboard.log_path.read_text()
        # 4. A restarted onboard process; every captured packet replayed to it.
        onboard2 = start(["onboard", "--duration", "900", "--out", str(out / "onboard2")]
                         + common, "onboard2")
        onboard2.wait_for("onboard: listening", PROCESS_TEST_TIMEOUT_S)
        deadline = time.monotonic() + 60
        while bus.latest_status().onboard_epoch == epoch1 and time.monotonic() < deadline:
            time.sleep(0.1)
        epoch2 = bus.latest_status().onboard_epoch
        captured = [(data, msg) for _, data, msg in list(bus.commands)
                    if msg.seq >= 0 and msg.onboard_epoch == epoch1
                    and msg.session_id != far]
        for data, _ in captured:
            bus.bus.publish(TELEOP_JOINT_COMMAND, data)
            time.sleep(0.005)
        # Wait until onboard 2 has counted them all (its clock may run behind the wall).
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline:
            status = bus.latest_status()
            if status.onboard_epoch == epoch2 and (
                    status.rejected_session_count + status.accepted_count >= len(captured)):
                break
            time.sleep(0.2)
        time.sleep(1.0)
        assert onboard2.stop(timeout_s=PROCESS_TEST_TIMEOUT_S) == 0, \
            onboard2.log_path.read_text()
        result.update(epoch1=epoch1, epoch2=epoch2, replayed=len(captured))
    finally:
        bus.close()
        for process in processes:
            if process.poll() is None:
                process.kill()
    result.update(out=out, commands=bus.commands, telemetry=bus.telemetry)
    return result


def test_a_session_from_the_future_is_refused_and_locks_nobody_out(session_run):
    out = session_run["out"]
    counts = json.loads((out / "onboard1" / "onboard_counts.json").read_text())
    assert counts["session"] >= 1
    accepted = read_rows(out / "onboard1" / "onboard_commands.csv")  # count, session, seq…
    sessions = accepted[:, 1].astype(np.int64)
    assert session_run["far_session"] not in set(sessions.tolist())
    # Ground 1 went on being accepted after the injection: the telemetry shows its session
    # accepting newer packets later.
    after = [msg for t, msg in session_run["telemetry"]
             if t > session_run["injected_at"] + 1.0 and msg.onboard_epoch == session_run["epoch1"]
             and msg.last_command_session_id == session_run["ground1_session"]]
    assert len({msg.last_command_seq for msg in after}) >= 4


def test_a_restarted_ground_is_accepted_within_a_second(session_run):
    commands, telemetry = session_run["commands"], session_run["telemetry"]
    epoch1 = session_run["epoch1"]
    ground1 = session_run["ground1_session"]
    second = [(t, msg) for t, _, msg in commands if msg.seq >= 0 and msg.onboard_epoch == epoch1
              and msg.session_id not in (ground1, session_run["far_session"])]
    assert second, "ground 2 sent nothing"
    first_t, first_msg = second[0]
    assert session_counter(first_msg.session_id) == session_counter(ground1) + 1
    # Timing-free: its very first packet was the first of it the robot accepted (nothing of
    # it was refused before).
    rows = read_rows(session_run["out"] / "onboard1" / "onboard_commands.csv")
    mine = rows[rows[:, 1].astype(np.int64) == first_msg.session_id]
    assert int(mine[0, 2]) == first_msg.seq
    # On the wall clock: accepted within a second of being on the bus, plus however much
    # further the onboard process had fallen behind the wall clock by then (measured from
    # its telemetry: wall arrival minus its simulation time, against the least seen).
    accepted = [(t, msg) for t, msg in telemetry if msg.onboard_epoch == epoch1
                and msg.last_command_session_id == first_msg.session_id]
    assert accepted, "ground 2 was never accepted"
    lags = [t - msg.utime * 1e-6 for t, msg in telemetry if msg.onboard_epoch == epoch1]
    t_accepted, msg_accepted = accepted[0]
    behind = (t_accepted - msg_accepted.utime * 1e-6) - min(lags)
    delay = t_accepted - first_t
    print(f"\nrestarted ground: its first packet was accepted {delay:.3f} s after it was on the "
          f"bus (seen in the telemetry); the onboard process was {behind:.3f} s further behind "
          "the wall clock than at its best")
    assert delay <= 1.0 + behind, (delay, behind)


def test_no_packet_of_the_previous_onboard_run_is_accepted_after_a_restart(session_run):
    out = session_run["out"]
    assert session_run["epoch2"] != session_run["epoch1"]
    assert session_run["replayed"] >= 20
    counts = json.loads((out / "onboard2" / "onboard_counts.json").read_text())
    print(f"\nreplayed {session_run['replayed']} captured packets to the restarted onboard "
          f"process: {counts}")
    assert counts["accepted"] == 0
    assert counts["session"] == session_run["replayed"]
    assert counts["auth"] == counts["invalid"] == counts["undecodable"] == 0
    report = json.loads((out / "onboard2" / "onboard_report.json").read_text())
    assert report["commands"] == 0 and report["onboard_epoch"] == session_run["epoch2"]
