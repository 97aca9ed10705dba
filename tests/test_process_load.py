"""The documented two-process run (docs/link.md) with a CPU-bound process beside it: the
onboard guard tracks.

Exactly the documented commands — ``telesmooth keygen``, ``telesmooth onboard … &``,
``telesmooth ground …`` on the Defaults scenario (a LASA demonstration, Online-CKS) — on a
private udpm bus, with ``python3 -c "while True: pass"`` running beside them. Two
departures, both for a loaded machine: the onboard process runs until this test stops it
(SIGINT; it then writes its logs) instead of for a fixed 40 s, and the ground waits up to 2
minutes for the robot's telemetry (a slow start).

The verdict is judged against the timing the run got, which the test measures rather than
assumes: from the onboard's own log (accepted packets, in its simulation time, the clock the
guard runs on) every gap longer than the guard's timeout is found; there the guard rightly
stops, and the ticks until it is back in TRACK are set aside (the re-join itself must take
at most ``REJOIN_LIMIT_S``, counted up to the next such gap when one comes first). On every
other guard tick from 1 s after the first packet to the last, the guard must be in TRACK on at
least 95 %. The wall-clock arrival of each packet on the bus (this test listens) and the
onboard's real-time factor are printed with it.
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
    CpuHog,
    bus_urls,
    guard_gaps,
    read_rows,
)

from telesmooth.diagrams.scenario import LoadScenario
from telesmooth.lcm_types import lcmt_teleop_joint_command
from telesmooth.lcm_types.channels import TELEOP_JOINT_COMMAND
from telesmooth.systems.link_guard import MODE_TRACK

pytestmark = pytest.mark.process

REQUIRED_SHARE = 0.95
REJOIN_LIMIT_S = 15.0      # the slowest re-join measured on Defaults' packets after 1 s


class _Arrivals(BusPump):
    """Wall-clock arrival of every addressed command on the bus."""

    def __init__(self, url):
        self.times = []
        bus = lcm.LCM(url)
        bus.subscribe(TELEOP_JOINT_COMMAND, self._handle).set_queue_capacity(10_000)
        super().__init__(bus)

    def _handle(self, _channel, data):
        if lcmt_teleop_joint_command.decode(data).seq >= 0:
            self.times.append(time.monotonic())


@pytest.fixture(scope="module")
def loaded_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("loaded_run")
    url, _ = bus_urls(7800)
    key = out / "uplink.key"
    arrivals = _Arrivals(url)
    processes = []
    try:
        with CpuHog():
            keygen = CliProcess(["keygen", str(key)], out / "keygen.log")
            assert keygen.wait(timeout=PROCESS_TEST_TIMEOUT_S) == 0, keygen.log_path.read_text()
            onboard = CliProcess(["onboard", "--duration", "900", "--out", str(out / "onboard"),
                                  "--uplink-key", str(key), "--lcm-url", url],
                                 out / "onboard.log")
            processes.append(onboard)
            onboard.wait_for("onboard: listening", PROCESS_TEST_TIMEOUT_S)
            started = time.monotonic()
            ground = CliProcess(["ground", "--out", str(out / "ground"), "--uplink-key",
                                 str(key), "--lcm-url", url, "--resume-wait", "120"],
                                out / "ground.log")
            processes.append(ground)
            assert ground.wait(timeout=PROCESS_TEST_TIMEOUT_S) == 0, ground.log_path.read_text()
            wall = time.monotonic() - started
            time.sleep(3.0)
            assert onboard.stop(timeout_s=PROCESS_TEST_TIMEOUT_S) == 0, \
                onboard.log_path.read_text()
    finally:
        arrivals.close()
        for process in processes:
            if process.poll() is None:
                process.kill()
    return dict(out=out, arrivals=np.array(arrivals.times), wall_s=wall,
                ground_log=(out / "ground.log").read_text(),
                onboard_log=(out / "onboard.log").read_text())


def test_the_guard_tracks_on_95_percent_of_its_ticks_with_a_cpu_bound_process_beside_it(
        loaded_run):
    out = loaded_run["out"] / "onboard"
    timeout_s = LoadScenario().link_guard.timeout_s
    accepted = read_rows(out / "onboard_commands.csv")     # count, session, seq, t, q…
    ticks = read_rows(out / "onboard_ticks.csv")          # t, mode, distance, accepted
    received = accepted[:, 3]
    first, last = received[0], received[-1]
    # Measured timing: the gaps the guard saw, and the wall-clock ones on the bus.
    gaps = guard_gaps(received, timeout_s)
    sim_gaps = np.diff(received)
    wall_gaps = np.diff(loaded_run["arrivals"])
    t, mode = ticks[:, 0], ticks[:, 1].astype(int)
    window = (t >= first + 1.0) & (t <= last)
    excused = np.zeros_like(window)
    for k, i in enumerate(gaps):
        start, back = received[i], received[i + 1]
        tracking = np.flatnonzero((t > back) & (mode == MODE_TRACK))
        end = t[tracking[0]] if tracking.size else last
        # A new gap before the guard is back restarts its re-join: this one is judged up to
        # there (a starved ground, seen in a fresh clone's run beside other heavy processes:
        # six gaps in 21 s, each stopping the guard again while it closed in).
        interrupted_at = received[gaps[k + 1]] if k + 1 < len(gaps) else np.inf
        end = min(end, interrupted_at)
        assert end - back <= REJOIN_LIMIT_S, (start, back, end)
        excused |= (t > start) & (t <= end)
    counted = window & ~excused
    share = float(np.mean(mode[counted] == MODE_TRACK))
    report = json.loads((out / "onboard_report.json").read_text())
    arrivals = loaded_run["arrivals"]
    print(f"\nREADME run beside a CPU-bound process: {int(np.sum(counted))} guard ticks "
          f"counted ({int(np.sum(window & excused))} set aside after {len(gaps)} gap(s) longer "
          f"than the {timeout_s} s timeout), TRACK on {100 * share:.1f} %; report: "
          f"{100 * report['tracking_share']:.1f} % of {report['ticks_counted']} ticks; time per "
          f"mode {report['time_in_mode_s']}; distance to the stream max "
          f"{report['stream_distance_rad']['max']:.4f} rad, mean "
          f"{report['stream_distance_rad']['mean']:.4f} rad. Packets {len(received)}: gaps "
          f"seen by the guard max {sim_gaps.max():.3f} s ({int(np.sum(sim_gaps > 0.3))} over "
          f"0.3 s), on the bus max {wall_gaps.max():.3f} s ({int(np.sum(wall_gaps > 0.3))} "
          f"over 0.3 s); onboard real-time factor over the run "
          f"{(last - first) / max(arrivals[-1] - arrivals[0], 1e-9):.2f}")
    # A loaded onboard process runs behind the wall clock (its packets then come closer
    # together in its own time, fewer guard ticks): judged on the ticks it had.
    assert np.sum(counted) >= 10, "too few guard ticks to judge"
    assert share >= REQUIRED_SHARE, share
    # Nothing the robot was commanded broke the limits or left the joint limits (the report
    # of the guard's own check), and the user was told how far off the robot was.
    assert "rad from the accepted stream" in loaded_run["ground_log"]
    assert "tracked the stream on" in loaded_run["onboard_log"]


def test_everything_commanded_in_the_loaded_run_is_within_the_limits(loaded_run):
    from telesmooth.systems.link_guard import fd_limits_ratio

    scenario = LoadScenario()
    guard = read_rows(loaded_run["out"] / "onboard" / "onboard_guard.csv")
    q = guard[:, 5:]
    arm = scenario.arm_description
    assert np.all(np.isfinite(q))
    assert np.all(q >= arm.joint_lower_rad) and np.all(q <= arm.joint_upper_rad)
    start = np.tile(q[0], (3, 1))
    ratio = fd_limits_ratio(np.vstack([start, q]), scenario.uplink.period_s,
                            scenario.smoother.max_acceleration_rad_per_s2,
                            scenario.smoother.max_jerk_rad_per_s3)
    # The Defaults ground (Online-CKS) breaks the limits by up to 1.9×; the robot's commands
    # do not.
    assert ratio.acceleration <= 1 + 1e-6 and ratio.jerk <= 1 + 1e-6, ratio
