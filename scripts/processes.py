"""`telesmooth ground` and `telesmooth onboard`: the two processes of the LCM split.

Ground: haptic source (or a live device on TELEOP_HAPTIC_COMMAND) → … → 4 Hz uplink, published
on TELEOP_JOINT_COMMAND (+ TELEOP_COLLISION_EVENT). Onboard: TELEOP_JOINT_COMMAND → validated
hold → flexible-joint plant → ONBOARD_JOINT_STATUS. Both run against the wall clock by default
(``--realtime 1``) so they stay in step; each writes what it sent or received to ``--out``.
"""

from __future__ import annotations

import csv
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


def _advance(simulator, duration_s: float, realtime: float, name: str) -> float:
    if realtime > 0:
        simulator.set_target_realtime_rate(realtime)
    simulator.Initialize()
    start = time.perf_counter()
    steps = max(1, int(np.ceil(duration_s)))
    for step in range(1, steps + 1):
        simulator.AdvanceTo(min(duration_s, step) + (1e-9 if step == steps else 0.0))
        _log(f"{name}: {simulator.get_context().get_time():6.2f} / {duration_s:.2f} s "
             f"(wall {time.perf_counter() - start:5.1f} s)")
    return time.perf_counter() - start


def _write_rows(path: Path, header, rows) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(header)
        for row in rows:
            writer.writerow([repr(float(v)) for v in row])


def run_ground(scenario, *, lcm_url: str, duration_s: float | None, realtime: float,
               out: Path | None) -> int:
    from pydrake.lcm import DrakeLcm
    from pydrake.systems.analysis import Simulator

    from telesmooth.diagrams.simulation import run_duration_s
    from telesmooth.diagrams.teleoperation import MakeGroundDiagram, uplink_packets

    lcm = DrakeLcm(_check_url(lcm_url))
    handles = MakeGroundDiagram(scenario, lcm=lcm)
    duration_s = run_duration_s(scenario, handles.ground.recording, duration_s)
    _log(f"ground: publishing on {lcm_url} for {duration_s:.2f} s")
    simulator = Simulator(handles.diagram)
    _advance(simulator, duration_s, realtime, "ground")
    if out is not None:
        context = simulator.get_context()
        seq, times, states = uplink_packets(handles, context)
        n = len(handles.ground.joint_names)
        rows = [[k, t, *state[:n]] for k, t, state in zip(seq, times, states)]
        _write_rows(Path(out) / "ground_commands.csv",
                    ["seq", "send_t"] + [f"q_{j}" for j in handles.ground.joint_names], rows)
    return 0


def run_onboard(scenario, *, lcm_url: str, duration_s: float, realtime: float,
                out: Path | None) -> int:
    from pydrake.lcm import DrakeLcm
    from pydrake.systems.analysis import Simulator

    from telesmooth.diagrams.teleoperation import MakeOnboardDiagram, first_sample_indices

    lcm = DrakeLcm(_check_url(lcm_url))
    handles = MakeOnboardDiagram(scenario, lcm=lcm)
    _log(f"onboard: listening on {lcm_url} for {duration_s:.2f} s")
    simulator = Simulator(handles.diagram)
    _advance(simulator, duration_s, realtime, "onboard")
    if out is not None:
        context = simulator.get_context()
        names = handles.onboard.arm.joint_names
        seq_log = handles.logs["last_command_seq"].FindLog(context)
        seq = seq_log.data()[0]
        commanded = handles.logs["q_commanded"].FindLog(context).data().T
        rows = [[seq[i], seq_log.sample_times()[i], *commanded[i]]
                for i in first_sample_indices(seq)]
        _write_rows(Path(out) / "onboard_commands.csv",
                    ["seq", "received_t"] + [f"q_{j}" for j in names], rows)
        telemetry = handles.logs["q_link"].FindLog(context)
        tool = handles.logs["position_measured"].FindLog(context).data().T
        _write_rows(Path(out) / "onboard_telemetry.csv",
                    ["t"] + [f"q_link_{j}" for j in names] + ["tool_x", "tool_y", "tool_z"],
                    ([t, *q, *p] for t, q, p in zip(telemetry.sample_times(),
                                                    telemetry.data().T, tool)))
    return 0
