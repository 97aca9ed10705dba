"""`telesmooth simulate`: run a scenario headless and write the report.

Output folder:
    metrics.json     docs/method.md §6 figures of the sent commands and of the robot's response
    commands.csv     every uplink packet: seq, send time, the operator instant it estimates,
                     position and velocity per joint
    telemetry.csv    the robot at 100 Hz: link and motor angles, laser-tracker tool position
    targets.csv      the IK joint targets at 100 Hz (the pre-simulator's newest command)
    *.png            joint positions/velocities, acceleration/jerk with limits, end-effector
                     tracks, tracking error over time, σ and collision/hold
    report.md        the figures and a summary table
    run.html         (with --meshcat) a self-contained Meshcat replay
"""

from __future__ import annotations

import csv
import json
import sys
from pathlib import Path

import numpy as np

from telesmooth.arms.joint_vectors import as_per_joint
from telesmooth.atomic_files import atomic_write, write_text
from telesmooth.diagrams.simulation import (
    SimulationRecord,
    plant_text,
    response_errors,
    run_metrics,
    simulate,
    tool_positions,
)
from telesmooth.scripts.figures import FigureWriter
from telesmooth.scripts.formatting import limit_ratio
from telesmooth.smoothing.metrics import finite_differences

__all__ = ["write_simulation_report"]


def _log(message: str) -> None:
    print(message, file=sys.stderr, flush=True)


