"""Ground and onboard as two real processes on udpm://…?ttl=0, recorded by lcm-logger.

The same scenario simulated in one process must send exactly the same commands; the log of
the uplink channel must decode with our types at 4 Hz; the onboard process must accept them.
"""

import csv
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import lcm
import numpy as np
import pytest
from process_fixtures import PROCESS_TEST_TIMEOUT_S, worker_port

from telesmooth.diagrams.scenario import LoadScenario
from telesmooth.diagrams.simulation import simulate
from telesmooth.lcm_types import lcmt_teleop_joint_command
from telesmooth.lcm_types.channels import TELEOP_JOINT_COMMAND
from telesmooth.link.auth import generate_key_file, verify
from telesmooth.link.session import session_counter

SCENARIO_TEXT = ("{haptic: {source: synthetic, synthetic: {duration_s: 4.0, hold_start_s: 0.5, "
                 "hold_end_s: 0.5}}, settle_s: 0.0}")
DURATION_S = 3.0


def _read(path):
    with open(path, newline="") as handle:
        rows = list(csv.reader(handle))
    return np.array(rows[1:], dtype=float)


pytestmark = pytest.mark.process


@pytest.fixture(scope="module")
def two_process_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("two_processes")
    port = worker_port(7700, 200)
    url = f"udpm://239.255.76.67:{port}?ttl=0"
    bin_dir = Path(sys.executable).parent
    log_path = out / "uplink.lcmlog"
    key_path = out / "uplink.key"
    generate_key_file(key_path)
    logger = subprocess.Popen(
        [str(bin_dir / "lcm-logger"), "-q", "-f", f"--lcm-url={url}", "-c",
         TELEOP_JOINT_COMMAND, str(log_path)], start_new_session=True)
    common = ["--scenario-text", SCENARIO_TEXT, "--lcm-url", url, "--out", str(out),
              "--uplink-key", str(key_path)]
    telesmooth = [sys.executable, "-m", "telesmooth.scripts.cli"]
    # The onboard process runs until this test stops it (SIGINT: it writes its logs), so
    # that a slow start on a loaded machine cannot end it before the ground has finished.
    onboard = subprocess.Popen(telesmooth + ["onboard", "--duration", "600"] + common,
                               stderr=subprocess.PIPE, text=True)
    # The ground waits for the robot's telemetry (its epoch) before it starts.
    ground = subprocess.run(telesmooth + ["ground", "--duration", str(DURATION_S),
                                          "--resume-wait", "120"] + common,
                            stderr=subprocess.PIPE, text=True, timeout=PROCESS_TEST_TIMEOUT_S)
    time.sleep(2.0)
    onboard.send_signal(signal.SIGINT)
    onboard_err = onboard.communicate(timeout=PROCESS_TEST_TIMEOUT_S)[1]
    time.sleep(0.3)
    os.killpg(logger.pid, signal.SIGINT)
    logger.wait(timeout=10)
    assert ground.returncode == 0, ground.stderr
    assert onboard.returncode == 0, onboard_err
    return out, log_path, key_path.read_text().strip(), ground.stderr


def test_logged_uplink_decodes_at_4hz_and_equals_the_single_process_run(two_process_run):
    out, log_path, key_hex, ground_log = two_process_run
    messages = [lcmt_teleop_joint_command.decode(event.data)
                for event in lcm.EventLog(str(log_path), "r")
                if event.channel == TELEOP_JOINT_COMMAND]
    messages = [m for m in messages if m.seq >= 0]
    # The ground had the robot's telemetry before it started: no packet was withheld.
    assert [m.seq for m in messages] == list(range(len(messages)))
    # Packets 0…11 leave at t_k + 1 ms; packet 12 is formed at t = 3.0 s, the run's end.
    assert len(messages) == int(DURATION_S / 0.25)
    np.testing.assert_array_equal(np.diff([m.utime for m in messages]), 250_000)

    record = simulate(LoadScenario(scenario_text=SCENARIO_TEXT), duration_s=DURATION_S)
    assert list(record.packet_seq[:len(messages)]) == [m.seq for m in messages]
    epoch = json.loads((out / "onboard_report.json").read_text())["onboard_epoch"]
    for message, q in zip(messages, record.q_sent):
        np.testing.assert_array_equal(message.joint_position_smoothed, q)
        assert list(message.joint_name) == list(record.joint_names)
        # Signed with the shared key, one session: the first counter of this robot's epoch.
        assert verify(message, bytes.fromhex(key_hex)) is None
        assert message.session_id == messages[0].session_id
        assert session_counter(message.session_id) == 1
        assert message.onboard_epoch == epoch > 0

    ground = _read(out / "ground_commands.csv")
    np.testing.assert_array_equal(ground[:len(messages), 2:],
                                  [m.joint_position_smoothed for m in messages][:len(ground)])


def test_onboard_process_accepted_the_commands(two_process_run):
    out, log_path, _, ground_log = two_process_run
    messages = {m.seq: m for m in (lcmt_teleop_joint_command.decode(e.data)
                                   for e in lcm.EventLog(str(log_path), "r"))}
    onboard = _read(out / "onboard_commands.csv")   # accepted, session, seq, t, q…
    assert onboard.shape[0] >= len(messages) - 2
    # One row per receiver poll that accepted packets (the newest of them): a loaded onboard
    # process can take two in one poll, so the running count may jump; seqs only increase.
    assert onboard[0, 0] >= 1 and np.all(np.diff(onboard[:, 0]) >= 1)
    assert np.all(np.diff(onboard[:, 2]) >= 1)
    np.testing.assert_array_equal(np.diff(onboard[:, 0]), np.diff(onboard[:, 2]))
    for row in onboard:
        np.testing.assert_array_equal(row[4:], messages[int(row[2])].joint_position_smoothed)
    telemetry = _read(out / "onboard_telemetry.csv")
    assert np.all(np.isfinite(telemetry))
    # The user sees how far off the robot is: the ground's status lines and the onboard report.
    assert "rad from the accepted stream" in ground_log
    report = json.loads((out / "onboard_report.json").read_text())
    assert report["packets"]["accepted"] == onboard[-1, 0] and report["commands"] > 0
    assert set(report["time_in_mode_s"]) == {"track", "stopping", "held", "resuming"}
