"""`telesmooth simulate`: run a scenario headless and write the report.

Output folder:
    metrics.json     docs/method.md §6 figures of the sent commands and of the robot's response,
                     and (deployed chain) what the onboard link guard did
    commands.csv     every uplink packet: seq, send time, the operator instant it estimates,
                     position and velocity per joint
    received.csv     (deployed chain) every command the onboard link guard issued: what
                     reached the robot, with the guard's mode
    telemetry.csv    the robot at 100 Hz: link and motor angles, laser-tracker tool position
    targets.csv      the IK joint targets at 100 Hz (the pre-simulator's newest command)
    *.png            joint positions/velocities, acceleration/jerk with limits, end-effector
                     tracks, tracking error over time, σ and the pre-simulator, the guard
    report.md        the figures and a summary, the chain it ran in its first lines
    run.html         (with --meshcat) a self-contained Meshcat replay

The figures and the summary are drawn from a :class:`~telesmooth.diagrams.simulation.
SimulationRecord` by :func:`write_record_report`, which the two processes' reports use too
(:mod:`telesmooth.scripts.process_report`): a record without the operator's targets (the
onboard side) or without the guard's record (the paper's chain) skips what it lacks.
"""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np

from telesmooth.arms.joint_vectors import as_per_joint
from telesmooth.atomic_files import atomic_write, write_text
from telesmooth.diagrams.simulation import (
    SimulationRecord,
    plant_text,
    received_response_errors,
    response_errors,
    run_metrics,
    simulate,
    tool_positions,
)
from telesmooth.scripts.figures import FigureWriter
from telesmooth.scripts.formatting import limit_ratio
from telesmooth.scripts.formatting import log as _log
from telesmooth.smoothing.metrics import finite_differences

__all__ = ["limits_text", "write_received_csv", "write_record_report",
           "write_simulation_report"]


