"""The link fault matrix through real processes: one case per fault, each with its own ground
process and its own relay, against one onboard process that runs through all of them.

Buses (udpm, ttl=0, this host only): each ground process publishes on A; ``telesmooth
link-relay`` forwards A → B with the case's faults (telemetry B → A unchanged); the onboard
process listens on B. Every ground starts from the robot's commanded pose (its telemetry,
``--resume-wait``), as after a restart, so the cases follow each other on one robot. The
"outage" case kills its relay mid-run and starts a new one 2 s later (the link is down in
between: those packets are gone). The "onboard stalls" case freezes the onboard process for
0.8 s (SIGSTOP/SIGCONT); it then catches up with the wall clock and its receiver takes the
packets that waited in the socket in one poll. This test listens on A (what each ground sent)
and on B (what the relay put on the onboard bus, in order, and the onboard telemetry).

Checked, per case, from the onboard process's own logs and telemetry:

* every packet the relay forwarded was examined by the onboard receiver (accepted, or dropped
  as a duplicate or stale), none was lost between the bus and the receiver;
* the accepted commands are exactly the oracle's: in arrival order on B, the packets newer
  than every packet before them, each bit for bit what its ground sent;
* without link gaps (no fault, delay, duplicates, a stalled onboard process) every accepted
  command reached the robot in the poll it arrived, in order, in TRACK and within the
  guard's re-join tolerance of the packet (bit for bit once the guard reproduces the stream;
  a re-join from the case before can leave it a few µrad behind a stream that moves at its
  limits until the stream slows), except after a timing gap the link did not make: a burst
  (several packets accepted in one poll, the onboard process fell behind the wall clock) or
  a packet later than the guard's timeout (the ground fell behind). The guard joins those
  through its limiter, within the limits like every other command;
* the fault really happened (the relay's counts).

And over the whole run: every command that reached the robot is finite, within the joint
limits, and the command sequence is within the FD acceleration and jerk limits (the ground
is online-hard; the guard joins every gap through its limiter and ramps down between cases).
"""

import json
import signal
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
from telesmooth.link.auth import generate_key_file
from telesmooth.systems.collision_stop import STOP_OUTCOMES
from telesmooth.systems.link_guard import MODE_TRACK, fd_limits_ratio

pytestmark = pytest.mark.process

SCENARIO_TEXT = ("{haptic: {source: synthetic, synthetic: {duration_s: 5.0, hold_start_s: 0.5,"
                 " hold_end_s: 0.5}}, settle_s: 0.0, smoother: {method: online-hard}}")
GROUND_S = 6.0

# name → (relay faults, the relay's count that must be > 0, gap-free)
CASES = {
    "none": ("{}", None, True),
    "delay 1.5 s": ("{delay_s: 1.5}", None, True),
    "jitter 0.2 s": ("{jitter_s: 0.2, seed: 2}", None, False),
    "loss 30 %": ("{loss_probability: 0.3, seed: 1}", "lost", False),
    "duplicates 50 %": ("{duplicate_probability: 0.5, seed: 3}", "duplicated", True),
    "reorder 30 %": ("{reorder_probability: 0.3, reorder_delay_s: 0.3, seed: 4}", "reordered",
                     False),
    "outage 2 s": ("{}", None, False),
    "onboard stalls 0.8 s": ("{}", None, True),
    "everything": ("{delay_s: 0.5, jitter_s: 0.1, loss_probability: 0.1, "
                   "duplicate_probability: 0.2, reorder_probability: 0.1, seed: 5}", "lost",
                   False),
}
COUNT_FIELDS = ("accepted_count", "rejected_invalid_count", "rejected_auth_count",
                "rejected_session_count",
                "dropped_duplicate_count", "dropped_stale_count", "undecodable_count")


