"""The experiment report's verdicts as the paper states its claims
(:func:`~telesmooth.studies.claims.paper_verdicts`): the verdict table with its robustness
column, the rules, the robustness over the variants, which KF form reproduces the paper's
figures, C1's figures, every pair, and the figures of each method under each reading."""

from __future__ import annotations

from telesmooth.scripts.formatting import figures_table
from telesmooth.studies.claims import (
    C8_MARGIN,
    DEFAULT_VARIANT,
    DEFORMATION_MARGIN_M,
    DEMONSTRATION_MAJORITY,
    E_MARGIN_M,
    JOINT_MARGIN_RAD,
    P_MARGIN_PERCENT,
    PAPER_CLAIMS,
    RANK_MARGIN,
    STATE_OVERSHOOT,
    STATE_SHARE,
    VARIANT_AXES,
)

__all__ = ["paper_verdicts_markdown", "verdict_table_with_robustness", "variant_figures_markdown"]

_AXIS_NAMES = {"kf": "KF form", "e": "e at 100 Hz or command instants",
               "phase": "motion phase or whole run", "sigma": "σ carried or fresh"}

# How each pair's figure is printed: scale, unit, name.
_FIGURES = {"P": (1.0, "points", "P"), "e": (1e3, "mm", "e"),
            "cartesian": (1e3, "mm", "E_def Cartesian"),
            "position": (1e6, "µrad", "joint position deformation"),
            "velocity": (1e6, "µrad/s", "joint velocity deformation"),
            "rank": (1.0, "ranks", "mean rank"), "fd_jerk": (1.0, "× j_max", "worst FD jerk")}


def verdict_table_with_robustness(result: dict) -> str:
    """Claims × cells under the default reading, the verdict over cells, and the robustness
    column: the readings a cell's verdict depends on (one axis changed at a time), with the
    cells."""
    cells = list(result["cells"])
    lines = ["| claim | " + " | ".join(cells) + " | over cells | robustness |",
             "|---|" + "---|" * (len(cells) + 2)]
    for claim in PAPER_CLAIMS:
        axes: dict[str, list[str]] = {}
        for cell in cells:
            for axis in result["cells"][cell][claim]["flipping_axes"]:
                axes.setdefault(axis, []).append(cell)
        robust = ("same under every reading" if not axes else "depends on " + "; ".join(
            f"{_AXIS_NAMES[axis]} ({' and '.join(where)})" for axis, where in axes.items()))
        lines.append(f"| {claim} | " + " | ".join(
            result["cells"][cell][claim]["verdict"] for cell in cells)
            + f" | {result['claims'][claim]['verdict']} | {robust} |")
    return "\n".join(lines)


