"""`telesmooth ground` and `telesmooth onboard`: the two processes of the LCM split.

Ground: haptic source (or a live device on TELEOP_HAPTIC_COMMAND) → … → 4 Hz uplink, published
on TELEOP_JOINT_COMMAND (+ TELEOP_COLLISION_EVENT). Onboard: TELEOP_JOINT_COMMAND → validated
hold → flexible-joint plant → ONBOARD_JOINT_STATUS. Both run against the wall clock by default
(``--realtime 1``) so they stay in step; each writes what it sent or received to ``--out``.
"""

from __future__ import annotations

import csv
import dataclasses
import json
import math
import signal
import time
from pathlib import Path
from typing import NamedTuple

import numpy as np

from telesmooth.scripts.formatting import log as _log

__all__ = ["RobotTelemetry", "ground_start_time", "onboard_report", "robot_telemetry",
           "run_ground", "run_onboard"]


def _check_url(url: str) -> str:
    if url.startswith("udpm://") and "ttl=0" not in url:
        _log(f"warning: LCM URL {url!r} has no ttl=0: traffic may leave this host")
    return url


def _advance(simulator, duration_s: float, realtime: float, name: str, status=None,
             start_at=None) -> float:
    """Runs to ``duration_s`` in 0.25 s slices, printing progress (and ``status()``, if
    given) every second. SIGINT or SIGTERM ends the run early but cleanly: the slice in
    progress finishes and the caller writes its logs as after a full run (up to that time).
    A second signal interrupts at once (KeyboardInterrupt, no logs). ``start_at(now)``:
    the ``time.monotonic()`` instant at which to start the clock (t = 0), waited for; None
    starts at once."""
    if realtime > 0:
        simulator.set_target_realtime_rate(realtime)
    simulator.Initialize()
    if start_at is not None:
        delay = start_at(time.monotonic()) - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        simulator.ResetStatistics()   # the real-time pacing counts t = 0 from now
    stopped_by = []

    def on_signal(signum, _frame):
        if stopped_by:   # a second signal: stop at once (e.g. a slice that hangs)
            raise KeyboardInterrupt(f"{name}: second {signal.Signals(signum).name}")
        stopped_by.append(signal.Signals(signum).name)

    previous = {signum: signal.signal(signum, on_signal)
                for signum in (signal.SIGINT, signal.SIGTERM)}
    start = time.perf_counter()
    slice_s = 0.25
    steps = max(1, int(np.ceil(duration_s / slice_s - 1e-9)))
    try:
        for step in range(1, steps + 1):
            if stopped_by:
                _log(f"{name}: {stopped_by[0]} at t = {simulator.get_context().get_time():.2f}"
                     f" s; stopping early")
                break
            simulator.AdvanceTo(min(duration_s, step * slice_s)
                                + (1e-9 if step == steps else 0.0))
            if step % 4 == 0 or step == steps:
                extra = "" if status is None else f"; {status()}"
                _log(f"{name}: {simulator.get_context().get_time():6.2f} / {duration_s:.2f} s "
                     f"(wall {time.perf_counter() - start:5.1f} s){extra}")
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)
    return time.perf_counter() - start


def _with_authentication(scenario, uplink_key):
    """The scenario with the receiver's authentication on when there is a key, else off."""
    mode = "off" if uplink_key is None else "required"
    return dataclasses.replace(scenario, command_receiver=dataclasses.replace(
        scenario.command_receiver, authentication=mode))


class RobotTelemetry(NamedTuple):
    """What a ground process reads from the robot before it starts."""

    pose: np.ndarray        # the robot's commanded pose, rad
    onboard_epoch: int      # the robot's epoch (its commands must carry it)
    last_session: int       # the session of the last command it accepted (0: none)
    clock_offset_s: float = math.nan   # time.monotonic() − the robot's clock (its utime):
    # the smallest difference over the messages read, i.e. the link's latency at its least


