"""The experiment's figures and the paper's claims, from the records of its tasks.

:func:`summarize_cells` groups the records of :mod:`telesmooth.studies.experiment` by cell
(plant × speed) and :func:`summarize` turns one cell's records into means, medians, 90th
percentiles and worst cases per method, with P taken against the original of the same
demonstration; :func:`check_claims` gives a verdict per claim C1–C8 (docs/method.md §7) with the
figures it rests on and the rule applied. Nothing here runs a simulation: it reads records, so
a finished grid can be judged again (e.g. with the other KF form) without recomputing it.
"""

from __future__ import annotations

import math

import numpy as np

from telesmooth.studies.comparison import LEAST_DEFORMATION
from telesmooth.studies.experiment import KF_FORMS, KF_SIGMA_STUDIES, cell_name

__all__ = [
    "APPROXIMATE_LIMIT",
    "C1_QUANTILE",
    "CLAIMS",
    "CONSTRAINED",
    "PAIRED_AGAINST_RUCKIG",
    "PAIRED_SHARE",
    "UNCONSTRAINED",
    "WITHIN_THE_LIMITS",
    "PAIRED_CLAIMS",
    "check_claims",
    "paired_claims",
    "paired_ratio",
    "summarize",
    "summarize_cells",
]

UNCONSTRAINED = ("offline-ks", "bmfls")
"""The paper's unconstrained smoothers besides the KF (whose declared form is added)."""
CONSTRAINED = ("offline-cks", "online-cks")
"""The paper's constrained smoothers: Offline-CKS (state box) and Online-CKS."""

WITHIN_THE_LIMITS = ("offline-cks-trajectory", "online-hard")
"""Offline and online methods that both keep the FD limits (C6 at matched limit satisfaction)."""



CLAIMS = {
    "C1": "Offline-CKS and Online-CKS keep acceleration and jerk within the limits "
          "approximately; the unconstrained methods do not guarantee it.",
    "C2": "Joint position and velocity deformation is small for every method except the KF.",
    "C3": "The end-effector track deformation is small except for the KF.",
    "C4": "Every smoothing method improves dynamic tracking (P > 0), and Offline-CKS most.",
    "C5": "The constrained methods get larger P than the unconstrained ones.",
    "C6": "Offline-CKS deforms less than Online-CKS.",
    "C7": "The KF performs worst overall.",
    "C8": "Under reduced-Q σ decreases monotonically, and later operations are smoother.",
}


_LOWER_IS_WORSE = ("improvement_ratio_percent",)

_NOT_SENSITIVITY = ("main", "reference", "carried")
"""Studies that are not a sensitivity axis (the carried-σ runs are the main table's)."""


def _with_p(records: list[dict]) -> list[dict]:
    """Adds P (and the added latency) of each run against the original of its demonstration
    (NaN, left out of the figures, when that original is not among the records: a shard)."""
    reference = {(r["shape"], r["demo"]): r["metrics"] for r in records
                 if r["kind"] == "run" and r["method"] == "original"
                 and r["study"] in ("main", "reference")}
    missing = {"e_sum_m": math.nan, "latency_s": math.nan}
    out = []
    for record in records:
        if record["kind"] == "run":
            ref = reference.get((record["shape"], record["demo"]), missing)
            m = dict(record["metrics"])
            m["improvement_ratio_percent"] = (
                100.0 * (ref["e_sum_m"] - m["e_sum_m"]) / ref["e_sum_m"])
            m["added_latency_s"] = m["latency_s"] - ref["latency_s"]
            record = {**record, "metrics": m}
        out.append(record)
    return out


def summarize_cells(records: list[dict]) -> dict:
    """:func:`summarize` per (plant, speed) cell: {cell name: summary with "plant" and
    "speed"}, in the order the cells first appear."""
    cells: dict[tuple, list] = {}
    for record in records:
        cells.setdefault((record.get("plant", "lab"), record.get("speed", 1.0)), []).append(
            record)
    return {cell_name(plant, speed): {"plant": plant, "speed": speed, **summarize(rows)}
            for (plant, speed), rows in cells.items()}


