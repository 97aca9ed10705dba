"""The real-time fault-injection relay as a process between two udpm://…?ttl=0 buses.

Traffic stays on this host (ttl=0) on ports 7900–7999, apart from the 7700–7899 of the other
multi-process tests. Packet k of the uplink is the k-th message the relay receives, which on
one host is the publish order, so the relay's fates must be exactly LinkFaultModel's.
"""

import collections
import json
import queue
import select
import signal
import subprocess
import sys
import threading
import time
import warnings

import lcm
import pytest
from process_fixtures import worker_port

from telesmooth.lcm_types import channels, lcmt_onboard_joint_status, lcmt_teleop_joint_command
from telesmooth.link import relay
from telesmooth.link.faults import LinkFaultConfig, LinkFaultModel

PORT_A = worker_port(7900, 50)
PORT_B = PORT_A + 50
URL_A = f"udpm://239.255.76.67:{PORT_A}?ttl=0"   # ground side
URL_B = f"udpm://239.255.76.67:{PORT_B}?ttl=0"   # onboard side
PUBLISH_PERIOD_S = 0.025                          # 40 Hz
READY_TIMEOUT_S = 30.0


class _Relay:
    """The relay as a subprocess; collects its stderr lines on a thread."""

    def __init__(self, tmp_path, *extra):
        self.report_path = tmp_path / "relay_report.json"
        self.lines = queue.Queue()
        self.stderr = []
        self.process = subprocess.Popen(
            [sys.executable, "-m", "telesmooth.link.relay", "--in-url", URL_A, "--out-url",
             URL_B, "--report", str(self.report_path), *extra],
            stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, text=True)
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self):
        for line in self.process.stderr:
            self.stderr.append(line)
            self.lines.put(line)

    def wait_ready(self):
        self.wait_for_line(lambda line: line.startswith("link-relay: ready"), "ready")

    def wait_for_line(self, wanted, what, timeout_s=READY_TIMEOUT_S):
        """Waits for a stderr line for which ``wanted(line)`` is true."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            try:
                line = self.lines.get(timeout=0.1)
            except queue.Empty:
                assert self.process.poll() is None, "".join(self.stderr)
                continue
            if wanted(line):
                return
        raise AssertionError(f"relay not {what}: " + "".join(self.stderr))

    def finish(self, terminate=True):
        if terminate:
            self.process.send_signal(signal.SIGTERM)
        try:
            returncode = self.process.wait(timeout=20)
        finally:
            if self.process.poll() is None:
                self.process.kill()
        self._reader.join(timeout=5)
        assert returncode == 0, "".join(self.stderr)
        return json.loads(self.report_path.read_text())


def _command(seq):
    msg = lcmt_teleop_joint_command()
    msg.utime, msg.seq, msg.num_joints = seq * 25_000, seq, 2
    msg.joint_name = ["shoulder", "elbow"]
    msg.joint_position_smoothed = [0.01 * seq, -0.01 * seq]
    msg.joint_velocity_smoothed = [0.0, 0.0]
    return msg


def _status(seq):
    msg = lcmt_onboard_joint_status()
    msg.utime, msg.seq, msg.num_joints = seq * 10_000, seq, 2
    msg.joint_position_link = [0.5, seq * 1.0]
    msg.joint_position_motor = [0.5, seq * 1.0]
    msg.tool_position_measured = [1.0, 0.0, 0.45]
    msg.joint_position_commanded = [0.0, 0.0]
    msg.joint_velocity_link = msg.joint_velocity_motor = [0.0, 0.0]
    msg.last_command_seq = -1
    return msg


def _exchange(num_uplink, *, num_downlink=0, tail_s, expected_uplink=None):
    """Publishes commands on A (and status on B) at 40 Hz; collects what crosses the relay.

    Returns (uplink [(seq, receive time)], publish times by seq, downlink [bytes], sent
    downlink [bytes]). Stops listening ``tail_s`` after the last publish, or as soon as
    ``expected_uplink`` commands (and every status) have arrived.
    """
    bus_a, bus_b = lcm.LCM(URL_A), lcm.LCM(URL_B)
    uplink, downlink = [], []
    bus_b.subscribe(channels.TELEOP_JOINT_COMMAND, lambda channel, data: uplink.append(
        (lcmt_teleop_joint_command.decode(data).seq, time.monotonic())))
    bus_a.subscribe(channels.ONBOARD_JOINT_STATUS, lambda channel, data: downlink.append(data))

    def pump(until):
        while True:
            remaining = until - time.monotonic()
            if remaining <= 0:
                return
            readable, _, _ = select.select([bus_a, bus_b], [], [], min(remaining, 0.005))
            for bus in readable:
                bus.handle_timeout(0)

    published, sent_downlink = {}, []
    start = time.monotonic()
    for k in range(max(num_uplink, num_downlink)):
        pump(start + k * PUBLISH_PERIOD_S)
        if k < num_uplink:
            data = _command(k).encode()
            published[k] = time.monotonic()
            bus_a.publish(channels.TELEOP_JOINT_COMMAND, data)
        if k < num_downlink:
            sent_downlink.append(_status(k).encode())
            bus_b.publish(channels.ONBOARD_JOINT_STATUS, sent_downlink[-1])
    deadline = time.monotonic() + tail_s
    while time.monotonic() < deadline:
        if (expected_uplink is not None and len(uplink) >= expected_uplink
                and len(downlink) >= num_downlink):
            pump(time.monotonic() + 0.05)   # anything extra would show up now
            break
        pump(min(deadline, time.monotonic() + 0.02))
    return uplink, published, downlink, sent_downlink


def test_perfect_link_forwards_every_packet_once_in_order_both_ways(tmp_path):
    dut = _Relay(tmp_path)
    dut.wait_ready()
    uplink, _, downlink, sent_downlink = _exchange(40, num_downlink=20, tail_s=3.0,
                                                   expected_uplink=40)
    report = dut.finish()
    assert [seq for seq, _ in uplink] == list(range(40))
    assert downlink == sent_downlink                 # unchanged, in order
    assert report["stopped_by"] == "SIGTERM"
    assert {k: report["uplink"][k] for k in ("received", "forwarded", "lost", "duplicated",
                                             "reordered", "in_flight")} == dict(
        received=40, forwarded=40, lost=0, duplicated=0, reordered=0, in_flight=0)
    assert report["downlink"]["received"] == report["downlink"]["forwarded"] == 20
    assert report["downlink"]["config"] is None


def test_total_loss_delivers_nothing_and_the_duration_ends_the_relay(tmp_path):
    dut = _Relay(tmp_path, "--duration", "2.5", "--link", "{loss_probability: 1}")
    dut.wait_ready()
    uplink, _, _, _ = _exchange(20, tail_s=0.5)
    report = dut.finish(terminate=False)
    assert uplink == []
    assert report["stopped_by"] == "duration"
    assert report["uplink"]["received"] == 20 and report["uplink"]["lost"] == 20
    assert report["uplink"]["forwarded"] == 0


def test_seeded_faults_match_the_model_and_the_delay_is_observed(tmp_path):
    config = LinkFaultConfig(delay_s=0.3, loss_probability=0.25, duplicate_probability=0.25,
                             duplicate_spacing_s=0.005, seed=7)
    num_packets = 60
    model = LinkFaultModel(config)
    # Without outages and jitter the fates do not depend on the send time.
    predicted = collections.Counter({k: len(model.fate(k, 0.0).delivery_times_s)
                                     for k in range(num_packets)})
    lost = [k for k in range(num_packets) if predicted[k] == 0]
    duplicated = [k for k in range(num_packets) if predicted[k] == 2]
    assert lost and duplicated   # the seed exercises both

    dut = _Relay(tmp_path, "--link", json.dumps(config.to_mapping()))
    dut.wait_ready()
    uplink, published, _, _ = _exchange(num_packets, tail_s=3.0,
                                        expected_uplink=sum(predicted.values()))
    report = dut.finish()

    assert collections.Counter(seq for seq, _ in uplink) == +predicted
    # No jitter: the originals keep their order. A duplicate follows its original by
    # duplicate_spacing_s after the relay received it, so it may come after the next packet
    # when a loaded machine hands the relay two packets within 5 ms (seen: 0, 1, 2, 1, 3).
    originals = list(dict.fromkeys(seq for seq, _ in uplink))
    assert originals == sorted(originals)
    assert report["uplink"]["received"] == num_packets
    assert report["uplink"]["lost"] == len(lost)
    assert report["uplink"]["duplicated"] == len(duplicated)
    assert report["uplink"]["forwarded"] == len(uplink)
    assert report["uplink"]["config"] == config.to_mapping()

    first_arrival = {}
    for seq, received_at in uplink:
        first_arrival.setdefault(seq, received_at)
    latency = sorted(first_arrival[k] - published[k] for k in first_arrival)
    # The relay schedules from its own receipt, after our publish: never early. Late by the
    # scheduling of a busy machine only; the median is robust to a few slow wake-ups.
    assert latency[0] >= 0.3 - 1e-3, latency
    assert latency[len(latency) // 2] <= 0.3 + 0.05, latency


def test_sigint_stops_the_relay_and_writes_the_report(tmp_path):
    dut = _Relay(tmp_path, "--link", "{delay_s: 60.0}")
    dut.wait_ready()
    _exchange(4, tail_s=0.2)
    # Its progress line (once a second) says when it has all four, however loaded the machine.
    dut.wait_for_line(lambda line: "uplink 4 received" in line, "given all four packets")
    dut.process.send_signal(signal.SIGINT)
    report = dut.finish(terminate=False)
    assert report["stopped_by"] == "SIGINT"
    assert report["uplink"]["received"] == 4 and report["uplink"]["in_flight"] == 4
    assert report["uplink"]["forwarded"] == 0
    assert "link-relay: stopped by SIGINT" in "".join(dut.stderr)


# --- arguments (no traffic) -------------------------------------------------------------------

@pytest.mark.parametrize("arguments, message", [
    (["--link", "{loss_probability: 2}"], "--link: loss_probability = 2 must be a probability"),
    (["--link", "{colour: red}"], "--link: link fault config: unknown key(s) ['colour']"),
    (["--link", "[1, 2]"], "--link must be a mapping at the top level; got list"),
    (["--link", "{delay_s: [0.3"], "--link: not valid YAML at line 1"),
    (["--link", "{delay_s: 0.1, delay_s: 0.2}"], "--link: 'delay_s' is given twice"),
    (["--link", "{1: 2}"], "--link: line 1: the key '1' in the top level is an integer"),
    (["--link", "{outages: [[2, 1]]}"], "--link: outages[0] = [2, 1]: end must be > start"),
    (["--downlink", "{delay_s: -1}"], "--downlink: delay_s = -1 must be finite and >= 0"),
    (["--duration", "0"], "--duration = 0.0 must be > 0 s"),
    (["--duration", "nan"], "--duration = nan must be > 0 s"),
    (["--out-url", URL_A.replace("?ttl=0", "")], "--in-url = "),
    (["--uplink-channel", channels.ONBOARD_JOINT_STATUS],
     "uplink_channels and downlink_channels share ['ONBOARD_JOINT_STATUS']"),
])
def test_main_rejects_bad_arguments_with_exit_code_2_naming_the_field(capsys, arguments,
                                                                      message):
    argv = ["--in-url", URL_A, "--out-url", URL_B, "--duration", "1"] + arguments
    with pytest.raises(SystemExit) as exit_info:
        relay.main(argv)
    assert exit_info.value.code == 2
    assert message in capsys.readouterr().err


def test_main_requires_both_urls(capsys):
    with pytest.raises(SystemExit) as exit_info:
        relay.main(["--in-url", URL_A])
    assert exit_info.value.code == 2
    assert "--out-url" in capsys.readouterr().err


def test_same_bus_is_refused_whatever_the_query_and_ttl_is_checked():
    with pytest.raises(ValueError, match="same LCM bus"):
        relay.check_relay_urls(URL_A, URL_A.replace("?ttl=0", ""))
    with pytest.raises(ValueError, match="same LCM bus"):
        relay.check_relay_urls("memq://", "memq://")
    with pytest.raises(ValueError, match=r"uplink_out_url = 7901 must be an LCM URL"):
        relay.check_relay_urls(URL_A, 7901)
    with pytest.warns(UserWarning, match=r"uplink_out_url = .* does not say ttl=0"):
        relay.check_relay_urls(URL_A, URL_B.replace("ttl=0", "ttl=1"))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        relay.check_relay_urls(URL_A, URL_B)
        relay.check_relay_urls(URL_A, "memq://")


def test_run_relay_validates_before_opening_any_bus():
    common = dict(uplink_in_url=URL_A, uplink_out_url=URL_B, config=LinkFaultConfig(),
                  duration_s=1.0)
    with pytest.raises(ValueError, match="same LCM bus"):
        relay.run_relay(**{**common, "uplink_out_url": URL_A})
    with pytest.raises(ValueError, match=r"duration_s = -1.0 must be > 0 s"):
        relay.run_relay(**{**common, "duration_s": -1.0})
    with pytest.raises(ValueError, match=r"config = \{\} must be a LinkFaultConfig"):
        relay.run_relay(**{**common, "config": {}})
    with pytest.raises(ValueError, match=r"uplink_channels = 'TELEOP_JOINT_COMMAND' must be"):
        relay.run_relay(**{**common, "uplink_channels": "TELEOP_JOINT_COMMAND"})


def test_relay_defaults_are_the_project_channels_and_it_imports_no_drake():
    assert relay.run_relay.__kwdefaults__["uplink_channels"] == (channels.TELEOP_JOINT_COMMAND,)
    assert relay.run_relay.__kwdefaults__["downlink_channels"] == (
        channels.ONBOARD_JOINT_STATUS,)
    code = ("import sys, telesmooth.link, telesmooth.link.relay; "
            "print(sorted(m for m in sys.modules if m.split('.')[0] == 'pydrake'))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=60, check=True).stdout
    assert out.strip() == "[]"
