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
import signal
import sys
import time
from pathlib import Path

import numpy as np

__all__ = ["run_ground", "run_onboard"]


def _log(message: str) -> None:
    print(message, file=sys.stderr, flush=True)


def _check_url(url: str) -> str:
    if url.startswith("udpm://") and "ttl=0" not in url:
        _log(f"warning: LCM URL {url!r} has no ttl=0: traffic may leave this host")
    return url


def _advance(simulator, duration_s: float, realtime: float, name: str, status=None) -> float:
    """Runs to ``duration_s`` in 0.25 s slices, printing progress (and ``status()``, if
    given) every second. SIGINT or SIGTERM ends the run early but cleanly: the slice in
    progress finishes and the caller writes its logs as after a full run (up to that time).
    A second signal interrupts at once (KeyboardInterrupt, no logs)."""
    if realtime > 0:
        simulator.set_target_realtime_rate(realtime)
    simulator.Initialize()
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


def robot_commanded_pose(lcm_url: str, scenario, wait_s: float):
    """The robot's commanded pose from its telemetry (ONBOARD_JOINT_STATUS), or None if no
    valid telemetry arrives within ``wait_s`` (finite, the arm's joint count, within its
    joint limits)."""
    import lcm as lcm_module

    from telesmooth.diagrams.channels import ONBOARD_JOINT_STATUS
    from telesmooth.lcm_types import decode_exact, lcmt_onboard_joint_status

    arm = scenario.arm_description
    found = []

    def handle(_channel, data):
        try:
            msg = decode_exact(lcmt_onboard_joint_status, data)
        except Exception:  # noqa: BLE001 - garbage on the channel is not telemetry
            return
        q = np.asarray(msg.joint_position_commanded, dtype=float)
        if q.shape == (arm.num_joints,) and np.all(np.isfinite(q)) and np.all(
                q >= arm.joint_lower_rad) and np.all(q <= arm.joint_upper_rad):
            found.append(q)

    bus = lcm_module.LCM(lcm_url)
    subscription = bus.subscribe(ONBOARD_JOINT_STATUS, handle)
    deadline = time.monotonic() + wait_s
    try:
        while not found and time.monotonic() < deadline:
            bus.handle_timeout(max(1, int(1000 * min(0.1, deadline - time.monotonic()))))
    finally:
        bus.unsubscribe(subscription)
    return found[-1] if found else None


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
    """The ground process. Its session id is the wall clock at start (µs), so the robot
    takes a restarted ground process as newer; with ``resume_wait_s`` > 0 it first waits for
    the robot's telemetry and starts from the robot's commanded pose (no jump on restart)."""
    from pydrake.lcm import DrakeLcm
    from pydrake.systems.analysis import Simulator

    from telesmooth.diagrams.simulation import run_duration_s
    from telesmooth.diagrams.teleoperation import MakeGroundDiagram, uplink_packets
    from telesmooth.systems.link_monitor import LINK_STATUSES

    _check_url(lcm_url)
    if resume_wait_s > 0:
        pose = robot_commanded_pose(lcm_url, scenario, resume_wait_s)
        if pose is None:
            _log(f"ground: no robot telemetry within {resume_wait_s:.1f} s; starting from the "
                 "scenario's initial pose")
        else:
            _log(f"ground: resuming from the robot's commanded pose {np.round(pose, 6).tolist()}")
            scenario = dataclasses.replace(
                scenario, initial_position_rad=tuple(float(v) for v in pose))
    session_id = time.time_ns() // 1000
    lcm = DrakeLcm(lcm_url)
    handles = MakeGroundDiagram(scenario, lcm=lcm, session_id=session_id, uplink_key=uplink_key)
    duration_s = run_duration_s(scenario, handles.ground.recording, duration_s)
    _log(f"ground: publishing on {lcm_url} for {duration_s:.2f} s (session {session_id}, "
         f"{'signed' if uplink_key is not None else 'UNSIGNED'})")
    simulator = Simulator(handles.diagram)
    monitor = handles.diagram.GetSubsystemByName("link_monitor")

    def link_text():
        context = monitor.GetMyContextFromRoot(simulator.get_context())
        status = LINK_STATUSES[int(monitor.GetOutputPort("link_status").Eval(context)[0])]
        counts = monitor.GetOutputPort("onboard_counts").Eval(context).astype(int)
        age = monitor.GetOutputPort("telemetry_age").Eval(context)[0]
        return (f"link {status} (telemetry age {age:.2f} s, unacknowledged "
                f"{int(monitor.GetOutputPort('unacknowledged').Eval(context)[0])}, onboard "
                f"accepted {counts[0]}, rejected invalid/auth {counts[1]}/{counts[2]}, dropped "
                f"duplicate/stale {counts[3]}/{counts[4]}, undecodable {counts[5]})")

    _advance(simulator, duration_s, realtime, "ground", status=link_text)
    if out is not None:
        context = simulator.get_context()
        seq, times, states = uplink_packets(handles, context)
        n = len(handles.ground.joint_names)
        rows = [[k, t, *state[:n]] for k, t, state in zip(seq, times, states)]
        _write_rows(Path(out) / "ground_commands.csv",
                    ["seq", "send_t"] + [f"q_{j}" for j in handles.ground.joint_names], rows)
    return 0