def summarize(records: list[dict]) -> dict:
    """Mean, median, 90th percentile and worst case of every figure per run label, over the
    demonstrations of one cell.

    Returns:
        {"main": {label: {figure: {"mean", "median", "p90", "worst", "n",
        "fraction_positive"}}}, "sensitivity": {study: [{value, figure: ...}]}, "c8": {...},
        "paired": {"<method> / ruckig": paired_ratio(...)} for the methods of
        :data:`PAIRED_AGAINST_RUCKIG` (when both ran), "least_deformation": {label:
        paired_ratio(label, offline-hard)} for every label (when offline-hard ran),
        "failed": [{"key", "error"}] of the runs whose method failed (left out of every
        figure), "records": the other records, with P}.
    """
    failed = [{"key": r["key"] if "key" in r else f"{r['shape']}/{r['demo']} {r['label']}",
               "error": r["error"]} for r in records if "error" in r]
    records = _with_p([r for r in records if "error" not in r])
    groups: dict[str, list[dict]] = {}
    for record in records:
        if record["kind"] == "run" and record["study"] == "main":
            groups.setdefault(record["label"], []).append(record["metrics"])
    main = {label: _aggregate(rows) for label, rows in groups.items()}
    sensitivity: dict[str, list] = {}
    by_value: dict[tuple, list] = {}
    for record in records:
        if record["kind"] == "run" and record["study"] not in _NOT_SENSITIVITY:
            by_value.setdefault((record["study"], record["value"]), []).append(record["metrics"])
    # The default point of every axis: the study's method with the scenario's settings on the
    # study's shapes (demonstration 0).
    study_shapes = {r["shape"] for r in records
                    if r["kind"] == "run" and r["study"] not in _NOT_SENSITIVITY}
    for study in {key[0] for key in by_value}:
        method = study[:-len("_sigma0")] if study in KF_SIGMA_STUDIES else "online-cks"
        defaults = [r for r in records if r["kind"] == "run" and r["label"] == method
                    and r["study"] in ("main", "reference") and r["demo"] == 0
                    and r["shape"] in study_shapes]
        values = ({1.0} if study in KF_SIGMA_STUDIES else
                  {r["online_cks"][study] for r in defaults})
        if len(defaults) == len(study_shapes) and len(values) == 1 and None not in values:
            by_value.setdefault((study, values.pop()), []).extend(r["metrics"] for r in defaults)
    for (study, value), rows in sorted(by_value.items()):
        sensitivity.setdefault(study, []).append({"value": value, **_aggregate(rows)})
    c8 = _c8_summary([r for r in records if r["kind"] == "c8"])
    paired = {f"{label} / ruckig": paired_ratio(records, label, "ruckig")
              for label in PAIRED_AGAINST_RUCKIG if label in main and "ruckig" in main}
    least = ({label: paired_ratio(records, label, LEAST_DEFORMATION) for label in main}
             if LEAST_DEFORMATION in main else {})
    modes = [r["plant_modes"] for r in records if "plant_modes" in r
             and r["plant_modes"].get("lowest_ringing_hz") is not None]
    plant = None
    if modes:
        lowest = np.array([m["lowest_ringing_hz"] for m in modes])
        zeta = np.array([m["lowest_ringing_damping_ratio"] for m in modes])
        plant = {"n": len(modes), "lowest_hz_min": float(lowest.min()),
                 "lowest_hz_max": float(lowest.max()), "lowest_zeta_min": float(zeta.min()),
                 "lowest_zeta_max": float(zeta.max())}
    return {"main": main, "sensitivity": sensitivity, "c8": c8, "paired": paired,
            "least_deformation": least, "plant_modes": plant, "failed": failed,
            "records": records}


PAIRED_AGAINST_RUCKIG = ("online-hard", "offline-cks-trajectory")
"""The methods within the limits whose E_def is set against Ruckig's demonstration by
demonstration: whether online-hard's E_def stays within a quarter of Ruckig's, Ruckig tracking
the same stream (:data:`PAIRED_SHARE`)."""