def robot_commanded_pose(lcm_url: str, scenario, wait_s: float):
    """The robot's commanded pose from its telemetry (``robot_telemetry``), or None."""
    telemetry = robot_telemetry(lcm_url, scenario, wait_s)
    return None if telemetry is None else telemetry.pose


def robot_telemetry(lcm_url: str, scenario, wait_s: float) -> RobotTelemetry | None:
    """The robot's commanded pose, epoch and last accepted session from its telemetry
    (ONBOARD_JOINT_STATUS), or None if no valid telemetry arrives within ``wait_s`` (finite,
    the arm's joint count, within its joint limits)."""
    import lcm as lcm_module

    from telesmooth.lcm_types import decode_exact, lcmt_onboard_joint_status
    from telesmooth.lcm_types.channels import ONBOARD_JOINT_STATUS

    arm = scenario.arm_description
    found = []
    offsets = []

    def handle(_channel, data):
        arrival = time.monotonic()
        try:
            msg = decode_exact(lcmt_onboard_joint_status, data)
        except Exception:  # noqa: BLE001 - garbage on the channel is not telemetry
            return
        q = np.asarray(msg.joint_position_commanded, dtype=float)
        if q.shape == (arm.num_joints,) and np.all(np.isfinite(q)) and np.all(
                q >= arm.joint_lower_rad) and np.all(q <= arm.joint_upper_rad):
            offsets.append(arrival - msg.utime * 1e-6)
            found.append(RobotTelemetry(q, int(msg.onboard_epoch),
                                        int(msg.last_command_session_id)))

    bus = lcm_module.LCM(lcm_url)
    subscription = bus.subscribe(ONBOARD_JOINT_STATUS, handle)
    deadline = time.monotonic() + wait_s
    try:
        while not found and time.monotonic() < deadline:
            bus.handle_timeout(max(1, int(1000 * min(0.1, deadline - time.monotonic()))))
        # A few more messages (0.3 s) for the robot's clock: the least latency among them.
        settle = time.monotonic() + PHASE_SAMPLE_S
        while found and time.monotonic() < settle:
            bus.handle_timeout(max(1, int(1000 * min(0.05, settle - time.monotonic()))))
    finally:
        bus.unsubscribe(subscription)
    if not found:
        return None
    return found[-1]._replace(clock_offset_s=min(offsets))


PHASE_SAMPLE_S = 0.3
"""How long the ground reads the robot's telemetry for its clock before it starts, s."""


def ground_start_time(telemetry: RobotTelemetry, scenario, *, now: float) -> float:
    """When (``time.monotonic()``) the ground should start its clock so that each packet,
    published ``publish_offset_s`` after a tick, reaches the robot half a receiver poll
    before the robot's next poll: every packet is then taken by the same poll relative to
    its tick, whatever a few milliseconds of latency jitter do (started at an arbitrary
    instant, a packet that arrives near a poll is taken by one poll or the next, which moves
    the robot's ramp by a poll period: measured, up to 1.5 mm on Defaults).

    The robot's polls are at whole multiples of its ``poll_period_s`` on its clock, and its
    telemetry is published ``publish_offset_s`` after a poll; ``telemetry.clock_offset_s``
    maps its clock onto ``time.monotonic()``. Returns the first such instant at least one
    poll after ``now``; ``now`` itself without a clock offset."""
    if not math.isfinite(telemetry.clock_offset_s):
        return now
    poll = scenario.command_receiver.poll_period_s
    # A poll of the robot, on this clock: its telemetry's utime − the publish offset.
    phase = (telemetry.clock_offset_s + poll / 2.0 - scenario.publish_offset_s) % poll
    start = now + poll - ((now - phase) % poll)
    return start if start >= now + poll else start + poll


