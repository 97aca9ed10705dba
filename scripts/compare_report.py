"""`telesmooth compare`: the paper's Table 2 for one scenario, every method through one plant.

Output folder:
    comparison.json  per method: every docs/method.md §6 figure (studies.comparison), the
                     table rows, and the scenario summary
    packets.csv      the packet each method sent at every 4 Hz tick (positions per joint)
    table.md         the Table 2 rows alone (Markdown)
    *.png            FD acceleration/jerk against the limits, end-effector tracks, response
                     error over time, a summary bar chart
    report.md        the table, how to read it, and the figures
"""

from __future__ import annotations

import csv
import json
import math
import sys
from pathlib import Path

import numpy as np

from telesmooth.atomic_files import atomic_write, write_text
from telesmooth.diagrams.scenario import describe_chain, describe_operator
from telesmooth.diagrams.simulation import plant_text, tool_positions
from telesmooth.scripts.figures import FigureWriter
from telesmooth.scripts.formatting import limit_ratio
from telesmooth.smoothing.methods import METHODS
from telesmooth.smoothing.metrics import finite_differences
from telesmooth.smoothing.offline import HISTORY_LENGTH, with_rest_history
from telesmooth.studies.comparison import (
    LEAST_DEFORMATION,
    Comparison,
    compare_methods,
)

__all__ = ["guard_table_markdown", "table_markdown", "write_comparison_report"]


def _log(message: str) -> None:
    print(message, file=sys.stderr, flush=True)


_COLUMNS = (
    ("method", "method", "{}"),
    ("delay [s]", "delay_s", "{:.2f}"),
    ("FD acc max/limit", "fd_acc_max_over_limit", "ratio"),
    ("FD acc over", "fd_acc_fraction_over", "{:.1%}"),
    ("FD jerk max/limit", "fd_jerk_max_over_limit", "ratio"),
    ("FD jerk over", "fd_jerk_fraction_over", "{:.1%}"),
    ("joint def. mean [mrad]", "position_deformation_mean_rad", "×1000{:.2f}"),
    ("E_def mean / max [mm]", ("cartesian_deformation_mean_m", "cartesian_deformation_max_m"),
     "×1000{:.2f} / {:.2f}"),
    ("e mean / max [mm]", ("e_mean_m", "e_max_m"), "×1000{:.3f} / {:.3f}"),
    ("P [%]", "improvement_ratio_percent", "{:.1f}"),
    ("vs operator mean [mm]", "operator_error_mean_m", "×1000{:.3f}"),
    ("residual motion [mm]", "residual_motion_m", "×1000{:.3f}"),
    ("settling [s]", "settling_time_s", "settling"),
    ("added latency [s]", "added_latency_s", "{:.2f}"),
    ("pre-sim violations", "presim_violations", "{}"),
)


def _cell(row: dict, key, fmt: str) -> str:
    keys = key if isinstance(key, tuple) else (key,)
    values = [row[k] for k in keys]
    if fmt.startswith("×1000"):
        fmt, values = fmt[len("×1000"):], [1000.0 * v for v in values]
    if fmt == "settling" and not row.get("settled", True):
        return "not settled in the run"
    if any(isinstance(v, float) and math.isnan(v) for v in values):
        return "n/a"
    if fmt == "ratio":
        return limit_ratio(values[0])
    if fmt == "settling":
        return f"{values[0]:.2f}"
    return fmt.format(*values)


def table_markdown(rows) -> str:
    """The Table 2 rows (``Comparison.table()``) as a Markdown table; with offline-hard among
    them, a last column sets each method's E_def beside offline-hard's (the least deformation
    the limits allow)."""
    least = next((row["cartesian_deformation_mean_m"] for row in rows
                  if row["method"] == LEAST_DEFORMATION), None)
    extra = [f"E_def / {LEAST_DEFORMATION}"] if least is not None else []
    lines = ["| " + " | ".join([title for title, _, _ in _COLUMNS] + extra) + " |",
             "|" + "---|" * (len(_COLUMNS) + len(extra))]
    for row in rows:
        cells = [_cell(row, key, fmt) for _, key, fmt in _COLUMNS]
        if least is not None:
            cells.append(f"{row['cartesian_deformation_mean_m'] / least:.2f}" if least > 0
                         else "n/a (offline-hard deforms nothing)")
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