PAIRED_SHARE = 0.25
"""The share of Ruckig's E_def the paired comparison counts the demonstrations above."""


EXACT_DEFORMATION_M = 1e-9
"""A deformation below 1 nm is round-off (the tracker's noise is 0.1 mm): a reference that
small tracks the operator exactly and gives no ratio (a ratio over round-off is meaningless:
it read 6e11 on a demonstration offline-hard passed unchanged)."""


def paired_ratio(records: list[dict], label: str, reference: str,
                 key: str = "cartesian_deformation_mean_m") -> dict:
    """``key`` of run ``label`` over that of ``reference`` on each demonstration both ran.

    Returns:
        {"n", "mean", "worst" (the largest ratio), "worst_demo" ("shape/demo"),
        "above_share" (demonstrations whose ratio exceeds :data:`PAIRED_SHARE`), "share",
        "reference_zero" (demonstrations both ran where the reference's figure is 0, or
        below :data:`EXACT_DEFORMATION_M`: no ratio)}; n = 0 and None figures when no ratio exists.
    """
    values = {}
    for record in records:
        if record["kind"] == "run" and record["study"] == "main" and (
                record["label"] in (label, reference)):
            values.setdefault((record["shape"], record["demo"]), {})[record["label"]] = \
                record["metrics"][key]
    both = {cell: pair for cell, pair in sorted(values.items())
            if label in pair and reference in pair}
    # A demonstration the reference tracks exactly (within round-off: below
    # EXACT_DEFORMATION_M) has no ratio; it is counted, not hidden.
    ratios = {cell: pair[label] / pair[reference] for cell, pair in both.items()
              if pair[reference] > EXACT_DEFORMATION_M}
    skipped = len(both) - len(ratios)
    if not ratios:
        return {"n": 0, "mean": None, "worst": None, "worst_demo": None, "above_share": 0,
                "share": PAIRED_SHARE, "reference_zero": skipped}
    worst_cell = max(ratios, key=ratios.get)
    array = np.array(list(ratios.values()))
    return {"n": len(ratios), "mean": float(array.mean()), "worst": float(ratios[worst_cell]),
            "worst_demo": f"{worst_cell[0]}/{worst_cell[1]}",
            "above_share": int(np.sum(array > PAIRED_SHARE)), "share": PAIRED_SHARE,
            "reference_zero": skipped}


def _aggregate(rows: list[dict]) -> dict:
    out = {}
    for key in rows[0]:
        values = np.array([row[key] for row in rows], dtype=float)
        finite = values[np.isfinite(values)]
        lower_is_worse = key in _LOWER_IS_WORSE
        worst = (np.min if lower_is_worse else np.max)(finite) if finite.size else None
        # The 90th percentile on the bad side (the 10th for P).
        p90 = (float(np.percentile(finite, 10 if lower_is_worse else 90)) if finite.size
               else None)
        out[key] = {"mean": float(finite.mean()) if finite.size else None,
                    "median": float(np.median(finite)) if finite.size else None,
                    "p90": p90, "worst": None if worst is None else float(worst),
                    "n": int(values.size), "n_finite": int(finite.size),
                    "fraction_positive": (float(np.mean(finite > 0)) if finite.size
                                          else None)}
    return out


def _c8_summary(records: list[dict]) -> dict:
    if not records:
        return {}
    pairs = monotone = smoother = 0
    carried, fresh = [], []
    for record in records:
        demos = record["c8"]["demos"]
        monotone += all(d["carried"]["sigma_monotone"] and d["fresh"]["sigma_monotone"]
                        for d in demos)
        for d in demos[1:]:
            pairs += 1
            smoother += d["carried"]["fd_jerk_max_over_limit"] <= \
                d["fresh"]["fd_jerk_max_over_limit"]
            carried.append(d["carried"]["fd_jerk_max_over_limit"])
            fresh.append(d["fresh"]["fd_jerk_max_over_limit"])
    return {"shapes": len(records), "shapes_sigma_monotone": int(monotone),
            "later_operations": pairs, "later_operations_not_rougher": int(smoother),
            "fd_jerk_max_over_limit_carried_mean": float(np.mean(carried)) if carried else None,
            "fd_jerk_max_over_limit_fresh_mean": float(np.mean(fresh)) if fresh else None}