def _write_rows(path: Path, header, rows) -> None:
    from telesmooth.atomic_files import atomic_write

    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_write(path, "w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(header)
        for row in rows:
            writer.writerow([repr(float(v)) for v in row])


def run_ground(scenario, *, lcm_url: str, duration_s: float | None, realtime: float,
               out: Path | None, uplink_key: bytes | None = None,
               resume_wait_s: float = 0.0) -> int:
    """The ground process. Its commands carry the robot's epoch and a session after the one
    the robot accepted last, both from the robot's telemetry (:mod:`telesmooth.link.session`;
    until telemetry arrives nothing is addressed to the robot); with ``resume_wait_s`` > 0 it
    first waits for that telemetry and starts from the robot's commanded pose (no jump on
    restart)."""
    from pydrake.lcm import DrakeLcm
    from pydrake.systems.analysis import Simulator

    from telesmooth.diagrams.simulation import run_duration_s
    from telesmooth.diagrams.teleoperation import MakeGroundDiagram, uplink_packets
    from telesmooth.link.session import new_ground_nonce, next_session, session_counter
    from telesmooth.systems.link_guard import GUARD_MODES
    from telesmooth.systems.link_monitor import LINK_STATUSES

    _check_url(lcm_url)
    nonce = new_ground_nonce()
    epoch, session_id = 0, 0
    telemetry = None
    if resume_wait_s > 0:
        telemetry = robot_telemetry(lcm_url, scenario, resume_wait_s)
        if telemetry is None:
            _log(f"ground: no robot telemetry within {resume_wait_s:.1f} s; starting from the "
                 "scenario's initial pose")
        else:
            pose = telemetry.pose
            _log(f"ground: resuming from the robot's commanded pose {np.round(pose, 6).tolist()}")
            scenario = dataclasses.replace(
                scenario, initial_position_rad=tuple(float(v) for v in pose))
            epoch = telemetry.onboard_epoch
            session_id = next_session(telemetry.last_session, nonce) if epoch else 0
    lcm = DrakeLcm(lcm_url)
    handles = MakeGroundDiagram(scenario, lcm=lcm, session_id=session_id,
                                uplink_key=uplink_key, session_nonce=nonce,
                                onboard_epoch=epoch)
    duration_s = run_duration_s(scenario, handles.ground.recording, duration_s)
    _log(f"ground: publishing on {lcm_url} for {duration_s:.2f} s (ground run {nonce:08x}, "
         f"{'signed' if uplink_key is not None else 'UNSIGNED'}; robot epoch "
         + (f"{epoch:013x}, session counter {session_counter(session_id)})" if epoch else
            "not seen yet: commands are withheld until its telemetry arrives)"))
    simulator = Simulator(handles.diagram)
    monitor = handles.diagram.GetSubsystemByName("link_monitor")

    def link_text():
        context = monitor.GetMyContextFromRoot(simulator.get_context())

        def value(name):
            return monitor.GetOutputPort(name).Eval(context)

        status = LINK_STATUSES[int(value("link_status")[0])]
        counts = value("onboard_counts").astype(int)
        age = value("telemetry_age")[0]
        mode = int(value("onboard_guard_mode")[0])
        robot = ("robot: no telemetry" if mode < 0 else
                 f"robot {GUARD_MODES[mode]}, {value('stream_distance')[0]:.4f} rad from the "
                 "accepted stream")
        mine, theirs = int(value("session_id")[0]), int(value("robot_session")[0])
        if mode >= 0 and theirs != mine and session_counter(theirs) >= session_counter(mine):
            robot += "; it follows ANOTHER ground session"
        return (f"link {status}; {robot} (telemetry age {age:.2f} s, unacknowledged "
                f"{int(value('unacknowledged')[0])}, onboard accepted {counts[0]}, rejected "
                f"invalid/auth/session {counts[1]}/{counts[2]}/{counts[6]}, dropped "
                f"duplicate/stale {counts[3]}/{counts[4]}, undecodable {counts[5]})")

    start_at = None
    if telemetry is not None and realtime == 1.0:
        # Packets reach the robot half a poll before its next poll (ground_start_time; the
        # robot's clock maps onto this one only when both run at the wall clock's rate).
        def start_at(now):
            return ground_start_time(telemetry, scenario, now=now)
    wall = _advance(simulator, duration_s, realtime, "ground", status=link_text,
                    start_at=start_at)
    if out is not None:
        from telesmooth.scripts.process_report import write_ground_report

        context = simulator.get_context()
        seq, times, states = uplink_packets(handles, context)
        n = len(handles.ground.joint_names)
        rows = [[k, t, *state[:n]] for k, t, state in zip(seq, times, states)]
        _write_rows(Path(out) / "ground_commands.csv",
                    ["seq", "send_t"] + [f"q_{j}" for j in handles.ground.joint_names], rows)
        write_ground_report(
            Path(out), handles, context, wall_time_s=wall,
            extra={"lcm_url": lcm_url,
                   "signing": "signed" if uplink_key is not None else "UNSIGNED"})
    return 0


def run_onboard(scenario, *, lcm_url: str, duration_s: float, realtime: float,
                out: Path | None, uplink_key: bytes | None = None) -> int:
    """The onboard process; with ``uplink_key`` only authentic commands are accepted, and
    only those addressed to this run's fresh random epoch (announced in the telemetry)."""
    from pydrake.lcm import DrakeLcm

    from telesmooth.diagrams.teleoperation import MakeOnboardDiagram
    from telesmooth.lcm_types.channels import TELEOP_JOINT_COMMAND
    from telesmooth.link.session import new_epoch
    from telesmooth.link.udpm_receiver import UdpmReceiver
    from telesmooth.systems.flexible_arm import MakeSimulator
    from telesmooth.systems.laser_tracker import tracker_record
    from telesmooth.systems.link_guard import GUARD_MODES

    scenario = _with_authentication(scenario, uplink_key)
    lcm = DrakeLcm(_check_url(lcm_url))
    # The uplink through a socket of our own with a sized receive buffer, which counts what
    # the kernel drops (DrakeLcm's subscription keeps one packet, an lcm.LCM subscription drops
    # a burst beyond its queue, both uncounted). memq:// is per instance: there DrakeLcm.
    uplink_lcm = (UdpmReceiver(lcm_url, TELEOP_JOINT_COMMAND) if lcm_url.startswith("udpm://")
                  else None)
    if uplink_lcm is not None:
        _log(f"onboard: uplink receive buffer {uplink_lcm.receive_buffer_bytes} bytes")
    epoch = new_epoch()
    handles = MakeOnboardDiagram(scenario, lcm=lcm, uplink_key=uplink_key,
                                 uplink_lcm=uplink_lcm, onboard_epoch=epoch)
    _log(f"onboard: listening on {lcm_url} for {duration_s:.2f} s (authentication "
         f"{scenario.command_receiver.authentication}, epoch {epoch:013x})")
    simulator = MakeSimulator(handles.diagram, scenario.onboard)
    receiver, guard = handles.onboard.receiver, handles.onboard.guard
    subscriber = handles.diagram.GetSubsystemByName("joint_command_subscriber")

    def dropped(root) -> float:
        context = subscriber.GetMyContextFromRoot(root)
        return float(subscriber.get_dropped_count_output_port().Eval(context)[0])

    def link_text():
        root = simulator.get_context()
        context = receiver.GetMyContextFromRoot(root)
        counts = receiver.rejection_counts(context)
        guard_context = guard.GetMyContextFromRoot(root)
        mode = GUARD_MODES[int(guard.get_guard_mode_output_port().Eval(guard_context)[0])]
        distance = guard.get_stream_distance_output_port().Eval(guard_context)[0]
        last = receiver.get_last_rejection_output_port().Eval(context)
        lost = dropped(root)
        return (f"guard {mode}, {distance:.4f} rad from the accepted stream; packets "
                + ", ".join(f"{k} {v}" for k, v in counts.items())
                + ("" if lost != lost else f", lost before decoding {int(lost)}")
                + (f"; last rejection: {last}" if last else ""))

    wall = _advance(simulator, duration_s, realtime, "onboard", status=link_text)
    if out is not None:
        context = simulator.get_context()
        names = handles.onboard.arm.joint_names
        write_onboard_logs(Path(out), handles, context, names)
        counts = dict(receiver.rejection_counts(receiver.GetMyContextFromRoot(context)))
        lost = dropped(context)
        counts["lost_before_decoding"] = None if lost != lost else int(lost)
        from telesmooth.atomic_files import write_text

        write_text(Path(out) / "onboard_counts.json", json.dumps(counts, indent=1))
        report = onboard_report(handles, context)
        report["onboard_epoch"] = epoch
        report["packets"] = counts
        write_text(Path(out) / "onboard_report.json", json.dumps(report, indent=1) + "\n")
        shares = report["time_in_mode_s"]
        _log(f"onboard: guard tracked the stream on {100 * report['tracking_share']:.1f} % of "
             f"its ticks from 1 s after the first packet to the last "
             f"({report['ticks_counted']} ticks); time per mode "
             + ", ".join(f"{k} {v:.2f} s" for k, v in shares.items())
             + f"; distance to the accepted stream max {report['stream_distance_rad']['max']:.4f}"
             f" rad, mean {report['stream_distance_rad']['mean']:.4f} rad")
        tracker = tracker_record(handles.logs["tracker"].FindLog(context).data().T)
        _write_rows(Path(out) / "onboard_telemetry.csv",
                    ["t"] + [f"q_link_{j}" for j in names] + ["tool_x", "tool_y", "tool_z"],
                    ([t, *q, *p] for t, q, p in zip(tracker.t_s, tracker.q_link,
                                                    tracker.tool_position_m)))
        from telesmooth.scripts.process_report import write_onboard_report

        write_onboard_report(
            Path(out), handles, context, wall_time_s=wall,
            extra={"authentication": scenario.command_receiver.authentication,
                   "onboard_epoch": epoch, "packets": counts})
    return 0


def write_onboard_logs(out: Path, handles, context, names) -> None:
    """onboard_commands.csv: one row per receiver poll that accepted commands (count, session,
    seq, time, q of the newest of them; ``accepted`` is the running count, so a poll that
    accepted a burst of k packets, e.g. after the process fell behind the wall clock, makes it
    jump by k);
    onboard_guard.csv: one row per guard command (count, time, mode, stop outcome of the last
    stop plan, the distance of the command to the newest accepted packet in rad, q) — what
    reached the robot's interpolator. Modes and outcomes are indices in ``GUARD_MODES`` and
    ``STOP_OUTCOMES``;
    onboard_ticks.csv: one row per guard tick (every period_s): time, mode, distance to the
    accepted stream (rad), packets accepted so far."""
    from telesmooth.diagrams.teleoperation import first_sample_indices

    logs = handles.logs
    count_log = logs["accepted_count"].FindLog(context)
    count = count_log.data()[0]
    session = logs["last_command_session"].FindLog(context).data()[0]
    seq = logs["last_command_seq"].FindLog(context).data()[0]
    accepted = logs["q_accepted"].FindLog(context).data().T
    rows = [[count[i], session[i], seq[i], count_log.sample_times()[i], *accepted[i]]
            for i in first_sample_indices(count) if count[i] > 0]
    _write_rows(out / "onboard_commands.csv",
                ["accepted", "session_id", "seq", "received_t"] + [f"q_{j}" for j in names],
                rows)
    guard_log = logs["guard_command_count"].FindLog(context)
    guard_count = guard_log.data()[0]
    mode = logs["guard_mode"].FindLog(context).data()[0]
    outcome = logs["guard_stop_outcome"].FindLog(context).data()[0]
    distance = logs["guard_stream_distance"].FindLog(context).data()[0]
    commanded = logs["guard_q_commanded"].FindLog(context).data().T
    rows = [[guard_count[i], guard_log.sample_times()[i], mode[i], outcome[i], distance[i],
             *commanded[i]] for i in first_sample_indices(guard_count)]
    _write_rows(out / "onboard_guard.csv",
                ["command", "t", "mode", "stop_outcome", "stream_distance_rad"]
                + [f"q_{j}" for j in names], rows)
    # onboard_ticks.csv: the guard at each of its ticks (every period_s): time, mode, the
    # distance to the accepted stream, packets accepted so far.
    times = logs["guard_mode"].FindLog(context).sample_times()
    period = handles.scenario.link_guard.period_s
    ticks = np.searchsorted(times, np.arange(0.0, times[-1] + 1e-9, period) - 1e-9) \
        if len(times) else np.zeros(0, dtype=int)
    _write_rows(out / "onboard_ticks.csv", ["t", "mode", "stream_distance_rad", "accepted"],
                ([times[i], mode[i], distance[i], count[i]] for i in ticks))


def onboard_report(handles, context) -> dict:
    """What the onboard guard did, from its logs (one sample per poll):

    * ``time_in_mode_s``: seconds per guard mode over the whole run;
    * ``tracking_share``: the share of the guard's ticks (one per period_s) in TRACK from
      1 s after the first accepted packet to the last accepted packet (while a ground was
      sending; ``ticks_counted`` of them), the figure the two-process test judges;
    * ``stream_distance_rad``: max, mean and 95th percentile over the same window of the
      distance between the robot's command and the newest accepted packet;
    * ``commands``, ``stops``: commands issued, and how many stops the guard planned (by
      outcome)."""
    from telesmooth.safety.stop import STOP_OUTCOMES
    from telesmooth.systems.link_guard import GUARD_MODES

    logs = handles.logs
    scenario = handles.scenario
    poll = scenario.command_receiver.poll_period_s
    period = scenario.link_guard.period_s
    mode_log = logs["guard_mode"].FindLog(context)
    times, mode = mode_log.sample_times(), mode_log.data()[0].astype(int)
    distance = logs["guard_stream_distance"].FindLog(context).data()[0]
    count = logs["accepted_count"].FindLog(context).data()[0]
    outcome = logs["guard_stop_outcome"].FindLog(context).data()[0].astype(int)
    commands = logs["guard_command_count"].FindLog(context).data()[0]
    report = {"time_in_mode_s": {name: float(np.sum(mode == k) * poll)
                                 for k, name in enumerate(GUARD_MODES)},
              "commands": int(commands[-1]) if len(commands) else 0}
    starts = np.flatnonzero((mode[1:] == 1) & (mode[:-1] != 1)) + 1   # entering STOPPING
    fallbacks = np.flatnonzero((mode[1:] == 2) & (mode[:-1] != 2)) + 1
    planned = [int(outcome[i]) for i in np.concatenate([starts, fallbacks]) if outcome[i] > 0]
    report["stops"] = {STOP_OUTCOMES[k]: planned.count(k) for k in sorted(set(planned))}
    accepted = np.flatnonzero(np.diff(np.concatenate([[0.0], count])) > 0)
    if accepted.size == 0:
        report.update(tracking_share=0.0, ticks_counted=0,
                      stream_distance_rad={"max": 0.0, "mean": 0.0, "p95": 0.0})
        return report
    first, last = times[accepted[0]], times[accepted[-1]]
    ticks = np.arange(first + 1.0, last + 1e-9, period)
    rows = np.clip(np.searchsorted(times, ticks), 0, len(times) - 1)
    window = (times >= first) & (times <= last)
    report["tracking_share"] = float(np.mean(mode[rows] == 0)) if rows.size else 0.0
    report["ticks_counted"] = int(rows.size)
    report["first_packet_t_s"], report["last_packet_t_s"] = float(first), float(last)
    report["stream_distance_rad"] = {"max": float(np.max(distance[window])),
                                     "mean": float(np.mean(distance[window])),
                                     "p95": float(np.percentile(distance[window], 95))}
    return report