_GUARD_COLUMNS = (
    ("method", "method", "{}"),
    ("commands", "guard_commands", "{}"),
    ("limited", "guard_limited", "{}"),
    ("largest cut [mrad]", "guard_largest_cut_rad", "×1000{:.3g}"),
    ("farthest from the stream [mrad]", "guard_stream_distance_rad", "×1000{:.3g}"),
    ("received FD acc max/limit", "received_fd_acc_max_over_limit", "ratio"),
    ("received FD jerk max/limit", "received_fd_jerk_max_over_limit", "ratio"),
)


def guard_table_markdown(rows) -> str:
    """What the onboard link guard did to each method's commands (deployed chain): the
    commands it issued, how many it limited (they differ from the packet they followed), the
    largest cut (worst joint), the farthest the robot's command got from the newest packet,
    and the FD acceleration and jerk of what the robot received over their limits."""
    lines = ["| " + " | ".join(title for title, _, _ in _GUARD_COLUMNS) + " |",
             "|---|" + "---:|" * (len(_GUARD_COLUMNS) - 1)]
    for row in rows:
        lines.append("| " + " | ".join(_cell(row, key, fmt) for _, key, fmt in _GUARD_COLUMNS)
                     + " |")
    return "\n".join(lines)


def _write_packets(out: Path, comparison: Comparison) -> None:
    names = comparison.joint_names
    runs = comparison.runs
    length = max(len(run.packets) for run in runs.values())
    header = ["t"] + [f"{method}:{joint}" for method in runs for joint in names]
    with atomic_write(out / "packets.csv", "w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(header)
        for k in range(length):
            row = [repr(k * comparison.period_s)]
            for run in runs.values():
                # After its last packet each method's uplink keeps re-sending it.
                row += [repr(float(v)) for v in run.packets[min(k, len(run.packets) - 1)]]
            writer.writerow(row)


def _write_figures(out: Path, comparison: Comparison) -> list[tuple[str, str]]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    scenario = comparison.scenario
    names = comparison.joint_names
    n = len(names)
    period = comparison.period_s
    runs = comparison.runs
    writer = FigureWriter(out)

    save = writer.save

    a_max, j_max = comparison.max_acceleration, comparison.max_jerk
    fig, axes = plt.subplots(len(runs), 2, figsize=(12, 1.7 * len(runs)), sharex=True,
                             sharey="col", squeeze=False)
    for row, (method, run) in enumerate(runs.items()):
        received = with_rest_history(run.packets, comparison.q_start)
        for column, order, limit, label in ((0, 2, a_max, "|FD acc| / a_max"),
                                            (1, 3, j_max, "|FD jerk| / j_max")):
            ax = axes[row, column]
            values = np.abs(finite_differences(received, period, order)) / limit
            # Row r spans received samples r … r+order; plot it at its newest packet's time.
            t = (np.arange(values.shape[0]) + order - HISTORY_LENGTH) * period
            for j, joint in enumerate(names):
                ax.plot(t, values[:, j], lw=0.8, label=joint)
            ax.axhline(1.0, color="k", ls="--", lw=0.8)
            ax.set_ylabel(f"{method}\n{label}", fontsize=7)
    axes[0, 0].legend(fontsize=6, ncol=min(n, 6), loc="upper right")
    axes[-1, 0].set_xlabel("packet time [s]")
    axes[-1, 1].set_xlabel("packet time [s]")
    save(fig, "acceleration_jerk.png",
         "What the plant receives: FD acceleration and jerk over their limits, per method")

    operator = tool_positions(scenario, comparison.q_original)
    plane = (0, 1) if scenario.arm == "air_bearing_arm" else (0, 2)
    columns = min(4, len(runs))
    rows = math.ceil(len(runs) / columns)
    fig, axes = plt.subplots(rows, columns, figsize=(3.4 * columns, 3.2 * rows),
                             sharex=True, sharey=True, squeeze=False)
    for ax in axes.flat[len(runs):]:
        ax.set_visible(False)
    for ax, (method, run) in zip(axes.flat, runs.items()):
        ax.plot(operator[:, plane[0]], operator[:, plane[1]], color="0.6", lw=1.5,
                label="operator")
        ax.plot(run.tool_position_m[:, plane[0]], run.tool_position_m[:, plane[1]],
                color="C3", lw=0.8, label="robot (tracker)")
        ax.set_title(method, fontsize=9)
        ax.set_aspect("equal", adjustable="box")
    axes[0, 0].legend(fontsize=7)
    for ax in axes[-1]:
        ax.set_xlabel("xyz"[plane[0]] + " [m]")
    for ax in axes[:, 0]:
        ax.set_ylabel("xyz"[plane[1]] + " [m]")
    save(fig, "end_effector.png", "End-effector tracks: the operator and the robot per method")

    # The robot against the operator's intent along the operator's path: where on the
    # drawing each method deviates (the tracks above overlap at this scale).
    step = np.linalg.norm(np.diff(operator, axis=0), axis=1)
    path_m = np.concatenate([[0.0], np.cumsum(step)])
    fig, ax = plt.subplots(figsize=(10, 3.8))
    for index, (method, run) in enumerate(runs.items()):
        ax.plot(path_m, 1000 * run.operator_error_m, lw=0.9, color=f"C{index % 10}",
                ls="-" if index < 10 else "--", label=method)
    ax.set_xlabel("distance along the operator's path [m]")
    ax.set_ylabel("‖robot − operator‖ [mm]")
    ax.set_yscale("log")
    ax.legend(fontsize=7, ncol=4)
    save(fig, "error_along_path.png",
         "The robot against the operator's intent along the path (the fixed-lag methods' "
         "designed delay removed)")

    # e per method, one panel each, e_ORG in grey behind every one of them.
    t = comparison.t_s
    reference = runs.get("original")
    columns = 2
    rows = math.ceil(len(runs) / columns)
    fig, axes = plt.subplots(rows, columns, figsize=(11, 1.9 * rows), sharex=True,
                             sharey=True, squeeze=False)
    for ax in axes.flat[len(runs):]:
        ax.set_visible(False)
    for index, (ax, (method, run)) in enumerate(zip(axes.flat, runs.items())):
        if reference is not None and method != "original":
            ax.plot(t, 1000 * reference.response_error_m, lw=0.8, color="0.7",
                    label="e_ORG (original)")
        ax.plot(t, 1000 * run.response_error_m, lw=0.9, color=f"C{index % 10}",
                label=f"e ({method})")
        ax.set_title(f"{method}: mean {1000 * run.response_error_m.mean():.3f} mm, P "
                     f"{run.metrics['improvement_ratio_percent']:.1f} %", fontsize=8)
        ax.legend(fontsize=6, loc="upper right")
    for ax in axes[-1]:
        ax.set_xlabel("operator sample time [s]")
    for ax in axes[:, 0]:
        ax.set_ylabel("e [mm]")
    save(fig, "response_error.png",
         "Response error e(i) per operator sample and method (e_ORG in grey behind each)")

    table = comparison.table()
    labels = [row["method"] for row in table]
    panels = (("E_def mean [mm]", [1000 * r["cartesian_deformation_mean_m"] for r in table]),
              ("e mean [mm]", [1000 * r["e_mean_m"] for r in table]),
              ("P [%]", [r["improvement_ratio_percent"] for r in table]),
              ("FD acc max / a_max", [r["fd_acc_max_over_limit"] for r in table]),
              ("FD jerk max / j_max", [r["fd_jerk_max_over_limit"] for r in table]))
    fig, axes = plt.subplots(1, len(panels), figsize=(3.0 * len(panels), 3.6))
    for ax, (title, values) in zip(axes, panels):
        ax.barh(range(len(labels)), values, color=[f"C{i}" for i in range(len(labels))])
        ax.set_yticks(range(len(labels)))
        ax.set_yticklabels(labels if ax is axes[0] else [], fontsize=7)
        ax.invert_yaxis()
        ax.set_title(title, fontsize=9)
        if "limit" in title or "/" in title:
            ax.axvline(1.0, color="k", ls="--", lw=0.8)
    save(fig, "summary.png", "Summary per method")
    return writer.figures


def _report_text(comparison: Comparison, rows, figures, plant: dict) -> str:
    scenario = comparison.scenario
    table = table_markdown(rows)
    lines = [
        "# telesmooth compare",
        "",
        f"Chain: {describe_chain(scenario)}.",
        "",
        f"Scenario: arm `{scenario.arm}`, operator: {describe_operator(scenario)}; "
        f"{comparison.q_original.shape[0]} operator samples at {comparison.period_s} s "
        f"(the recording and {scenario.settle_s} s of holding still); every method played "
        f"through the same uplink and flexible-joint robot for {comparison.duration_s:.1f} s.",
        "",
        plant_text(plant),
        "",
        table,
        "",
        "How to read it (docs/method.md §6; definitions in `telesmooth.studies.comparison`):",
        "",
        "- FD acc/jerk: finite differences of the packets as the plant receives them (start "
        "pose before, last packet held after), worst joint; *over* is the share of samples "
        "above the limit.",
        "- joint def., E_def: the method's estimate of each operator sample against the sample "
        "(worst joint; Cartesian via forward kinematics).",
        "- e: the robot's response error to its own commands (tracker read when the "
        "interpolator has reached the packet); e of `original` is e_ORG. "
        "P = (Σe_ORG − Σe_SMT)/Σe_ORG.",
        "- vs operator: the tracker against the operator's sample, the error the user feels "
        "(the fixed-lag methods' designed delay removed).",
        "- residual motion / settling: the tool after the operator's last sample; settling is "
        "the time until it stays within 0.1 mm of its final position.",
        "- pre-sim violations: samples the pre-simulator would refuse (collision, joint "
        "limits); reported, not enforced, in this comparison.",
        "",
    ]
    if comparison.chain == "deployed":
        lines += [
            "## What the onboard link guard did",
            "",
            "The figures above are of what each method sent; the robot received the guard's "
            "commands. *Limited*: commands that differ from the packet they followed (the "
            "guard cut them to keep the limits); *largest cut*: the largest |command − packet| "
            "of those, worst joint; *farthest from the stream*: the largest distance of the "
            "robot's command from the newest accepted packet after any poll; *received FD*: "
            "the finite differences of the guard's commands (after the robot's rest at its "
            "start pose) over the limits.",
            "",
            guard_table_markdown(rows),
            "",
        ]
    for title, name in figures:
        lines += [f"## {title}", "", f"![{title}]({name})", ""]
    return "\n".join(lines)


def write_comparison_report(out_dir, scenario, *, methods=METHODS,
                            progress=_log, offline_solver="drake", chain="paper") -> Path:
    """Runs :func:`compare_methods` (through ``chain``: ``"paper"`` or ``"deployed"``) and
    writes the report folder; returns report.md's path."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    comparison = compare_methods(scenario, methods, progress=progress,
                                 offline_solver=offline_solver, chain=chain)
    scenario = comparison.scenario
    rows = comparison.table()
    plant = comparison.plant()
    data = {
        "scenario": {"arm": scenario.arm, "chain": scenario.chain,
                     "chain_text": describe_chain(scenario),
                     "haptic_source": scenario.haptic.source,
                     "period_s": comparison.period_s, "num_samples": int(comparison.t_s.size),
                     "duration_s": comparison.duration_s,
                     "joint_names": list(comparison.joint_names)},
        "plant": plant,
        "table": rows,
        "methods": {name: run.metrics for name, run in comparison.runs.items()},
    }
    write_text(out / "comparison.json", json.dumps(data, indent=2, default=float) + "\n")
    table = table_markdown(rows) + "\n"
    if comparison.chain == "deployed":
        table += "\nWhat the onboard link guard did:\n\n" + guard_table_markdown(rows) + "\n"
    write_text(out / "table.md", table)
    _write_packets(out, comparison)
    figures = _write_figures(out, comparison)
    report = out / "report.md"
    write_text(report, _report_text(comparison, rows, figures, plant))
    return report