class _Listener:
    """This test's own view of both buses (lcm package, pumped in a thread)."""

    def __init__(self, url_a, url_b):
        self.sent = {}            # (session, seq) → positions, what the grounds sent on A
        self.sent_at = {}         # (session, seq) → when it was on A (monotonic, s)
        self.arrivals = []        # (session, seq) in arrival order on B
        self.status = None        # the newest onboard telemetry
        self._bus_a, self._bus_b = lcm.LCM(url_a), lcm.LCM(url_b)
        for bus in (self._bus_a, self._bus_b):
            bus.subscribe(TELEOP_JOINT_COMMAND, lambda c, d, bus=bus: self._command(bus, d)) \
                .set_queue_capacity(10_000)
        self._bus_b.subscribe(ONBOARD_JOINT_STATUS, self._status)
        self._pump = BusPump(self._bus_a, self._bus_b)

    def _command(self, bus, data):
        msg = lcmt_teleop_joint_command.decode(data)
        if msg.seq < 0:            # a ground without the robot's telemetry yet: not addressed
            return
        key = (msg.session_id, msg.seq)
        if bus is self._bus_a:
            self.sent[key] = np.asarray(msg.joint_position_smoothed)
            self.sent_at.setdefault(key, time.monotonic())
        else:
            self.arrivals.append(key)

    def _status(self, _channel, data):
        self.status = lcmt_onboard_joint_status.decode(data)

    def counts(self):
        return {field: int(getattr(self.status, field)) for field in COUNT_FIELDS}

    def settled_counts(self, timeout_s=120.0):
        """The onboard counts once they have not changed for 1 s (the onboard process may
        run behind the wall clock under load)."""
        deadline = time.monotonic() + timeout_s
        previous, stable_since = self.counts(), time.monotonic()
        while time.monotonic() < deadline:
            time.sleep(0.2)
            current = self.counts()
            if current != previous:
                previous, stable_since = current, time.monotonic()
            elif time.monotonic() - stable_since >= 1.0:
                return current
        raise AssertionError(f"the onboard counts did not settle: {previous}")

    def close(self):
        self._pump.close()


@pytest.fixture(scope="module")
def matrix(tmp_path_factory):
    out = tmp_path_factory.mktemp("fault_matrix")
    url_a, url_b = bus_urls(7400)
    key_path = out / "uplink.key"
    generate_key_file(key_path)
    common = ["--scenario-text", SCENARIO_TEXT, "--uplink-key", str(key_path)]
    listener = _Listener(url_a, url_b)
    processes = []

    def start(args, name):
        process = CliProcess(args, out / f"{name}.log")
        processes.append(process)
        return process

    def relay(name, faults):
        process = start(["link-relay", "--in-url", url_a, "--out-url", url_b, "--link", faults,
                         "--report", str(out / f"{name}.json")], name)
        process.wait_for("ready", PROCESS_TEST_TIMEOUT_S)
        return process

    cases = {}
    try:
        onboard = start(["onboard", "--lcm-url", url_b, "--duration", "900", "--out", str(out)]
                        + common, "onboard")
        onboard.wait_for("onboard: listening", PROCESS_TEST_TIMEOUT_S)
        deadline = time.monotonic() + PROCESS_TEST_TIMEOUT_S
        while listener.status is None and time.monotonic() < deadline:
            time.sleep(0.1)
        assert listener.status is not None, "no onboard telemetry"
        for index, (name, (faults, _, _)) in enumerate(CASES.items()):
            before = listener.settled_counts()
            arrivals_before = len(listener.arrivals)
            relays = [relay(f"relay{index}", faults)]
            # The outage case runs longer: packets after the link comes back must remain.
            duration = GROUND_S + (3.0 if name.startswith("outage") else 0.0)
            ground = start(["ground", "--lcm-url", url_a, "--duration", str(duration),
                            "--resume-wait", "5"] + common, f"ground{index}")
            ground.wait_for("ground: publishing", PROCESS_TEST_TIMEOUT_S)
            if name.startswith("onboard stalls"):
                # The onboard process is frozen (as by the scheduler of a loaded machine) and
                # then catches up with the wall clock: the packets that waited in its socket
                # reach the receiver in one poll.
                time.sleep(2.0)
                onboard.send_signal(signal.SIGSTOP)
                time.sleep(0.8)
                onboard.send_signal(signal.SIGCONT)
            back_at = None
            if name.startswith("outage"):
                time.sleep(2.0)
                assert relays[0].stop() == 0           # the link goes down ...
                time.sleep(2.0)
                relays.append(relay(f"relay{index}b", faults))   # ... and comes back
                back_at = time.monotonic()             # (a loaded machine starts it slowly)
            assert ground.wait(timeout=PROCESS_TEST_TIMEOUT_S) == 0, \
                ground.log_path.read_text()
            time.sleep(2.5)                            # the relay's queue drains (delay 1.5 s)
            for process in relays:
                assert process.stop() == 0, process.log_path.read_text()
            reports = [json.loads((out / f"relay{index}{suffix}.json").read_text())["uplink"]
                       for suffix in ("", "b")[:len(relays)]]
            sessions = {key[0] for key in listener.arrivals[arrivals_before:]}
            cases[name] = dict(before=before, after=listener.settled_counts(), reports=reports,
                               sessions=sessions,
                               relay_back_at=back_at)
        assert onboard.stop(timeout_s=PROCESS_TEST_TIMEOUT_S) == 0, \
            onboard.log_path.read_text()
    finally:
        listener.close()
        for process in processes:
            if process.poll() is None:
                process.kill()
    accepted = read_rows(out / "onboard_commands.csv")        # count, session, seq, t, q…
    guard = read_rows(out / "onboard_guard.csv")              # command, t, mode, outcome, q…
    return dict(cases=cases, accepted=accepted, guard=guard, listener=listener,
                scenario=LoadScenario(scenario_text=SCENARIO_TEXT), out=out)