# --- claims -----------------------------------------------------------------------------------

APPROXIMATE_LIMIT = 1.5
"""C1: "within the limits approximately" = at most 1.5 × the limit."""

C1_QUANTILE = 90
"""C1 is judged on this percentile of the per-demonstration worst FD ratio (a distribution over
the demonstrations); the strict rule on the single worst demonstration is reported beside it."""


def _worst_ratios(records: list[dict], label: str) -> np.ndarray:
    """Per demonstration of the main table: max(worst FD acc/a_max, worst FD jerk/j_max)."""
    return np.array([max(r["metrics"]["fd_acc_max_over_limit"],
                         r["metrics"]["fd_jerk_max_over_limit"])
                     for r in records if r["kind"] == "run" and r["study"] == "main"
                     and r["label"] == label], dtype=float)


def _share_over(records: list[dict], label: str) -> float:
    """Mean over the demonstrations of the share of samples over a limit (acc or jerk)."""
    return float(np.mean([max(r["metrics"].get("fd_acc_fraction_over", 0.0),
                              r["metrics"].get("fd_jerk_fraction_over", 0.0))
                          for r in records if r["kind"] == "run" and r["study"] == "main"
                          and r["label"] == label]))


def check_claims(summary: dict, kf_form: str = "kf") -> dict:
    """A verdict per claim of docs/method.md §7 for one cell, with the figures and the rule
    applied.

    Every claim uses the same KF form, ``kf_form`` (the other form's figures are given beside
    it where it ran), and the paper's methods: KF, Offline-KS, Offline-CKS (the state box),
    BMFLS and Online-CKS. Verdicts are ``holds``, ``does not hold``, ``partly`` or ``not
    tested`` (a method the claim needs was not run). Figures are means over demonstrations
    unless named otherwise.
    """
    if kf_form not in KF_FORMS:
        raise ValueError(f"kf_form = {kf_form!r} must be one of {KF_FORMS}")
    other_kf = next(form for form in KF_FORMS if form != kf_form)
    main = summary["main"]
    records = summary.get("records", [])

    def mean(label, key):
        return main[label][key]["mean"] if label in main else None

    def have(*labels):
        return all(label in main for label in labels)

    claims = {}

    def verdict(name, ok, rule, figures):
        claims[name] = {"claim": CLAIMS[name], "rule": rule, "figures": figures,
                        "verdict": ("not tested" if ok is None else
                                    ok if isinstance(ok, str) else
                                    ("holds" if ok else "does not hold"))}

    def beside(key):
        """The other KF form's mean of ``key``, or None."""
        return mean(other_kf, key)

    unconstrained = tuple(m for m in (kf_form,) + UNCONSTRAINED if m in main)
    smoothers = [m for m in (kf_form, "offline-ks", "offline-cks", "bmfls", "online-cks")
                 if m in main]

    # C1: a distribution over the demonstrations, the strict worst case beside it.
    if have(*CONSTRAINED):
        figures = {}
        for label in ("original",) + CONSTRAINED + unconstrained:
            if label not in main:
                continue
            ratios = _worst_ratios(records, label)
            if ratios.size == 0:      # hand-made summaries without records
                ratios = np.array([max(main[label]["fd_acc_max_over_limit"]["worst"],
                                       main[label]["fd_jerk_max_over_limit"]["worst"])])
            figures[label] = {
                "worst_ratio_median": float(np.median(ratios)),
                f"worst_ratio_p{C1_QUANTILE}": float(np.percentile(ratios, C1_QUANTILE)),
                "worst_ratio_max": float(ratios.max()),
                "share_of_samples_over_a_limit": (_share_over(records, label)
                                                  if records else None)}
        quantile = f"worst_ratio_p{C1_QUANTILE}"
        within = {label: figures[label][quantile] <= APPROXIMATE_LIMIT for label in CONSTRAINED}
        broken = [label for label in unconstrained if figures[label][quantile] > 1.0]
        ok = (True if all(within.values()) and broken else
              "partly" if any(within.values()) else False)
        strict_within = {label: figures[label]["worst_ratio_max"] <= APPROXIMATE_LIMIT
                         for label in CONSTRAINED}
        strict_broken = [label for label in unconstrained
                         if figures[label]["worst_ratio_max"] > 1.0]
        strict = ("holds" if all(strict_within.values()) and strict_broken else
                  "partly" if any(strict_within.values()) else "does not hold")
        figures["constrained_within_approximately"] = within
        figures["unconstrained_over_the_limit"] = broken
        figures["strict_rule"] = {"rule": f"the single worst demonstration of both "
                                          f"constrained methods ≤ {APPROXIMATE_LIMIT}× the "
                                          f"limit, and some unconstrained method > 1× in its "
                                          f"worst demonstration",
                                  "verdict": strict}
        verdict("C1", ok, f"the {C1_QUANTILE}th percentile over the demonstrations of the worst "
                f"FD acc/jerk ratio ≤ {APPROXIMATE_LIMIT} for both constrained methods, and "
                f"> 1 for some unconstrained one (the strict rule on the single worst "
                f"demonstration is given beside it: {strict})", figures)
    else:
        verdict("C1", None, "needs offline-cks and online-cks", {})

    def largest(key):
        values = {m: mean(m, key) for m in smoothers}
        return values, max(values, key=values.get)

    # C2, C3: the declared KF form deforms most.
    for name, keys in (("C2", ("position_deformation_mean_rad",
                               "velocity_deformation_mean_rad_per_s")),
                       ("C3", ("cartesian_deformation_mean_m",))):
        if kf_form not in main or len(smoothers) < 3:
            verdict(name, None, f"needs {kf_form} and two other smoothers", {})
            continue
        figures, hits = {}, []
        for key in keys:
            values, top = largest(key)
            figures[key] = {"means": values, "largest": top,
                            f"{other_kf} (beside)": beside(key)}
            hits.append(top == kf_form)
        ok = True if all(hits) else ("partly" if any(hits) else False)
        verdict(name, ok, f"the KF ({kf_form}) has the largest mean deformation of the paper's "
                "smoothing methods" + ("; partly: for some of the figures only"
                                       if len(keys) > 1 else ""), figures)

    key = "improvement_ratio_percent"
    p_known = all(mean(m, key) is not None for m in smoothers)
    # C4
    if len(smoothers) >= 2 and "offline-cks" in main and p_known:
        p = {m: mean(m, key) for m in smoothers}
        positive = {m: main[m][key]["fraction_positive"] for m in smoothers}
        all_positive = all(v > 0 for v in p.values())
        best = max(p, key=p.get)
        ok = (True if all_positive and best == "offline-cks" else
              "partly" if all_positive or best == "offline-cks" else False)
        verdict("C4", ok, "mean P > 0 for every smoothing method of the paper, and Offline-CKS "
                "(state box) has the largest mean P",
                {"P_mean": p, "fraction_of_demos_with_P_positive": positive, "largest": best,
                 "beside": {m: mean(m, key) for m in (other_kf, "offline-cks-trajectory",
                                                      "offline-hard", "online-hard", "ruckig")
                            if m in main}})
    else:
        verdict("C4", None, "needs offline-cks, another smoothing method and, for P, the "
                "original of each demonstration", {})

    # C5
    if have(*CONSTRAINED) and unconstrained and p_known:
        p_con = {m: mean(m, key) for m in CONSTRAINED}
        p_unc = {m: mean(m, key) for m in unconstrained}
        ok = min(p_con.values()) > max(p_unc.values())
        if not ok and max(p_con.values()) > max(p_unc.values()):
            ok = "partly"
        verdict("C5", ok, "every constrained method's mean P exceeds every unconstrained one's",
                {"constrained": p_con, "unconstrained": p_unc,
                 f"{other_kf} (beside)": beside(key)})
    else:
        verdict("C5", None, "needs the constrained and an unconstrained method and, for P, "
                "the original of each demonstration", {})

    # C6: offline against online at matched limit satisfaction, each pair on its own.
    pairs = {"as the paper defines them (offline-cks against online-cks)": CONSTRAINED,
             "both within the limits (offline-cks-trajectory against online-hard)":
                 WITHIN_THE_LIMITS}
    figures, results = {}, []
    for title, (offline, online) in pairs.items():
        if not have(offline, online):
            continue
        key = "cartesian_deformation_mean_m"
        per_demo = paired_ratio(records, offline, online, key) if records else None
        holds = mean(offline, key) < mean(online, key)
        results.append(holds)
        figures[title] = {"offline_E_def_mean_m": mean(offline, key),
                          "online_E_def_mean_m": mean(online, key),
                          "offline_over_online_per_demonstration": per_demo,
                          "verdict": "holds" if holds else "does not hold"}
    ok = (None if not results else True if all(results) else
          "partly" if any(results) else False)
    verdict("C6", ok, "the offline method's mean E_def < the online one's, for each pair that "
            "keeps the limits alike (partly: for one pair only)", figures)

    # C7: mean rank over FD acc, FD jerk, E_def and e (1 = best).
    keys = ("fd_acc_max_over_limit", "fd_jerk_max_over_limit", "cartesian_deformation_mean_m",
            "e_mean_m")
    if kf_form in main and len(smoothers) >= 3:
        ranks = {m: 0.0 for m in smoothers}
        for key in keys:
            order = sorted(smoothers, key=lambda m: mean(m, key))
            for rank, m in enumerate(order, start=1):
                ranks[m] += rank / len(keys)
        worst_method = max(ranks, key=ranks.get)
        verdict("C7", worst_method == kf_form, f"the KF ({kf_form}) has the worst mean rank over "
                "FD acc, FD jerk, E_def and e among the paper's smoothing methods",
                {"mean_rank": ranks, "worst": worst_method})
    else:
        verdict("C7", None, f"needs {kf_form} and two other smoothers", {})

    # C8
    c8 = summary.get("c8") or {}
    if c8:
        monotone = c8["shapes_sigma_monotone"] == c8["shapes"]
        smoother = c8["later_operations_not_rougher"] / max(1, c8["later_operations"])
        ok = True if monotone and smoother == 1.0 else ("partly" if monotone else False)
        verdict("C8", ok, "σ never increases in any shape, and every later operation (σ carried "
                "over) has a worst FD jerk no larger than the same operation from σ_0",
                {**c8, "fraction_not_rougher": smoother})
    else:
        verdict("C8", None, "the C8 study was not run", {})
    return claims