def _write_csv(path: Path, header, rows) -> None:
    with atomic_write(path, "w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(header)
        for row in rows:
            writer.writerow([repr(v) if isinstance(v, float) else v for v in row])


def write_received_csv(out: Path, record: SimulationRecord) -> None:
    """received.csv: every command the onboard link guard issued (what reached the robot's
    interpolator), the poll that issued it, the guard's mode then and the packet it
    followed."""
    from telesmooth.systems.link_guard import GUARD_MODES

    guard, names = record.guard, record.joint_names
    modes = guard.mode[np.searchsorted(guard.poll_t_s, guard.command_t_s)]
    _write_csv(out / "received.csv", ["t", "guard_mode"] + [f"q_{j}" for j in names]
               + [f"packet_q_{j}" for j in names],
               ([float(t), GUARD_MODES[int(mode)]] + [float(v) for v in q]
                + [float(v) for v in p]
                for t, mode, q, p in zip(guard.command_t_s, modes, guard.q_commanded,
                                         guard.q_followed)))


def _write_tables(out: Path, record: SimulationRecord) -> list[str]:
    """The CSV files of a record; returns their names."""
    names = record.joint_names
    n = record.num_joints
    delay = record.scenario.fifo.delay_s
    written = []
    if record.packet_seq is not None:
        rows = []
        for seq, t, state in zip(record.packet_seq, record.packet_t_s, record.packet_state):
            rows.append([int(seq), float(t), float(t - delay)]
                        + [float(v) for v in state[:2 * n]])
        _write_csv(out / "commands.csv", ["seq", "send_t", "sample_t"]
                   + [f"q_{j}" for j in names] + [f"v_{j}" for j in names], rows)
        written.append("commands.csv")
    if record.guard is not None:
        write_received_csv(out, record)
        written.append("received.csv")
    _write_csv(out / "telemetry.csv",
               ["t"] + [f"q_link_{j}" for j in names] + [f"q_motor_{j}" for j in names]
               + ["tool_x", "tool_y", "tool_z"],
               ([float(t)] + [float(v) for v in np.concatenate([a, b, c])]
                for t, a, b, c in zip(record.tracker_t_s, record.q_link, record.q_motor,
                                      record.tool_position_m)))
    written.append("telemetry.csv")
    if record.target_t_s is not None:
        _write_csv(out / "targets.csv", ["t"] + list(names),
                   ([float(t)] + [float(v) for v in q]
                    for t, q in zip(record.target_t_s, record.q_target)))
        written.append("targets.csv")
    return written


def record_limits(record: SimulationRecord):
    """The scenario's acceleration and jerk limits, one per joint of the record's arm."""
    scenario = record.scenario
    n, names = record.num_joints, record.joint_names
    a_max = as_per_joint("a_max", scenario.smoother.max_acceleration_rad_per_s2, n, names,
                         allow_inf=True)
    j_max = as_per_joint("j_max", scenario.smoother.max_jerk_rad_per_s3, n, names,
                         allow_inf=True)
    return a_max, j_max


def _received_sequence(record: SimulationRecord) -> np.ndarray:
    """The guard's command sequence after the robot's rest at its start pose (the sequence
    whose FD values the guard keeps within the limits)."""
    rest = np.tile(record.initial_position_rad, (3, 1))
    return np.vstack([rest, record.guard.q_commanded])


def _joints_figure(plt, writer, record: SimulationRecord, packets: str) -> None:
    scenario = record.scenario
    names = record.joint_names
    n = record.num_joints
    delay = scenario.fifo.delay_s
    has_packets = record.packet_seq is not None and record.packet_seq.size > 0
    velocities = has_packets and bool(np.any(np.isfinite(record.packet_state[:, n:2 * n])))
    fig, axes = plt.subplots(n, 2 if velocities else 1, figsize=(12, 2.2 * n), sharex=True,
                             squeeze=False)
    for j, name in enumerate(names):
        ax = axes[j, 0]
        if record.target_t_s is not None:
            ax.plot(record.target_t_s + delay, record.q_target[:, j], color="0.55", lw=1,
                    ls="--", label="operator (IK target), shifted by the delay")
        if has_packets:
            ax.step(record.packet_t_s, record.q_sent[:, j], where="post", color="C0", lw=1.2,
                    label=packets)
        if record.guard is not None and record.guard.num_commands:
            ax.step(record.guard.command_t_s, record.guard.q_commanded[:, j], where="post",
                    color="C2", lw=1, label="received by the robot (after the guard)")
        ax.plot(record.tracker_t_s, record.q_link[:, j], color="C3", lw=1, label="robot link")
        ax.set_ylabel(f"{name} [rad]")
        if velocities:
            velocity = record.packet_state[:, n + j]
            axes[j, 1].step(record.packet_t_s, velocity, where="post", color="C0", lw=1.2)
            axes[j, 1].set_ylabel(f"{name} q̇ sent [rad/s]")
    axes[0, 0].legend(fontsize=7, loc="best")
    for ax in axes[-1]:
        ax.set_xlabel("time [s]")
    shown = (["operator"] if record.target_t_s is not None else []) + (
        [packets.split(" (")[0]] if has_packets else []) + (
        ["received"] if record.guard is not None else []) + ["robot"]
    writer.save(fig, "joints.png", f"Joint positions ({', '.join(shown)})"
                + (f" and {packets.split(' (')[0]} velocity" if velocities else ""))


def _acceleration_jerk_figure(plt, writer, record: SimulationRecord, packets: str) -> None:
    scenario = record.scenario
    names = record.joint_names
    n = record.num_joints
    period = scenario.uplink.period_s
    a_max, j_max = record_limits(record)
    series = []
    if record.packet_seq is not None and record.packet_seq.size > 3:
        series.append((packets, record.packet_t_s, record.q_sent, "C0"))
    if record.guard is not None and record.guard.num_commands:
        sequence = _received_sequence(record)
        times = np.r_[np.full(3, np.nan), record.guard.command_t_s]
        series.append(("received by the robot", times, sequence, "C2"))
    if not series:
        return
    fig, axes = plt.subplots(n, 2, figsize=(12, 2.2 * n), sharex=True, squeeze=False)
    for j, name in enumerate(names):
        for column, order, limit, label in ((0, 2, a_max, "FD acc [rad/s²]"),
                                            (1, 3, j_max, "FD jerk [rad/s³]")):
            ax = axes[j, column]
            for text, times, positions, color in series:
                values = finite_differences(positions, period, order)
                t = times[len(times) - len(values):]
                keep = np.isfinite(t)
                ax.plot(t[keep], values[keep, j], color=color, lw=1, label=text)
            if np.isfinite(limit[j]):
                ax.axhline(limit[j], color="C3", ls="--", lw=0.8,
                           label=f"limit ±{limit[j]:g}")
                ax.axhline(-limit[j], color="C3", ls="--", lw=0.8)
            ax.set_ylabel(f"{name}\n{label}", fontsize=8)
            if j == 0:
                ax.legend(fontsize=7, loc="upper right")
    for ax in axes[-1]:
        ax.set_xlabel("time [s]")
    writer.save(fig, "acceleration_jerk.png",
                "FD acceleration and jerk of the commands against the limits")


def _tool_paths_figure(plt, writer, record: SimulationRecord, packets: str) -> None:
    scenario = record.scenario
    plane = (0, 1) if scenario.arm == "air_bearing_arm" else (0, 2)
    fig, ax = plt.subplots(figsize=(6.5, 5.5))
    if record.packet_seq is not None and record.packet_seq.size:
        commanded = tool_positions(scenario, record.q_sent)
        ax.plot(commanded[:, plane[0]], commanded[:, plane[1]], "C0.", ms=3,
                label=packets, zorder=2)
    if record.guard is not None and record.guard.num_commands:
        received = tool_positions(scenario, record.guard.q_commanded)
        ax.plot(received[:, plane[0]], received[:, plane[1]], "C2x", ms=3,
                label="received by the robot", zorder=3)
    ax.plot(record.tool_position_m[:, plane[0]], record.tool_position_m[:, plane[1]],
            color="C3", lw=1.2, label="robot (laser tracker)", zorder=1)
    if record.target_t_s is not None:
        operator = tool_positions(scenario, record.q_target)
        # On top, dashed: the robot's track lies on it within millimetres.
        ax.plot(operator[:, plane[0]], operator[:, plane[1]], color="k", lw=0.9, ls="--",
                label="operator", zorder=4)
    ax.set_xlabel("xyz"[plane[0]] + " [m]")
    ax.set_ylabel("xyz"[plane[1]] + " [m]")
    _at_least_span(ax, TOOL_PLOT_MIN_SPAN_M)
    ax.set_aspect("equal", adjustable="datalim")
    ax.legend(fontsize=8)
    writer.save(fig, "end_effector.png", "End-effector tracks")


TOOL_PLOT_MIN_SPAN_M = 0.01
"""The end-effector plot shows at least 1 cm each way (a tool at rest is a point)."""


def _at_least_span(ax, span: float) -> None:
    """Widens each axis of ``ax`` to ``span`` about its centre where its data span less: an
    equal-aspect plot of data without extent has no scale to keep."""
    for get, put in ((ax.get_xlim, ax.set_xlim), (ax.get_ylim, ax.set_ylim)):
        low, high = get()
        if high - low < span:
            centre = 0.5 * (low + high)
            put(centre - 0.5 * span, centre + 0.5 * span)


def _error_figures(plt, writer, record: SimulationRecord, packets: str) -> None:
    scenario = record.scenario
    delay = scenario.fifo.delay_s
    response = response_errors(record) if record.packet_seq is not None else None
    received = received_response_errors(record)
    fig, ax = plt.subplots(figsize=(9, 3))
    if response is not None:
        ax.plot(response.response_t_s, 1000 * response.response_m, color="C0", lw=1,
                label=f"against the {packets}")
    if received is not None:
        ax.plot(received[0], 1000 * received[1], color="C2", lw=1,
                label="against the command the robot received")
    ax.set_xlabel("time the tracker was read (the set-point on the command) [s]")
    ax.set_ylabel("‖FK(command) − tracker‖ [mm]")
    ax.legend(fontsize=8)
    writer.save(fig, "tracking_error.png", "Robot response error to each command over time")

    if record.target_t_s is None or response is None or response.chain_m.size == 0:
        return
    # The robot against the operator's intent along the operator's path: where on the
    # drawing it deviates (the tracks above overlap at this scale).
    operator = tool_positions(scenario, record.q_target)
    step = np.linalg.norm(np.diff(operator, axis=0), axis=1)
    path_m = np.interp(response.chain_t_s - delay - response.ramp_s, record.target_t_s,
                       np.concatenate([[0.0], np.cumsum(step)]))
    fig, ax = plt.subplots(figsize=(9, 3))
    ax.plot(path_m, 1000 * response.chain_m, color="C3", lw=1)
    ax.set_xlabel("distance along the operator's path [m]")
    ax.set_ylabel("‖robot − operator‖ [mm]")
    writer.save(fig, "error_along_path.png",
                "The robot against the operator's intent along the path (the designed delay "
                "removed)")


def _shade(ax, times, flags, period, **style) -> bool:
    """Shades the spans of ``times`` where ``flags`` is set (each sample held for ``period``);
    returns whether there was any."""
    flags = np.asarray(flags) > 0.5
    if not np.any(flags):
        return False
    starts = np.flatnonzero(flags & ~np.r_[False, flags[:-1]])
    ends = np.flatnonzero(flags & ~np.r_[flags[1:], False])
    label = style.pop("label", None)
    for index, (a, b) in enumerate(zip(starts, ends)):
        ax.axvspan(times[a], times[b] + period, **style, label=None if index else label)
    return True


def _sigma_collision_figure(plt, writer, record: SimulationRecord) -> None:
    if record.tick_t_s is None:
        return
    scenario = record.scenario
    fig, axes = plt.subplots(2, 1, figsize=(9, 4.8), sharex=True)
    for j, name in enumerate(record.joint_names):
        # σ changes once per 4 Hz tick: drawn as the steps it is.
        axes[0].step(record.tick_t_s, record.sigma[:, j], where="post", lw=1, label=name)
    axes[0].set_yscale("log")
    axes[0].set_ylabel("σ [rad²/s⁷]")
    axes[0].legend(fontsize=7, ncol=3)
    checker = scenario.collision_checker
    ax = axes[1]
    ax.plot(record.target_t_s, 1000 * record.min_distance_m, color="C0", lw=1,
            label="pre-simulator: smallest distance")
    ax.axhline(1000 * checker.distance_horizon_m, color="C0", ls=":", lw=0.8,
               label=f"distance horizon {1000 * checker.distance_horizon_m:g} mm "
                     "(farther reads as this)")
    ax.axhline(1000 * checker.safety_margin_m, color="C3", ls="--", lw=0.8,
               label=f"safety margin {1000 * checker.safety_margin_m:g} mm")
    _shade(ax, record.tick_t_s, record.holding, scenario.uplink.period_s, color="C3",
           alpha=0.2, label="FIFO holding (collision hold or stop)")
    ax.set_ylabel("distance [mm]")
    ax.set_xlabel("time [s]")
    ax.legend(fontsize=7)
    writer.save(fig, "sigma_collision.png",
                "Reduced-Q σ per joint (jounce intensity, one value per 4 Hz tick); the "
                "pre-simulator's smallest distance and the FIFO's holds")


def _guard_figure(plt, writer, record: SimulationRecord) -> None:
    from telesmooth.systems.link_guard import GUARD_MODES

    guard = record.guard
    if guard is None or guard.poll_t_s.size == 0:
        return
    fig, axes = plt.subplots(2, 1, figsize=(9, 4.2), sharex=True)
    axes[0].step(guard.poll_t_s, guard.mode, where="post", color="C2", lw=1.2)
    axes[0].set_yticks(range(len(GUARD_MODES)), GUARD_MODES)
    axes[0].set_ylim(-0.5, len(GUARD_MODES) - 0.5)
    axes[0].set_ylabel("guard mode")
    axes[1].plot(guard.poll_t_s, 1000 * guard.stream_distance_rad, color="C2", lw=1)
    axes[1].set_ylabel("command − accepted\npacket [mrad]")
    axes[1].set_xlabel("time [s]")
    writer.save(fig, "guard.png", "The onboard link guard: its mode over time, and how far "
                "the robot's command was from the newest accepted packet (max over joints)")


def _write_figures(out: Path, record: SimulationRecord,
                   packets: str = "sent (4 Hz)") -> list[tuple[str, str]]:
    """The figures of ``record``; ``packets`` names its packets in the legends (what the
    ground sent; onboard: what was accepted)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    writer = FigureWriter(out)
    _joints_figure(plt, writer, record, packets)
    _acceleration_jerk_figure(plt, writer, record, packets)
    _tool_paths_figure(plt, writer, record, packets)
    _error_figures(plt, writer, record, packets)
    _guard_figure(plt, writer, record)
    _sigma_collision_figure(plt, writer, record)
    return writer.figures


def _over_limits(statistics: dict, names, quantity: str) -> list[str]:
    """The joints whose |values| break the limit, in words."""
    return [f"the {quantity} limit on {name} ({statistics['max_over_limit'][j]:.2f}× the limit, "
            f"{100 * statistics['fraction_over_limit'][j]:.1f} % of the samples over)"
            for j, name in enumerate(names) if statistics["fraction_over_limit"][j] > 0.0]


def _and(items: list[str]) -> str:
    return items[0] if len(items) == 1 else ", ".join(items[:-1]) + " and " + items[-1]


def limits_text(metrics: dict) -> str:
    """The sent commands against the FD limits, and what the onboard guard did about it, in
    words (the table beside it marks each ratio over the limit with ``!``)."""
    commands = metrics["commands"]
    names = commands.get("joint_names") or []
    over = (_over_limits(commands["fd_acceleration"], names, "acceleration")
            + _over_limits(commands["fd_jerk"], names, "jerk"))
    guard = metrics.get("guard")
    if not over:
        text = ("The commands the ground sent stay within the FD acceleration and jerk limits "
                "on every joint.")
    else:
        text = f"The commands the ground sent break {_and(over)}."
    if guard is None:
        if over:
            text += (" In the paper's chain nothing between the uplink and the robot enforces "
                     "the limits: the robot received these commands as they were sent.")
        return text
    received = guard["received"]
    worst_a = max(received["fd_acceleration"]["max_over_limit"], default=0.0)
    worst_j = max(received["fd_jerk"]["max_over_limit"], default=0.0)
    cut = guard["largest_cut_rad"]
    worst = int(np.argmax(cut)) if cut else 0
    text += (f" The onboard link guard issued {guard['commands']} commands for the "
             f"{guard['accepted_packets']} packets it accepted and limited "
             f"{guard['limited']} of them, so that what reached the robot stays within the "
             f"limits (its FD acceleration at most {limit_ratio(worst_a)} and jerk at most "
             f"{limit_ratio(worst_j)} of the limit)")
    if guard["limited"]:
        text += (f"; its largest cut was {1000 * cut[worst]:.1f} mrad on {names[worst]}, and the "
                 f"robot's command was at most {1000 * guard['stream_distance_rad']:.1f} mrad "
                 "(max over joints) from the newest accepted packet")
    modes = {name: seconds for name, seconds in guard["time_in_mode_s"].items() if seconds}
    text += (". Time per guard mode: "
             + ", ".join(f"{name} {seconds:.2f} s" for name, seconds in modes.items()) + ".")
    return text


def _limits_table(metrics: dict) -> list[str]:
    commands = metrics["commands"]
    guard = metrics.get("guard")
    names = commands.get("joint_names") or []
    acc, jerk = commands["fd_acceleration"], commands["fd_jerk"]
    deformation = commands["position_deformation_rad"]
    header = ("| joint | FD acc max/limit (sent) | over | FD jerk max/limit (sent) | over | "
              + ("FD acc / jerk max/limit (received) | " if guard else "")
              + "deformation mean [mrad] |")
    lines = [header, "|" + "---|" * (header.count("|") - 1)]
    for j, name in enumerate(names):
        received = ""
        if guard:
            r = guard["received"]
            received = (f"{limit_ratio(r['fd_acceleration']['max_over_limit'][j])} / "
                        f"{limit_ratio(r['fd_jerk']['max_over_limit'][j])} | ")
        lines.append(
            f"| {name} | {limit_ratio(acc['max_over_limit'][j])} | "
            f"{100 * acc['fraction_over_limit'][j]:.1f} % "
            f"| {limit_ratio(jerk['max_over_limit'][j])} | "
            f"{100 * jerk['fraction_over_limit'][j]:.1f} % | {received}"
            f"{1000 * deformation['mean'][j]:.2f} |")
    lines += ["", "A ratio above 1 (marked `!`) breaks the limit; \"over\" is the share of the "
              "samples that do. Sent: the packets the ground sent; received: the commands the "
              "onboard link guard issued to the robot."]
    return lines


def _report_text(metrics: dict, figures, meshcat_html: bool = False) -> str:
    commands = metrics["commands"]
    scenario = metrics["scenario"]
    lines = [
        "# telesmooth simulate",
        "",
        f"Chain: {scenario['chain_text']}.",
        "",
        f"Scenario: arm `{scenario['arm']}`, operator: {scenario['operator']}, smoother "
        f"`{scenario['method']}`, on collision `{scenario['on_collision']}`. "
        f"{metrics['duration_s']:.1f} s simulated in {metrics['wall_time_s']:.1f} s "
        f"({metrics['realtime_factor']:.1f}× real time), {metrics['num_packets']} packets.",
        "",
        plant_text(metrics["plant"]),
        "",
    ]
    if meshcat_html:
        lines += ["A Meshcat replay of the run, viewable offline: [run.html](run.html).", ""]
    lines += ["## Limits", "", limits_text(metrics), ""] + _limits_table(metrics)
    tracking = metrics["tracking"]
    received = tracking.get("received_response_error_m")
    lines += [
        "",
        "## Accuracy",
        "",
        f"Cartesian deformation of the sent commands (mean / max): "
        f"{1000 * commands['cartesian_deformation_m']['mean']:.2f} / "
        f"{1000 * commands['cartesian_deformation_m']['max']:.2f} mm. Robot response error "
        f"against the sent commands, e (mean / max): "
        f"{1000 * tracking['response_error_m']['mean']:.2f} / "
        f"{1000 * tracking['response_error_m']['max']:.2f} mm"
        + ("" if received is None else
           f"; against the commands the robot received: {1000 * received['mean']:.2f} / "
           f"{1000 * received['max']:.2f} mm")
        + f". Whole-chain error against the operator: "
        f"{1000 * tracking['chain_error_m']['mean']:.2f} / "
        f"{1000 * tracking['chain_error_m']['max']:.2f} mm. Ticks on collision hold: "
        f"{metrics['collision_ticks']}; smallest pre-simulator distance "
        + _distance_text(metrics["min_distance_m"], metrics["distance_horizon_m"]) + "."
        + _stops_text(metrics.get("collision_stops")),
        "",
    ]
    for title, name in figures:
        lines += [f"## {title}", "", f"![{title}]({name})", ""]
    return "\n".join(lines)


def _distance_text(distance_m: float, horizon_m: float) -> str:
    """The pre-simulator's smallest distance; at its horizon (pairs farther apart are not
    computed) it is a lower bound and says so."""
    if distance_m >= horizon_m:
        return (f"at least {1000 * horizon_m:.1f} mm (nothing came within the pre-simulator's "
                "horizon, collision_checker.distance_horizon_m)")
    return f"{1000 * distance_m:.1f} mm"


def _stops_text(stops) -> str:
    if stops is None:
        return ""
    plans = ", ".join(f"{count} {name}" for name, count in stops["plans"].items() if count)
    largest = max(stops["max_braking_distance_rad"], default=0.0)
    return (f" Collision stops planned (jerk-limited, `--on-collision stop`): "
            f"{plans or 'none'}; largest braking distance {largest:.4f} rad.")


def write_record_report(out: Path, record: SimulationRecord, text_of, *,
                        packets: str = "sent (4 Hz)", tables: bool = True) -> Path:
    """Writes the tables (unless ``tables`` is False), figures and ``report.md`` of
    ``record`` into ``out``; ``text_of(figures)`` makes the report's text, ``packets`` names
    the record's packets in the figures. Returns the path of report.md."""
    if tables:
        _write_tables(out, record)
    figures = _write_figures(out, record, packets)
    report = out / "report.md"
    write_text(report, text_of(figures))
    return report


def write_simulation_report(out_dir, scenario, *, duration_s=None, meshcat_html=False,
                            progress=_log) -> Path:
    """Runs ``scenario`` and writes the report folder; returns the path of report.md."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    meshcat = None
    if meshcat_html:
        from telesmooth.diagrams.scenario import make_haptic_recording
        from telesmooth.diagrams.visualization import start_meshcat_recording

        meshcat = start_meshcat_recording(scenario, make_haptic_recording(scenario))
    record = simulate(scenario, duration_s=duration_s, meshcat=meshcat, progress=progress)
    if meshcat is not None:
        from telesmooth.diagrams.visualization import save_meshcat_recording

        save_meshcat_recording(meshcat, out / "run.html", record.duration_s)
    metrics = run_metrics(record)
    write_text(out / "metrics.json", json.dumps(metrics, indent=2) + "\n")
    return write_record_report(
        out, record, lambda figures: _report_text(metrics, figures,
                                                  meshcat_html=meshcat is not None))