def _rules() -> list[str]:
    default = (f"KF = `{DEFAULT_VARIANT['kf']}` (or the experiment's --kf-form), e at the "
               f"{DEFAULT_VARIANT['e']}, over the {DEFAULT_VARIANT['phase']}, Online-CKS's σ "
               f"{DEFAULT_VARIANT['sigma']}")
    readings = ", ".join(f"{axis}: " + " / ".join(values) for axis, values in VARIANT_AXES.items())
    return [
        "Each claim in the paper's words, and its test:", "",
        *[f"- **{claim}**: {statement}." for claim, statement in PAPER_CLAIMS.items()], "",
        "Differences between two methods are judged on the paired differences over the "
        "demonstrations both ran (the median, its distribution-free 95 % interval from the "
        "sign test's order statistics, the Wilcoxon signed-rank p), never on two means. A "
        "pair is *better* when the interval lies beyond 0 and the median is at least the "
        "margin, *worse* the other way, a *tie* when the interval lies within ± the margin or "
        "the difference is significant but smaller, *inconclusive* otherwise (or with fewer "
        "than 6 pairs). Margins: "
        f"{P_MARGIN_PERCENT:g} percentage point of P; {E_MARGIN_M * 1e3:g} mm of e and "
        f"{DEFORMATION_MARGIN_M * 1e3:g} mm of E_def (the tracker's accuracy); "
        f"{JOINT_MARGIN_RAD * 1e6:g} µrad (and µrad/s) of a joint deformation (1 µm at a "
        f"metre of reach); {RANK_MARGIN:g} of a mean rank (C7); {C8_MARGIN:g} × j_max of the "
        "worst FD jerk (C8). In a cell a claim *holds* when every pair it names is better "
        "(for C4's \"most\", Offline-CKS better than or tied with each other smoother), is a "
        "*tie* when every pair is, *does not hold* when a pair is worse, *partly* otherwise. "
        "Over cells: *holds* in every cell, *partly (cells)* naming where it holds. A claim "
        "whose figures a reading lacks is *not tested* under it (not counted).", "",
        f"C1: a method keeps a limit \"approximately\" on a demonstration when at most "
        f"{STATE_SHARE:.0%} of its samples exceed it and none by more than "
        f"{STATE_OVERSHOOT - 1:.0%} (occasional overshoots of a soft constraint, as the "
        f"paper's plots show the constrained curves touching the limits); the claim holds "
        f"in a cell when both constrained methods keep it on at least "
        f"{DEMONSTRATION_MAJORITY:.0%} of the demonstrations and some unconstrained method "
        f"exceeds it, does not hold at most {1 - DEMONSTRATION_MAJORITY:.0%}, else partly. "
        "Judged on the states (the paper's quantity) and, apart, on the FD of the packets "
        "the robot receives. Both thresholds are choices; the figures behind them are below.",
        "",
        f"The readings (variants) of the rules: {readings} (the joint velocity deformation "
        "is over the whole run in every reading: the records have no motion-phase figure for "
        "it). "
        f"The verdicts above are those of the default reading ({default}); the robustness "
        "column names each axis whose other value alone changes a cell's verdict (one axis at "
        "a time; the robustness table counts the readings, all 16, in which the claim "
        "holds). A claim whose methods did not all run in a cell is not tested there.", ""]


def _robustness_table(result: dict) -> str:
    lines = ["| claim | cell | verdict | readings where it holds | depends on |",
             "|---|---|---|---:|---|"]
    for cell, claims in result["cells"].items():
        for claim, row in claims.items():
            depends = row["robustness"] if row["flipping_axes"] else "—"
            lines.append(f"| {claim} | {cell} | {row['verdict']} | "
                         f"{row['holding_variants']} of {row['variants']} | {depends} |")
    return "\n".join(lines)


def _kf_forms(result: dict) -> list[str]:
    forms = result["kf_forms"]
    cells = list(forms)
    if not cells:
        return []
    names = [k for k in next(iter(forms[cells[0]].values())) if k != "all three"]
    lines = ["| cell | KF form | " + " | ".join(names) + " | all three |",
             "|---|---|" + "---|" * (len(names) + 1)]
    for cell in cells:
        for form, row in forms[cell].items():
            lines.append(f"| {cell} | `{form}` | " + " | ".join(row[n] for n in names)
                         + f" | {'yes' if row['all three'] else 'no'} |")
    found = {form: where for form, where in result["kf_reproduces"].items() if where}
    sentences = ([f"`{form}` reproduces all three in {' and '.join(where)}."
                  for form, where in found.items()] if found else
                 ["No KF form reproduces the paper's figures 8, 10 and 11 together in any "
                  "cell."])
    for form in next(iter(forms.values())):
        deforms = [cell for cell in cells if forms[cell][form][names[0]] == "holds"
                   and forms[cell][form][names[1]] == "holds"]
        improves = [cell for cell in cells if forms[cell][form][names[2]] == "holds"]
        sentences.append(f"`{form}` deforms most (figs. 8 and 10) in "
                         f"{' and '.join(deforms) or 'no cell'}, and improves e (fig. 11) in "
                         f"{' and '.join(improves) or 'no cell'}.")
    return [" ".join(sentences), "", "\n".join(lines)]