P_MARGIN_PERCENT = 1.0
"""Practical-equivalence margin of P: a paired median difference under 1 percentage point is
a tie."""

DEFORMATION_MARGIN_M = 1e-6
"""Practical-equivalence margin of a Cartesian deformation: the laser tracker's 0.001 mm."""

PAIRED_CLAIMS = {
    "C4": ("\"the performance of Offline-CKS is the best\", judged as its P against every "
           "other smoother's, paired over the demonstrations", "improvement_ratio_percent"),
    "C5": ("the constrained smoother against its unconstrained counterpart: Offline-CKS "
           "against Offline-KS, Online-CKS against BMFLS, on P", "improvement_ratio_percent"),
    "C6": ("Offline-CKS deforms the end-effector track less than Online-CKS "
           "(mean Cartesian deformation)", "cartesian_deformation_mean_m"),
}
"""The claims judged pair by pair (:func:`paired_claims`): the statement and the figure."""


def _paired_figure(records: list[dict], figure: str, a: str, b: str):
    """``figure`` of runs ``a`` and ``b`` on every demonstration both ran (main study), in
    the same order."""
    values: dict = {}
    for record in records:
        if record["kind"] == "run" and record["study"] == "main" and record["label"] in (a, b):
            values.setdefault((record["shape"], record["demo"]), {})[record["label"]] = \
                record["metrics"][figure]
    both = sorted(demo for demo, pair in values.items() if a in pair and b in pair)
    return (np.array([values[d][a] for d in both], dtype=float),
            np.array([values[d][b] for d in both], dtype=float))