def _write_csv(path: Path, header, rows) -> None:
    with atomic_write(path, "w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(header)
        for row in rows:
            writer.writerow([repr(v) if isinstance(v, float) else v for v in row])


def _write_tables(out: Path, record: SimulationRecord) -> None:
    names = record.joint_names
    n = record.num_joints
    delay = record.scenario.fifo.delay_s
    rows = []
    for seq, t, state in zip(record.packet_seq, record.packet_t_s, record.packet_state):
        rows.append([int(seq), float(t), float(t - delay)] + [float(v) for v in state[:2 * n]])
    _write_csv(out / "commands.csv", ["seq", "send_t", "sample_t"]
               + [f"q_{j}" for j in names] + [f"v_{j}" for j in names], rows)
    _write_csv(out / "telemetry.csv",
               ["t"] + [f"q_link_{j}" for j in names] + [f"q_motor_{j}" for j in names]
               + ["tool_x", "tool_y", "tool_z"],
               ([float(t)] + [float(v) for v in np.concatenate([a, b, c])]
                for t, a, b, c in zip(record.tracker_t_s, record.q_link, record.q_motor,
                                      record.tool_position_m)))
    _write_csv(out / "targets.csv", ["t"] + list(names),
               ([float(t)] + [float(v) for v in q]
                for t, q in zip(record.target_t_s, record.q_target)))


def _write_figures(out: Path, record: SimulationRecord, metrics: dict) -> list[tuple[str, str]]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    scenario = record.scenario
    names = record.joint_names
    n = record.num_joints
    delay = scenario.fifo.delay_s
    period = scenario.uplink.period_s
    writer = FigureWriter(out)

    save = writer.save

    sent = record.q_sent
    velocity = record.packet_state[:, n:2 * n]
    fig, axes = plt.subplots(n, 2, figsize=(12, 2.2 * n), sharex=True, squeeze=False)
    for j, name in enumerate(names):
        ax = axes[j, 0]
        ax.plot(record.target_t_s + delay, record.q_target[:, j], color="0.6", lw=1,
                label="operator (IK target), shifted by the delay")
        ax.step(record.packet_t_s, sent[:, j], where="post", color="C0", lw=1.2,
                label="sent (4 Hz)")
        ax.plot(record.tracker_t_s, record.q_link[:, j], color="C3", lw=1, label="robot link")
        ax.set_ylabel(f"{name} [rad]")
        axes[j, 1].step(record.packet_t_s, velocity[:, j], where="post", color="C0", lw=1.2)
        axes[j, 1].set_ylabel(f"{name} q̇ sent [rad/s]")
    axes[0, 0].legend(fontsize=7, loc="best")
    axes[-1, 0].set_xlabel("time [s]")
    axes[-1, 1].set_xlabel("time [s]")
    save(fig, "joints.png", "Joint positions (operator, sent, robot) and sent velocity")

    a_max = as_per_joint("a_max", scenario.smoother.max_acceleration_rad_per_s2, n, names,
                         allow_inf=True)
    j_max = as_per_joint("j_max", scenario.smoother.max_jerk_rad_per_s3, n, names,
                         allow_inf=True)
    acc = finite_differences(sent, period, 2)
    jerk = finite_differences(sent, period, 3)
    fig, axes = plt.subplots(n, 2, figsize=(12, 2.2 * n), sharex=True, squeeze=False)
    for j, name in enumerate(names):
        for column, values, limit, label in ((0, acc, a_max, "FD acc [rad/s²]"),
                                             (1, jerk, j_max, "FD jerk [rad/s³]")):
            ax = axes[j, column]
            t = record.packet_t_s[len(record.packet_t_s) - len(values):]
            ax.plot(t, values[:, j], color="C0", lw=1)
            if np.isfinite(limit[j]):
                ax.axhline(limit[j], color="C3", ls="--", lw=0.8)
                ax.axhline(-limit[j], color="C3", ls="--", lw=0.8)
            ax.set_ylabel(f"{name}\n{label}", fontsize=8)
    axes[-1, 0].set_xlabel("time [s]")
    axes[-1, 1].set_xlabel("time [s]")
    save(fig, "acceleration_jerk.png", "Sent commands: FD acceleration and jerk vs the limits")

    operator = tool_positions(scenario, record.q_target)
    commanded = tool_positions(scenario, sent)
    plane = (0, 1) if scenario.arm == "air_bearing_arm" else (0, 2)
    fig, ax = plt.subplots(figsize=(6.5, 5.5))
    ax.plot(operator[:, plane[0]], operator[:, plane[1]], color="0.6", lw=1, label="operator")
    ax.plot(commanded[:, plane[0]], commanded[:, plane[1]], "C0.-", ms=3, lw=0.8,
            label="sent (4 Hz)")
    ax.plot(record.tool_position_m[:, plane[0]], record.tool_position_m[:, plane[1]],
            color="C3", lw=1, label="robot (laser tracker)")
    ax.set_xlabel("xyz"[plane[0]] + " [m]")
    ax.set_ylabel("xyz"[plane[1]] + " [m]")
    ax.set_aspect("equal", adjustable="datalim")
    ax.legend(fontsize=8)
    save(fig, "end_effector.png", "End-effector tracks")

    response = response_errors(record)
    fig, ax = plt.subplots(figsize=(9, 3))
    ax.plot(response.response_t_s, 1000 * response.response_m, color="C3", lw=1)
    ax.set_xlabel("time the tracker was read (the set-point on the command) [s]")
    ax.set_ylabel("‖FK(sent) − tracker‖ [mm]")
    save(fig, "tracking_error.png", "Robot response error to each command over time")

    # The robot against the operator's intent along the operator's path: where on the
    # drawing it deviates (the tracks above overlap at this scale).
    step = np.linalg.norm(np.diff(operator, axis=0), axis=1)
    path_m = np.interp(response.chain_t_s - delay - response.ramp_s, record.target_t_s,
                       np.concatenate([[0.0], np.cumsum(step)]))
    fig, ax = plt.subplots(figsize=(9, 3))
    ax.plot(path_m, 1000 * response.chain_m, color="C3", lw=1)
    ax.set_xlabel("distance along the operator's path [m]")
    ax.set_ylabel("‖robot − operator‖ [mm]")
    save(fig, "error_along_path.png",
         "The robot against the operator's intent along the path (the designed delay removed)")

    fig, axes = plt.subplots(2, 1, figsize=(9, 4.5), sharex=True)
    for j, name in enumerate(names):
        # σ changes once per 4 Hz tick: drawn as the steps it is.
        axes[0].step(record.tick_t_s, record.sigma[:, j], where="post", lw=1, label=name)
    axes[0].set_yscale("log")
    axes[0].set_ylabel("σ [rad²/s⁷]")
    axes[0].legend(fontsize=7, ncol=3)
    horizon = scenario.collision_checker.distance_horizon_m
    axes[1].plot(record.target_t_s, record.min_distance_m, color="C0", lw=1,
                 label="pre-simulator min distance [m]")
    axes[1].axhline(horizon, color="C0", ls=":", lw=0.8,
                    label=f"distance horizon {horizon:g} m (farther is reported as this)")
    axes[1].step(record.tick_t_s, 0.1 * record.holding, where="post", color="C3", lw=1,
                 label="FIFO hold (×0.1)")
    axes[1].axhline(scenario.collision_checker.safety_margin_m, color="C3", ls=":", lw=0.8,
                    label="safety margin")
    axes[1].set_xlabel("time [s]")
    axes[1].legend(fontsize=7)
    save(fig, "sigma_collision.png", "Reduced-Q σ per joint (jounce intensity, one value per "
         "4 Hz tick); pre-simulator distance and holds")
    return writer.figures


def _report_text(metrics: dict, figures, meshcat_html: bool = False) -> str:
    commands = metrics["commands"]
    lines = [
        "# telesmooth simulate",
        "",
        f"Scenario: arm `{metrics['scenario']['arm']}`, operator: "
        f"{metrics['scenario']['operator']}, smoother `{metrics['scenario']['method']}`, "
        f"on collision `{metrics['scenario']['on_collision']}`. "
        f"{metrics['duration_s']:.1f} s simulated in {metrics['wall_time_s']:.1f} s "
        f"({metrics['realtime_factor']:.1f}× real time), {metrics['num_packets']} packets.",
        "",
        plant_text(metrics["plant"]),
        "",
    ]
    if meshcat_html:
        lines += ["A Meshcat replay of the run, viewable offline: [run.html](run.html).", ""]
    lines += [
        "| joint | FD acc max/limit | FD acc over | FD jerk max/limit | FD jerk over | "
        "deformation mean [mrad] |",
        "|---|---|---|---|---|---|",
    ]
    names = commands.get("joint_names") or []
    acc, jerk = commands["fd_acceleration"], commands["fd_jerk"]
    deformation = commands["position_deformation_rad"]
    for j, name in enumerate(names):
        lines.append(
            f"| {name} | {limit_ratio(acc['max_over_limit'][j])} | "
            f"{100 * acc['fraction_over_limit'][j]:.1f} % "
            f"| {limit_ratio(jerk['max_over_limit'][j])} | "
            f"{100 * jerk['fraction_over_limit'][j]:.1f} % "
            f"| {1000 * deformation['mean'][j]:.2f} |")
    tracking = metrics["tracking"]
    lines += [
        "",
        f"Cartesian deformation of the sent commands (mean / max): "
        f"{1000 * commands['cartesian_deformation_m']['mean']:.2f} / "
        f"{1000 * commands['cartesian_deformation_m']['max']:.2f} mm. Robot response error "
        f"(mean / max): {1000 * tracking['response_error_m']['mean']:.2f} / "
        f"{1000 * tracking['response_error_m']['max']:.2f} mm; whole-chain error against the "
        f"operator: {1000 * tracking['chain_error_m']['mean']:.2f} / "
        f"{1000 * tracking['chain_error_m']['max']:.2f} mm. Ticks on collision hold: "
        f"{metrics['collision_ticks']}; smallest pre-simulator distance "
        f"{1000 * metrics['min_distance_m']:.1f} mm."
        + _stops_text(metrics.get("collision_stops")),
        "",
    ]
    for title, name in figures:
        lines += [f"## {title}", "", f"![{title}]({name})", ""]
    return "\n".join(lines)


def _stops_text(stops) -> str:
    if stops is None:
        return ""
    plans = ", ".join(f"{count} {name}" for name, count in stops["plans"].items() if count)
    largest = max(stops["max_braking_distance_rad"], default=0.0)
    return (f" Collision stops planned (jerk-limited, `--on-collision stop`): "
            f"{plans or 'none'}; largest braking distance {largest:.4f} rad.")


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
    _write_tables(out, record)
    figures = _write_figures(out, record, metrics)
    report = out / "report.md"
    write_text(report, _report_text(metrics, figures, meshcat_html=meshcat is not None))
    return report