def run_onboard(scenario, *, lcm_url: str, duration_s: float, realtime: float,
                out: Path | None, uplink_key: bytes | None = None) -> int:
    """The onboard process; with ``uplink_key`` only authentic commands are accepted."""
    from pydrake.lcm import DrakeLcm
    from pydrake.systems.analysis import Simulator

    from telesmooth.diagrams.teleoperation import MakeOnboardDiagram
    from telesmooth.systems.laser_tracker import tracker_record
    from telesmooth.systems.link_guard import GUARD_MODES

    from telesmooth.diagrams.channels import TELEOP_JOINT_COMMAND
    from telesmooth.link.udpm_receiver import UdpmReceiver

    scenario = _with_authentication(scenario, uplink_key)
    lcm = DrakeLcm(_check_url(lcm_url))
    # The uplink through a socket of our own with a sized receive buffer, which counts what
    # the kernel drops (DrakeLcm's subscription keeps one packet, an lcm.LCM subscription drops
    # a burst beyond its queue, both uncounted). memq:// is per instance: there DrakeLcm.
    uplink_lcm = (UdpmReceiver(lcm_url, TELEOP_JOINT_COMMAND) if lcm_url.startswith("udpm://")
                  else None)
    if uplink_lcm is not None:
        _log(f"onboard: uplink receive buffer {uplink_lcm.receive_buffer_bytes} bytes")
    handles = MakeOnboardDiagram(scenario, lcm=lcm, uplink_key=uplink_key,
                                 uplink_lcm=uplink_lcm)
    _log(f"onboard: listening on {lcm_url} for {duration_s:.2f} s (authentication "
         f"{scenario.command_receiver.authentication})")
    simulator = Simulator(handles.diagram)
    receiver, guard = handles.onboard.receiver, handles.onboard.guard
    subscriber = handles.diagram.GetSubsystemByName("joint_command_subscriber")

    def dropped(root) -> float:
        context = subscriber.GetMyContextFromRoot(root)
        return float(subscriber.get_dropped_count_output_port().Eval(context)[0])

    def link_text():
        root = simulator.get_context()
        context = receiver.GetMyContextFromRoot(root)
        counts = receiver.rejection_counts(context)
        mode = GUARD_MODES[int(guard.get_guard_mode_output_port().Eval(
            guard.GetMyContextFromRoot(root))[0])]
        last = receiver.get_last_rejection_output_port().Eval(context)
        lost = dropped(root)
        return (f"guard {mode}; packets " + ", ".join(f"{k} {v}" for k, v in counts.items())
                + ("" if lost != lost else f", lost before decoding {int(lost)}")
                + (f"; last rejection: {last}" if last else ""))

    _advance(simulator, duration_s, realtime, "onboard", status=link_text)
    if out is not None:
        context = simulator.get_context()
        names = handles.onboard.arm.joint_names
        write_onboard_logs(Path(out), handles, context, names)
        counts = dict(receiver.rejection_counts(receiver.GetMyContextFromRoot(context)))
        lost = dropped(context)
        counts["lost_before_decoding"] = None if lost != lost else int(lost)
        from telesmooth.atomic_files import write_text

        write_text(Path(out) / "onboard_counts.json", json.dumps(counts, indent=1))
        tracker = tracker_record(handles.logs["tracker"].FindLog(context).data().T)
        _write_rows(Path(out) / "onboard_telemetry.csv",
                    ["t"] + [f"q_link_{j}" for j in names] + ["tool_x", "tool_y", "tool_z"],
                    ([t, *q, *p] for t, q, p in zip(tracker.t_s, tracker.q_link,
                                                    tracker.tool_position_m)))
    return 0


def write_onboard_logs(out: Path, handles, context, names) -> None:
    """onboard_commands.csv: one row per receiver poll that accepted commands (count, session,
    seq, time, q of the newest of them; ``accepted`` is the running count, so a poll that
    accepted a burst of k packets, e.g. after the process fell behind the wall clock, makes it
    jump by k);
    onboard_guard.csv: one row per guard command (count, time, mode, stop outcome of the last
    stop plan, q) — what reached the robot's interpolator. Modes and outcomes are indices in
    ``GUARD_MODES`` and ``STOP_OUTCOMES``."""
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
    commanded = logs["guard_q_commanded"].FindLog(context).data().T
    rows = [[guard_count[i], guard_log.sample_times()[i], mode[i], outcome[i], *commanded[i]]
            for i in first_sample_indices(guard_count)]
    _write_rows(out / "onboard_guard.csv",
                ["command", "t", "mode", "stop_outcome"] + [f"q_{j}" for j in names], rows)