def _pairs_for(claim: str, labels: set, kf_form: str) -> list[tuple[str, str]]:
    if claim == "C4":
        others = [label for label in ("offline-ks", kf_form, "bmfls", "online-cks")
                  if label in labels]
        return [("offline-cks", other) for other in others]
    if claim == "C5":
        return [("offline-cks", "offline-ks"), ("online-cks", "bmfls")]
    return [("offline-cks", "online-cks")]


def _claim_in_cell(claim: str, verdicts: list[str]) -> str:
    """A claim's verdict in one cell from its pairs': ``not`` when a pair is worse,
    ``inconclusive`` when one is, ``tie`` when all are ties, ``better`` when all are better
    (C4, "the best": better than or tied with each, better than one), else ``not``."""
    if "worse" in verdicts:
        return "not"
    if "inconclusive" in verdicts:
        return "inconclusive"
    if all(v == "tie" for v in verdicts):
        return "tie"
    if claim == "C4" or all(v == "better" for v in verdicts):
        return "better"
    return "not"


def paired_claims(records: list[dict], kf_form: str = "kf") -> dict:
    """C4, C5 and C6 as the paper states them, judged pair by pair over the demonstrations
    of each cell with :func:`~telesmooth.studies.verdicts.compare_paired` (margins
    :data:`P_MARGIN_PERCENT`, :data:`DEFORMATION_MARGIN_M`).

    A claim holds in a cell when every pair it names is ``better`` (C4: Offline-CKS better or
    tied with each other smoother, "best" allowing a tie, and better than at least one); the
    verdict over cells is :func:`~telesmooth.studies.verdicts.cell_verdict`'s.

    Returns:
        {claim: {"statement", "figure", "cells": {cell: {"verdict", "pairs": [{"a", "b",
        "n", "median_difference", "interval", "p_value", "verdict"}]}}, "verdict"}}.
    """
    from telesmooth.studies.verdicts import cell_verdict, compare_paired

    cells: dict = {}
    for record in records:
        if "error" not in record:
            cells.setdefault(cell_name(record.get("plant", "lab"), record.get("speed", 1.0)),
                             []).append(record)
    # P against the original of the same cell (the originals differ by plant and speed).
    cells = {cell: _with_p(rows) for cell, rows in cells.items()}
    out = {}
    for claim, (statement, figure) in PAIRED_CLAIMS.items():
        higher = figure == "improvement_ratio_percent"
        margin = P_MARGIN_PERCENT if higher else DEFORMATION_MARGIN_M
        per_cell = {}
        for cell, rows in cells.items():
            labels = {r["label"] for r in rows if r["kind"] == "run"}
            pairs = []
            for a, b in _pairs_for(claim, labels, kf_form):
                if a not in labels or b not in labels:
                    continue
                first, second = _paired_figure(rows, figure, a, b)
                if not np.any(np.isfinite(first) & np.isfinite(second)):
                    continue
                result = compare_paired(first, second, margin=margin, higher_is_better=higher)
                pairs.append({"a": a, "b": b, "n": result.n,
                              "median_difference": result.median_difference,
                              "interval": list(result.interval), "p_value": result.p_value,
                              "verdict": result.verdict})
            if not pairs:
                continue
            verdict = _claim_in_cell(claim, [p["verdict"] for p in pairs])
            per_cell[cell] = {"verdict": verdict, "pairs": pairs}
        out[claim] = {"statement": statement, "figure": figure, "cells": per_cell,
                      "verdict": (cell_verdict({c: v["verdict"] for c, v in per_cell.items()})
                                  if per_cell else "not run")}
    return out
