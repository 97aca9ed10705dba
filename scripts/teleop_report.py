"""A live session's files: the operator's hand as a recording, the logs, the prediction, the
report (``telesmooth teleop --out DIR``).

    operator.npz, operator.csv   the hand the ground received, 100 Hz: the haptic recording
                                 format (``t,<pose>,enable``) that ``simulate``'s ``file``
                                 source reads; replaying it sends the same commands
    console.csv                  the console at the haptic rate: clutch, stop, why the
                                 console released the clutch (no browser, gamepad lost)
    predicted.csv                every measured prediction: the instant, how far ahead of
                                 its telemetry it ran, predicted and measured tool position,
                                 the residual
    commands.csv, received.csv,  as ``simulate`` writes them
    telemetry.csv, targets.csv
    ticks.csv                    every haptic tick against the wall clock: its simulated
                                 instant, the wall clock then (s from the first tick), how
                                 late it ran
    metrics.json, report.md      the figures of ``simulate`` for the session, the session's
                                 timing (real-time rate, late ticks, timing.png) and the
                                 prediction's residual, with figures
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from telesmooth.atomic_files import write_text
from telesmooth.diagrams.scenario import describe_chain
from telesmooth.diagrams.simulation import (
    SimulationRecord,
    ground_fields,
    guard_record,
    plant_text,
    run_metrics,
)
from telesmooth.scripts.simulate_report import _write_csv, limits_text, write_record_report
from telesmooth.systems.laser_tracker import tracker_record
from telesmooth.systems.wall_clock_monitor import lateness

__all__ = ["operator_recording", "teleop_record", "write_teleop_report"]


def teleop_record(handles, context, *, wall_time_s: float = float("nan")) -> SimulationRecord:
    """The session as a :class:`SimulationRecord` (deployed chain: the guard's record)."""
    scenario = handles.scenario
    logs = handles.logs
    tracker = tracker_record(logs["tracker"].FindLog(context).data().T)
    return SimulationRecord(
        scenario=scenario, joint_names=tuple(handles.ground.joint_names),
        duration_s=context.get_time(), wall_time_s=wall_time_s, cpu_time_s=float("nan"),
        **ground_fields(handles, context), tracker_t_s=tracker.t_s, q_link=tracker.q_link,
        q_motor=tracker.q_motor, tool_position_m=tracker.tool_position_m,
        ramp_start_t_s=np.unique(logs["command_ramp"].FindLog(context).data()[0]),
        guard=guard_record(logs, context, scenario.command_receiver.poll_period_s))


def operator_recording(handles, context):
    """The hand the ground station received, as a
    :class:`~telesmooth.datasets.haptic_recording.HapticRecording`: one sample per haptic
    period from t = 0. A logger shows the state before its instant's updates, i.e. what the
    inverse kinematics reads at that instant: the row logged at t is the sample of t."""
    from telesmooth.datasets.haptic_recording import HapticRecording
    from telesmooth.diagrams.teleop import console_pose_names

    pose_log = handles.logs["hand_pose"].FindLog(context)
    enable = handles.logs["hand_enable"].FindLog(context).data()[0] > 0.5
    return HapticRecording(t_s=pose_log.sample_times().copy(), pose=pose_log.data().T.copy(),
                           enable=enable, pose_names=console_pose_names(handles.scenario))


def _write_console_csv(path: Path, handles, context) -> None:
    """console.csv: the console at the haptic rate, as the ground read it (the row at t is
    the tick before t, like operator.csv): the clutch, the stop, why the console released
    the clutch (``notice``: none, stopped, no-browser, gamepad-lost) and whether the hand
    was held at the edge of the reach."""
    from telesmooth.console.input import ConsoleNotice

    logs = handles.logs
    enable_log = logs["hand_enable"].FindLog(context)
    columns = [enable_log.data()[0]] + [logs[f"console_{name}"].FindLog(context).data()[0]
                                        for name in ("stop_requested", "notice", "saturated")]
    _write_csv(path, ["t", "enable", "stop", "notice", "saturated"],
               ([float(t), int(e > 0.5), int(s > 0.5),
                 ConsoleNotice(int(round(n))).name.lower().replace("_", "-"), int(a > 0.5)]
                for t, e, s, n, a in zip(enable_log.sample_times(), *columns)))


def _residual_figure(out: Path, residuals, warning_m: float) -> list[tuple[str, str]]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from telesmooth.scripts.figures import FigureWriter

    writer = FigureWriter(out)
    if not residuals:
        return []
    t = np.array([r.t_s for r in residuals])
    fig, axes = plt.subplots(2, 1, figsize=(9, 4.2), sharex=True)
    axes[0].plot(t, 1000 * np.array([r.residual_m for r in residuals]), color="C2", lw=1)
    axes[0].axhline(1000 * warning_m, color="C3", ls="--", lw=0.8,
                    label=f"the display warns above {1000 * warning_m:g} mm")
    axes[0].set_ylabel("‖predicted − measured‖\n[mm]")
    axes[0].legend(fontsize=7)
    axes[1].plot(t, [r.horizon_s for r in residuals], color="C0", lw=1)
    axes[1].set_ylabel("ahead of its\ntelemetry [s]")
    axes[1].set_xlabel("the instant predicted [s]")
    writer.save(fig, "prediction.png", "The predicted robot against the robot's telemetry of "
                "the same instant, and how far ahead of its telemetry each prediction ran")
    return writer.figures


def _prediction_stats(residuals) -> dict | None:
    if not residuals:
        return None
    values = np.array([r.residual_m for r in residuals])
    horizon = np.array([r.horizon_s for r in residuals])
    return {"count": int(values.size), "max_m": float(values.max()),
            "p95_m": float(np.percentile(values, 95)), "median_m": float(np.median(values)),
            "horizon_median_s": float(np.median(horizon)),
            "horizon_max_s": float(horizon.max())}


def _report_text(metrics: dict, figures) -> str:
    session, prediction = metrics["session"], metrics["prediction"]
    tracking = metrics["tracking"]
    lines = [
        "# telesmooth teleop",
        "",
        f"Chain: {metrics['scenario']['chain_text']}. The robot's telemetry came back over "
        f"{session['downlink']}; the operator drove from the browser console.",
        "",
        f"Session: {metrics['duration_s']:.1f} s, arm `{metrics['scenario']['arm']}`, smoother "
        f"`{metrics['scenario']['method']}`, {metrics['num_packets']} packets.",
    ]
    if session.get("ticks"):
        lines.append(_timing_text(session))
    lines += ["", plant_text(metrics["plant"]), "", "## Limits", "", limits_text(metrics), "",
              "## The predicted robot", "", _prediction_text(prediction)]
    lines += ["", "## Accuracy", "",
              f"Robot response error against the sent commands (mean / max): "
              f"{1000 * tracking['response_error_m']['mean']:.2f} / "
              f"{1000 * tracking['response_error_m']['max']:.2f} mm; whole-chain error against "
              f"the operator: {1000 * tracking['chain_error_m']['mean']:.2f} / "
              f"{1000 * tracking['chain_error_m']['max']:.2f} mm.", ""]
    for title, name in figures:
        lines += [f"## {title}", "", f"![{title}]({name})", ""]
    return "\n".join(lines)


def _write_hand_and_prediction(out: Path, handles, context) -> None:
    """operator.npz, operator.csv, console.csv and predicted.csv of a session."""
    from telesmooth.datasets.haptic_recording import write_haptic_csv, write_haptic_npz

    out.mkdir(parents=True, exist_ok=True)
    recording = operator_recording(handles, context)
    write_haptic_npz(out / "operator.npz", recording)
    write_haptic_csv(out / "operator.csv", recording)
    if "console_notice" in handles.logs:
        _write_console_csv(out / "console.csv", handles, context)
    _write_csv(out / "predicted.csv",
               ["t", "horizon_s", "predicted_x", "predicted_y", "predicted_z", "measured_x",
                "measured_y", "measured_z", "residual_m"],
               ([float(r.t_s), float(r.horizon_s), *map(float, r.predicted_m),
                 *map(float, r.measured_m), float(r.residual_m)]
                for r in handles.predictor.residuals))


def _session_timing(monitor) -> dict:
    if monitor is None:
        return {}
    stats = monitor.statistics()
    return dict(ticks=stats.ticks, late_ticks=stats.late_ticks, worst_lateness_s=stats.worst_s,
                p99_lateness_s=stats.p99_s, realtime_rate=stats.realtime_rate,
                period_s=monitor.period_s)


def _timing_text(session: dict) -> str:
    if not session.get("ticks"):
        return ""
    return (f"Timing: {session['realtime_rate']:.3f}× real time over the session; "
            f"{session['late_ticks']} of {session['ticks']} haptic ticks ran more than one "
            f"period ({1000 * session['period_s']:g} ms) late; the latest by "
            f"{1000 * session['worst_lateness_s']:.1f} ms (99th percentile "
            f"{1000 * session['p99_lateness_s']:.1f} ms; ticks.csv, timing.png).")


def _tick_lateness(monitor) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each tick's simulated instant, wall clock from the first tick and lateness, s."""
    sim_t, wall_t = np.array(monitor.sim_t_s), np.array(monitor.wall_t_s)
    if sim_t.size == 0:
        return sim_t, wall_t, wall_t
    return sim_t, wall_t - wall_t[0], lateness(sim_t, wall_t, sim_t[0], wall_t[0], monitor.rate)


def _write_timing(out: Path, monitor) -> list[tuple[str, str]]:
    """ticks.csv and timing.png (nothing without a monitor)."""
    if monitor is None or not monitor.sim_t_s:
        return []
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from telesmooth.scripts.figures import FigureWriter

    sim_t, wall, lateness = _tick_lateness(monitor)
    _write_csv(out / "ticks.csv", ["t", "wall_s", "lateness_s"],
               ([float(a), float(b), float(c)] for a, b, c in zip(sim_t, wall, lateness)))
    writer = FigureWriter(out)
    fig, ax = plt.subplots(figsize=(9, 2.6))
    ax.plot(sim_t, 1000 * lateness, color="C0", lw=0.8)
    ax.axhline(1000 * monitor.period_s, color="C3", ls="--", lw=0.8,
               label=f"one haptic period ({1000 * monitor.period_s:g} ms): later is late")
    ax.set_ylabel("lateness [ms]")
    ax.set_xlabel("simulated time [s]")
    ax.legend(fontsize=7, loc="upper right")
    writer.save(fig, "timing.png", "Each haptic tick against the wall clock: how late it ran")
    return writer.figures


def _prediction_text(prediction) -> str:
    if prediction is None:
        return "No prediction was measured (no telemetry arrived)."
    return (f"{prediction['count']} predictions were measured against the telemetry of the "
            f"same instant: residual max {1000 * prediction['max_m']:.3f} mm, 95th percentile "
            f"{1000 * prediction['p95_m']:.3f} mm, median {1000 * prediction['median_m']:.4f} "
            f"mm, each made {prediction['horizon_median_s']:.2f} s (median; at most "
            f"{prediction['horizon_max_s']:.2f} s) ahead of the telemetry it was synchronised "
            "on (predicted.csv).")


def write_operator_report(out: Path, handles, context, *, monitor=None) -> Path:
    """The session of ``telesmooth operator`` (the console alone): the hand, console.csv,
    predicted.csv, metrics.json and report.md (the chain's own figures are in the ground's
    and the onboard process's reports)."""
    out = Path(out)
    _write_hand_and_prediction(out, handles, context)
    residuals = handles.predictor.residuals
    clock = handles.predictor.clock
    metrics = {"side": "operator", "duration_s": context.get_time(),
               "session": _session_timing(monitor),
               "prediction": _prediction_stats(residuals),
               "clocks": None if clock is None or not clock.ready() else {
                   "robot_minus_operator_s": clock.robot_minus_local,
                   "robot_minus_ground_s": clock.robot_minus_ground}}
    write_text(out / "metrics.json", json.dumps(metrics, indent=2) + "\n")
    figures = (_residual_figure(out, residuals, handles.scenario.predictor.residual_warning_m)
               + _write_timing(out, monitor))
    lines = ["# telesmooth operator", "",
             "The console alone: the operator's hand went out on TELEOP_HAPTIC_COMMAND; the "
             "ground's packets and the robot's telemetry came back over the bus. What the "
             "ground sent and what the robot did are in those processes' own reports.", "",
             f"Session: {context.get_time():.1f} s. {_timing_text(metrics['session'])}", "",
             "## The predicted robot", "", _prediction_text(metrics["prediction"]), ""]
    for title, name in figures:
        lines += [f"## {title}", "", f"![{title}]({name})", ""]
    report = out / "report.md"
    write_text(report, "\n".join(lines))
    return report


def write_teleop_report(out: Path, handles, context, *, monitor=None) -> Path:
    """Writes the session's files (module docstring) into ``out``; returns report.md."""
    out = Path(out)
    _write_hand_and_prediction(out, handles, context)
    residuals = handles.predictor.residuals
    record = teleop_record(handles, context)
    metrics = run_metrics(record)
    scenario = handles.scenario
    metrics["session"] = {"downlink": scenario.link.downlink.describe(),
                          **_session_timing(monitor)}
    metrics["prediction"] = _prediction_stats(residuals)
    metrics["scenario"]["chain_text"] = describe_chain(scenario)
    write_text(out / "metrics.json", json.dumps(metrics, indent=2) + "\n")
    warning = scenario.predictor.residual_warning_m

    def text_of(figures):
        return _report_text(metrics, list(figures) + _residual_figure(out, residuals, warning)
                            + _write_timing(out, monitor))

    return write_record_report(out, record, text_of)