def _oracle_accepted(arrivals):
    """In arrival order, the packets newer than every packet before them."""
    newest, accepted = None, []
    for key in arrivals:
        if newest is None or key > newest:
            accepted.append(key)
            newest = key
    return accepted


@pytest.mark.parametrize("name", list(CASES))
def test_every_forwarded_packet_was_examined_and_exactly_the_newer_ones_accepted(matrix, name):
    case = matrix["cases"][name]
    _, fault_count, gap_free = CASES[name]
    delta = {field: case["after"][field] - case["before"][field] for field in COUNT_FIELDS}
    forwarded = sum(report["forwarded"] for report in case["reports"])
    relay = {field: sum(report[field] for report in case["reports"])
             for field in ("received", "lost", "duplicated", "reordered")}
    print(f"\n{name}: relay {relay}, forwarded {forwarded}; onboard accepted "
          f"{delta['accepted_count']}, duplicate {delta['dropped_duplicate_count']}, stale "
          f"{delta['dropped_stale_count']}")
    # Every packet on the onboard bus reached the receiver: none lost in the subscriber.
    assert forwarded == (delta["accepted_count"] + delta["dropped_duplicate_count"]
                         + delta["dropped_stale_count"]), (name, delta, case["reports"])
    assert delta["rejected_invalid_count"] == delta["rejected_auth_count"] == 0
    assert delta["rejected_session_count"] == 0    # every ground addressed the robot right
    assert delta["undecodable_count"] == 0
    if fault_count is not None:
        assert sum(report[fault_count] for report in case["reports"]) > 0, case["reports"]
    # The accepted commands of this case are the oracle's, bit for bit what was sent.
    listener, accepted = matrix["listener"], matrix["accepted"]
    assert len(case["sessions"]) == 1, case["sessions"]
    session = next(iter(case["sessions"]))
    arrivals = [key for key in listener.arrivals if key[0] <= session]
    expected = [key for key in _oracle_accepted(arrivals) if key[0] == session]
    mine = accepted[accepted[:, 1] == session]
    # The log has a row per receiver poll that accepted packets: the newest of them, with the
    # running count (several packets accepted in one poll, a burst, make it jump).
    taken = [int(count) - case["before"]["accepted_count"] - 1 for count in mine[:, 0]]
    assert delta["accepted_count"] == len(expected) == taken[-1] + 1, (name, taken)
    assert taken == sorted(set(taken)), (name, taken)
    assert [(int(s), int(k)) for s, k in mine[:, 1:3]] == [expected[i] for i in taken]
    assert len(expected) >= (4 if name.startswith("outage") else 10), name
    for row in mine:
        np.testing.assert_array_equal(row[4:], listener.sent[(int(row[1]), int(row[2]))])
    if name == "outage 2 s":
        assert len(case["reports"]) == 2          # a second relay after the outage
        sent = [key for key in listener.sent if key[0] == session]
        assert len(sent) - len(expected) >= 4     # the packets of the 2 s outage are gone
        # Measured, not assumed: packets the ground sent a second or more after the second
        # relay was up reached the robot too (every forwarded packet was examined: the sum
        # over both relays, above). A slowly starting relay may have seen none.
        later = [key for key in sent if listener.sent_at[key] > case["relay_back_at"] + 1.0]
        if later:
            assert case["reports"][1]["forwarded"] > 0, (later, case["reports"])
    bursts = [i for i in range(1, len(taken)) if taken[i] - taken[i - 1] > 1]
    timeout_s = matrix["scenario"].link_guard.timeout_s
    late = [i for i in range(1, len(taken)) if mine[i, 3] - mine[i - 1, 3] > timeout_s]
    if name.startswith("onboard stalls"):
        # The premise: the packets that waited for the frozen process were accepted together.
        assert bursts, (name, taken)
    if gap_free:
        # Nothing accepted was lost on the way to the robot: once the guard has joined this
        # ground's stream (it may start while the robot still ramps down from the case
        # before), every accepted packet is commanded in the poll it arrives, in TRACK,
        # within the re-join tolerance (bit for bit where the guard reproduces the stream).
        # Except after a timing gap the link did not make: a burst (packets accepted in one
        # poll: the onboard process fell behind the wall clock and caught up) or a packet
        # later than the guard's timeout (the ground fell behind) is a gap in the command
        # sequence, which the guard rightly joins through its limiter (or stops, then
        # joins: LinkGuard's TRACK rule) until it reproduces the stream again.
        guard = matrix["guard"]          # command, t, mode, outcome, distance, q…
        tolerance = matrix["scenario"].link_guard.rejoin_tolerance_rad
        # passed: commanded in the poll it arrived, in TRACK; close: also within the
        # re-join tolerance; exact: bit for bit.
        passed, close, exact = [], [], 0
        for row in mine:
            at = np.flatnonzero(np.abs(guard[:, 1] - row[3]) < 1e-6)
            passed.append(at.size == 1 and int(guard[at[0], 2]) == MODE_TRACK)
            close.append(passed[-1] and np.max(np.abs(guard[at[0], 5:] - row[4:])) <= tolerance)
            exact += at.size == 1 and np.array_equal(guard[at[0], 5:], row[4:])
        first = close.index(True) if True in close else len(close)
        excused = set()
        for gap in sorted(bursts + late):
            back = next((i for i in range(gap + 1, len(passed)) if passed[i]), len(passed))
            excused.update(range(gap, back))
        unexcused = [i for i in range(first, len(passed)) if i not in excused]
        assert all(passed[i] for i in unexcused), (name, passed, bursts, late)
        # Judged against the timing this run got. With no timing gap, every packet after the
        # join is also within the re-join tolerance (bit for bit where the guard reproduces
        # the stream), and there are at least 10. After a gap the guard catches up with the
        # stream through its limiter for as long as the stream needs (the distance closes
        # but need not be monotone), so only "commanded at once, in TRACK" is asserted.
        if not (bursts or late):
            assert all(close[first:]), (name, close)
            assert sum(close) >= 10, (name, close)
        print(f"{name}: {sum(passed)} of {len(passed)} accepted packets commanded at once in "
              f"TRACK, {sum(close)} of them within {tolerance} rad, {exact} bit for bit (the "
              f"first {first} joined through the limiter; timing gaps: bursts at {bursts}, "
              f"late at {late}, then {len(excused)} joined)")


def test_nothing_unsafe_reached_the_robot_in_any_case(matrix):
    scenario = matrix["scenario"]
    arm = scenario.arm_description
    guard = matrix["guard"]
    q = guard[:, 5:]
    assert len(q) > 100
    assert np.all(np.isfinite(q))
    assert np.all(q >= arm.joint_lower_rad) and np.all(q <= arm.joint_upper_rad)
    # No stop fell back to the hold, and so the whole command sequence of the run (eight
    # cases, eight grounds, the ramp-downs between them) is within the FD limits.
    outcomes = {STOP_OUTCOMES[int(v)] for v in guard[:, 3]}
    assert outcomes <= {"none", "stop"}, outcomes
    ratio = fd_limits_ratio(q, scenario.uplink.period_s,
                            scenario.smoother.max_acceleration_rad_per_s2,
                            scenario.smoother.max_jerk_rad_per_s3)
    print(f"fault matrix through processes: {len(q)} commands, FD ratios {ratio}")
    assert ratio.acceleration <= 1 + 1e-6 and ratio.jerk <= 1 + 1e-6, ratio