def _c1_table(result: dict) -> str:
    lines = ["| cell | quantity | method | demonstrations kept approximately | worst ratio | "
             "median worst ratio | mean share of samples over |",
             "|---|---|---|---:|---:|---:|---:|"]
    for cell, claims in result["cells"].items():
        for claim, quantity in (("C1", "states"), ("C1 (FD received)", "FD received")):
            for method, row in claims[claim]["detail"].get("figures", {}).items():
                lines.append(f"| {cell} | {quantity} | {method} | {row['kept_share']:.0%} of "
                             f"{row['n']} | {row['worst_ratio']:.2f} | "
                             f"{row['median_worst_ratio']:.2f} | "
                             f"{100 * row['mean_share_over']:.1f} % |")
    return "\n".join(lines)


def _pairs_table(result: dict) -> str:
    lines = ["| claim | cell | A against B | figure | pairs | median A − B [95 % interval] | "
             "Wilcoxon p | verdict for A |", "|---|---|---|---|---:|---|---:|---|"]
    for cell, claims in result["cells"].items():
        for claim, row in claims.items():
            for pair in row["detail"].get("pairs", []):
                scale, unit, name = _FIGURES[pair["figure"]]
                low, high = (scale * v for v in pair["interval"])
                lines.append(
                    f"| {claim} | {cell} | {pair['a']} against {pair['b']} | {name} | "
                    f"{pair['n']} | {scale * pair['median_difference']:.4g} [{low:.4g}, "
                    f"{high:.4g}] {unit} | {pair['p_value']:.2g} | {pair['verdict']} |")
    return "\n".join(lines)


def paper_verdicts_markdown(result: dict) -> list[str]:
    """The report's section on the claims as the paper states them."""
    return [
        "## The claims as the paper states them", "",
        verdict_table_with_robustness(result), "",
        *_rules(),
        "### Robustness: every reading", "",
        _robustness_table(result), "",
        "### Which KF form reproduces the paper's figures", "",
        "The paper does not say which KF it ran. Its figs. 8 and 10 show the KF deforming "
        "the joint and end-effector tracks most (C2, C3); its fig. 11 shows every method, the "
        "KF included, improving the dynamic response (e below the original's, paired).", "",
        *_kf_forms(result), "",
        "### C1: the states and what the robot receives", "",
        _c1_table(result), "",
        "### Every pair (default reading)", "",
        _pairs_table(result), "",
    ]


_VARIANT_COLUMNS = (
    ("e [mm]", "e_mean_m", 1e3, "{:.3f}"),
    ("e 100 Hz [mm]", "e_tracker_rate_mean_m", 1e3, "{:.3f}"),
    ("e motion [mm]", "e_motion_mean_m", 1e3, "{:.3f}"),
    ("e settle [mm]", "e_settle_mean_m", 1e3, "{:.3f}"),
    ("P [%]", "improvement_ratio_percent", 1.0, "{:.1f}"),
    ("P 100 Hz [%]", "p_tracker_rate_percent", 1.0, "{:.1f}"),
    ("P motion [%]", "p_motion_percent", 1.0, "{:.1f}"),
    ("P 100 Hz motion [%]", "p_tracker_rate_motion_percent", 1.0, "{:.1f}"),
    ("E_def [mm]", "cartesian_deformation_mean_m", 1e3, "{:.3f}"),
    ("E_def motion [mm]", "cartesian_deformation_motion_mean_m", 1e3, "{:.3f}"),
    ("joint def. motion [mrad]", "position_deformation_motion_mean_rad", 1e3, "{:.3f}"),
    ("state acc/limit", "state_acc_max_over_limit", 1.0, "{:.2f}"),
    ("state acc over", "state_acc_fraction_over", 100.0, "{:.1f}%"),
    ("state jerk/limit", "state_jerk_max_over_limit", 1.0, "{:.2f}"),
    ("state jerk over", "state_jerk_fraction_over", 100.0, "{:.1f}%"),
)


def variant_figures_markdown(summary: dict, carried: dict | None = None) -> str:
    """Mean (worst) over the demonstrations of the figures each reading of the rules uses,
    per method (and Online-CKS with σ carried over, ``carried``: its figures)."""
    rows = dict(summary["main"])
    if carried:
        rows["online-cks carried"] = carried
    return figures_table(rows, _VARIANT_COLUMNS)
