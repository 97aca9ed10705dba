"""The experiment's figures and the paper's claims, from the records of its tasks.

:func:`summarize_cells` groups the records of :mod:`telesmooth.studies.experiment` by cell
(plant × speed) and :func:`summarize` turns one cell's records into means, medians, 90th
percentiles and worst cases per method, with P taken against the original of the same
demonstration; :func:`check_claims` gives a verdict per claim C1–C8 (docs/method.md §7) with the
figures it rests on and the rule applied. Nothing here runs a simulation: it reads records, so
a finished grid can be judged again (e.g. with the other KF form) without recomputing it.
"""

from __future__ import annotations

import functools
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
    "PAPER_CLAIMS",
    "check_claims",
    "paper_verdicts",
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


P_VARIANTS = {"improvement_ratio_percent": "e_sum_m",
              "p_motion_percent": "e_motion_mean_m",
              "p_tracker_rate_percent": "e_tracker_rate_mean_m",
              "p_tracker_rate_motion_percent": "e_tracker_rate_motion_mean_m"}
"""P under each reading of e (key → the e figure it is taken from): at the command instants
over the whole run (the paper's) or the motion phase, at the tracker's 100 Hz over either."""

_LOWER_IS_WORSE = tuple(P_VARIANTS)

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
            for key, e in P_VARIANTS.items():
                if e in m:
                    original = _or_nan(ref.get(e))
                    m[key] = (100.0 * (original - _or_nan(m[e])) / original if original != 0.0
                              else math.nan)
            m["added_latency_s"] = m["latency_s"] - ref["latency_s"]
            record = {**record, "metrics": m}
        out.append(record)
    return out


def summarize_cells(records: list[dict]) -> dict:
    """:func:`summarize` per (plant, speed) cell: {cell name: summary with "plant" and
    "speed"}, in the order the cells first appear."""
    return {cell_name(plant, speed): {"plant": plant, "speed": speed, **summarize(rows)}
            for (plant, speed), rows in _by_cell(records).items()}


def _by_cell(records: list[dict]) -> dict:
    """{(plant, speed): the records of that cell}, in the order the cells first appear."""
    cells: dict[tuple, list] = {}
    for record in records:
        cells.setdefault((record.get("plant", "lab"), record.get("speed", 1.0)), []).append(
            record)
    return cells


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
        figure), "carried": the figures of Online-CKS with σ carried over (None if not run),
        "records": the other records, with P}.
    """
    failed = [{"key": r["key"] if "key" in r else f"{r['shape']}/{r['demo']} {r['label']}",
               "error": r["error"]} for r in records if "error" in r]
    records = _with_p([r for r in records if "error" not in r])
    groups: dict[str, list[dict]] = {}
    for record in records:
        if record["kind"] == "run" and record["study"] == "main":
            groups.setdefault(record["label"], []).append(record["metrics"])
    main = {label: _aggregate(rows) for label, rows in groups.items()}
    carried = [r["metrics"] for r in records if r["kind"] == "run" and r["study"] == "carried"]
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
            "carried": _aggregate(carried) if carried else None, "records": records}


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

# --- the paper's claims as it states them, under every reasonable variant --------------------

VARIANT_AXES = {
    "kf": KF_FORMS,
    "e": ("command instants", "100 Hz"),
    "phase": ("whole run", "motion phase"),
    "sigma": ("fresh", "carried"),
}
"""The reasonable readings of the paper's rules (issue: the paper does not say which):

* ``kf``: the KF comparator as the a-posteriori filter or its one-step predictor;
* ``e``: the response error at each command's instant (the tracker resampled at 4 Hz, the end
  of the command's ramp) or at every 100 Hz tracker sample against the set-point the robot was
  following at that instant;
* ``phase``: e and the deformations over the whole run, or over the operator's motion phase
  only (the holds before and after and the settling add near-zero samples to every method);
* ``sigma``: Online-CKS from σ_0 on every demonstration, or with σ carried over from the
  shape's earlier demonstrations, as the paper keeps σ per operator.
"""

DEFAULT_VARIANT = {"kf": "kf", "e": "command instants", "phase": "whole run", "sigma": "fresh"}
"""The variant of the main verdicts (the paper's own set-up as far as it says; the KF form
is the experiment's ``kf_form``)."""

JOINT_MARGIN_RAD = 1e-6
"""Practical-equivalence margin of a joint deformation: 1 µrad (1 µm at a metre of reach,
the tracker's accuracy); the same number in rad/s for the velocity deformation."""

E_MARGIN_M = 1e-6
"""Practical-equivalence margin of the response error e: the tracker's 0.001 mm."""

RANK_MARGIN = 0.5
"""Practical-equivalence margin of C7's mean rank (over four figures, 1 = best): half a rank."""

C8_MARGIN = 0.05
"""Practical-equivalence margin of C8's worst FD jerk over its limit: 5 % of the limit."""

STATE_SHARE = 0.05
"""C1: a method keeps a limit "approximately" on a demonstration when at most 5 % of its
samples exceed it (occasional overshoots, as the paper's acceleration and jerk plots show the
constrained curves touching the limit lines) …"""

STATE_OVERSHOOT = 1.10
"""… and none by more than 10 % (an overshoot the servo absorbs: the limits are calibrated
with a margin). Both thresholds are choices; the report gives the figures behind them."""

DEMONSTRATION_MAJORITY = 0.9
"""C1 in a cell: holds when both constrained methods keep the limits approximately on at least
90 % of the demonstrations, does not hold when on at most 10 %, else partly."""

PAPER_CLAIMS = {
    "C1": ("\"the proposed methods can constrain the acceleration and jerk within the "
           "specified range approximately\" (Results): the states of Offline-CKS and "
           "Online-CKS (the paper's quantity) within the limits approximately on most "
           "demonstrations, some unconstrained method over them"),
    "C1 (FD received)": ("the same rule on the finite differences of what the robot receives "
                         "(the packets), which the paper does not state"),
    "C2": ("\"the deformations of smoothed joint position and velocity compared with the "
           "original are all very little except Kalman filtering\" (Fig. 8): every other "
           "smoother's joint deformation below the KF's, paired"),
    "C3": ("\"the deformations of the end track are all small except Kalman filtering\" "
           "(Fig. 10): every other smoother's E_def below the KF's, paired"),
    "C4": ("\"all these smoothing methods can increase the accuracy of dynamic response … "
           "the effect of Offline-CKS is the most obvious\" (Fig. 11): every smoother's e "
           "below the original's, and Offline-CKS's P above or tied with every other's"),
    "C5": ("\"only the constrained smoothing methods can limit the acceleration and jerk … "
           "they have a better performance than the others\" (Results): P of Offline-CKS above "
           "Offline-KS's, of Online-CKS above BMFLS's"),
    "C6": ("\"the deformation of Offline-CKS is smaller than Online-CKS\" (Table 2): "
           "Offline-CKS's E_def below Online-CKS's"),
    "C7": ("\"Standard Kalman filter … exhibits the worst performance\" (Results): the "
           "KF's mean rank over FD acceleration, FD jerk, E_def and e worse than every other "
           "smoother's"),
    "C8": ("reduced-Q: σ never increases, and a later operation with σ carried over is "
           "smoother than the same operation from σ_0 (worst FD jerk over the limit)"),
}
"""Each claim as the paper states it (quoted) and how it is tested."""

_SMOOTHERS = ("offline-ks", "offline-cks", "bmfls", "online-cks")

_NEEDS = {"C2": {"KF", *_SMOOTHERS}, "C3": {"KF", *_SMOOTHERS},
          "C4": {"original", "KF", *_SMOOTHERS}, "C5": set(_SMOOTHERS) | {"original"},
          "C6": {"offline-cks", "online-cks"}, "C7": {"KF", *_SMOOTHERS}}
"""The methods (roles) each comparison claim names: all must have run in a cell."""


def _variant_figures(metrics: dict, variant: dict) -> dict:
    """The figures one record gives under a variant of the rules."""
    motion = variant["phase"] == "motion phase"
    e_key = {("command instants", False): "e_mean_m",
             ("command instants", True): "e_motion_mean_m",
             ("100 Hz", False): "e_tracker_rate_mean_m",
             ("100 Hz", True): "e_tracker_rate_motion_mean_m"}[(variant["e"], motion)]
    return {
        "e": metrics.get(e_key, math.nan),
        "position": metrics.get("position_deformation_motion_mean_rad" if motion
                                else "position_deformation_mean_rad", math.nan),
        "velocity": metrics.get("velocity_deformation_mean_rad_per_s", math.nan),
        "cartesian": metrics.get("cartesian_deformation_motion_mean_m" if motion
                                 else "cartesian_deformation_mean_m", math.nan),
        "fd_acc": metrics.get("fd_acc_max_over_limit", math.nan),
        "fd_jerk": metrics.get("fd_jerk_max_over_limit", math.nan),
    }


def _demonstrations(rows: list[dict], variant: dict) -> dict:
    """{(shape, demo): {role: record}} of one cell under ``variant``: the roles are the
    original, the paper's smoothers and ``KF`` (the variant's form); Online-CKS is the fresh
    or the carried-over run."""
    online = "online-cks carried" if variant["sigma"] == "carried" else "online-cks"
    roles = {"original": "original", variant["kf"]: "KF", online: "online-cks",
             **{m: m for m in _SMOOTHERS if m != "online-cks"}}
    out: dict = {}
    for record in rows:
        if record["kind"] != "run" or "error" in record or record["label"] not in roles:
            continue
        wanted = "carried" if record["label"] == "online-cks carried" else "main"
        if record["study"] != wanted:
            continue
        out.setdefault((record["shape"], record["demo"]), {})[roles[record["label"]]] = record
    return out


@functools.lru_cache(maxsize=4096)
def _compare_cached(first: tuple, second: tuple, margin: float, higher: bool):
    """:func:`~telesmooth.studies.verdicts.compare_paired`, once per distinct input (the
    variants of a claim often give the same figures: e.g. the σ reading leaves the KF's)."""
    from telesmooth.studies.verdicts import compare_paired

    return compare_paired(np.array(first), np.array(second), margin=margin,
                          higher_is_better=higher)


def _pair(demos: dict, a: str, b: str, figure, margin: float, higher: bool,
          name: str) -> dict | None:
    """``compare_paired`` of ``figure(role, demo figures)`` of roles a and b over the
    demonstrations both ran."""
    both = [roles for _, roles in sorted(demos.items()) if a in roles and b in roles]
    if not both:
        return None
    first = np.array([figure(roles, a) for roles in both], dtype=float)
    second = np.array([figure(roles, b) for roles in both], dtype=float)
    if not np.any(np.isfinite(first) & np.isfinite(second)):
        return None
    result = _compare_cached(tuple(first), tuple(second), margin, higher)
    return {"a": a, "b": b, "figure": name, "n": result.n,
            "median_difference": result.median_difference,
            "interval": list(result.interval), "p_value": result.p_value,
            "verdict": result.verdict}


def _in_cell(pairs: list[dict], ties_support: bool = False) -> str:
    """A claim's verdict in a cell from its pairs (each expecting A better than B): ``holds``
    when every pair is better (or, with ``ties_support``, better or tied with at least one
    better), ``tie`` when every pair is a tie, ``does not hold`` when a pair is worse,
    ``inconclusive`` when a pair is and none is worse, else ``partly``."""
    verdicts = [p["verdict"] for p in pairs]
    if not verdicts:
        return "not tested"
    if "worse" in verdicts:
        return "does not hold"
    if "inconclusive" in verdicts:
        return "inconclusive"
    if all(v == "tie" for v in verdicts):
        return "tie"
    if all(v == "better" for v in verdicts) or ties_support:
        return "holds"
    return "partly"


def _c1_cell(demos: dict, source: str) -> dict:
    """C1 on the states (``source`` "state") or on the FD of what the robot receives ("fd"):
    per method, the share of demonstrations kept approximately, the worst ratio and the mean
    share of samples over a limit."""
    def keeps(metrics):
        ratio = max(_or_nan(metrics.get(f"{source}_acc_max_over_limit")),
                    _or_nan(metrics.get(f"{source}_jerk_max_over_limit")))
        share = max(_or_nan(metrics.get(f"{source}_acc_fraction_over")),
                    _or_nan(metrics.get(f"{source}_jerk_fraction_over")))
        return ratio, share

    figures = {}
    for method in ("offline-cks", "online-cks", "KF", "offline-ks", "bmfls"):
        values = [keeps(roles[method]["metrics"]) for roles in demos.values() if method in roles]
        values = [(r, s) for r, s in values if math.isfinite(r) and math.isfinite(s)]
        if not values:
            continue
        ratios, shares = np.array(values).T
        kept = (shares <= STATE_SHARE) & (ratios <= STATE_OVERSHOOT)
        figures[method] = {"n": len(values), "kept_share": float(kept.mean()),
                           "worst_ratio": float(ratios.max()),
                           "median_worst_ratio": float(np.median(ratios)),
                           "mean_share_over": float(shares.mean()),
                           "over_somewhere": bool(np.any(ratios > 1.0 + 1e-6))}
    if not all(m in figures for m in CONSTRAINED):
        return {"verdict": "not tested", "figures": figures}
    kept = min(figures[m]["kept_share"] for m in CONSTRAINED)
    # The contrast by the same rule: some unconstrained method does not keep the limits
    # approximately on the majority of the demonstrations.
    contrast = any(figures[m]["kept_share"] < DEMONSTRATION_MAJORITY
                   for m in ("KF", "offline-ks", "bmfls") if m in figures)
    verdict = ("holds" if kept >= DEMONSTRATION_MAJORITY and contrast else
               "does not hold" if kept <= 1.0 - DEMONSTRATION_MAJORITY else "partly")
    return {"verdict": verdict, "figures": figures}


def _or_nan(value) -> float:
    return math.nan if value is None else float(value)


def _p_of(roles: dict, role: str) -> float:
    reference = roles.get("original")
    if reference is None or not reference["figures"]["e"] > 0.0:
        return math.nan
    return 100.0 * (reference["figures"]["e"] - roles[role]["figures"]["e"]) \
        / reference["figures"]["e"]


def _ranks(roles: dict) -> dict:
    """Each smoother's mean rank (1 = best) over FD acc, FD jerk, E_def and e on one
    demonstration (ties share the mean rank)."""
    from scipy.stats import rankdata

    present = [r for r in ("KF",) + _SMOOTHERS if r in roles]
    total = np.zeros(len(present))
    for key in ("fd_acc", "fd_jerk", "cartesian", "e"):
        total += rankdata([roles[r]["figures"][key] for r in present])
    return dict(zip(present, total / 4.0))


def _claims_in_cell(rows: list[dict], variant: dict) -> dict:
    """Every claim's verdict but C8's (which no reading changes: :func:`_c8_cell`), with its
    pairs or figures, in one cell under ``variant``."""
    demos = _demonstrations(rows, variant)
    for roles in demos.values():
        for role, record in list(roles.items()):
            roles[role] = {**record, "figures": _variant_figures(record["metrics"], variant)}
    out = {"C1": _c1_cell(demos, "state"), "C1 (FD received)": _c1_cell(demos, "fd")}
    present = {role for roles in demos.values() for role in roles}

    def figure(key):
        return lambda roles, role: roles[role]["figures"][key]

    c2 = []
    for m in _SMOOTHERS:
        for key in ("position", "velocity"):
            pair = _pair(demos, m, "KF", figure(key), JOINT_MARGIN_RAD, False, key)
            if pair is not None:
                c2.append(pair)
    out["C2"] = {"verdict": _in_cell(c2), "pairs": c2}
    c3 = [p for m in _SMOOTHERS
          if (p := _pair(demos, m, "KF", figure("cartesian"), DEFORMATION_MARGIN_M, False,
                         "cartesian"))]
    out["C3"] = {"verdict": _in_cell(c3), "pairs": c3}
    improve = [p for m in ("KF",) + _SMOOTHERS
               if (p := _pair(demos, m, "original", figure("e"), E_MARGIN_M, False, "e"))]
    best = [p for m in ("KF", "offline-ks", "bmfls", "online-cks")
            if (p := _pair(demos, "offline-cks", m, _p_of, P_MARGIN_PERCENT, True, "P"))]
    parts = (_in_cell(improve), _in_cell(best, ties_support=True))
    out["C4"] = {"verdict": (parts[0] if parts[0] == parts[1] else
                             "does not hold" if "does not hold" in parts else
                             "inconclusive" if "inconclusive" in parts else
                             "not tested" if "not tested" in parts else "partly"),
                 "pairs": improve + best, "parts": {"every smoother improves": parts[0],
                                                   "Offline-CKS best": parts[1]}}
    c5 = [p for a, b in (("offline-cks", "offline-ks"), ("online-cks", "bmfls"))
          if (p := _pair(demos, a, b, _p_of, P_MARGIN_PERCENT, True, "P"))]
    out["C5"] = {"verdict": _in_cell(c5), "pairs": c5}
    c6 = [p for p in [_pair(demos, "offline-cks", "online-cks", figure("cartesian"),
                            DEFORMATION_MARGIN_M, False, "cartesian")] if p]
    out["C6"] = {"verdict": _in_cell(c6), "pairs": c6}
    for roles in demos.values():
        for role, rank in _ranks(roles).items():
            roles[role]["figures"]["rank"] = rank
    c7 = [p for m in _SMOOTHERS
          if (p := _pair(demos, m, "KF", figure("rank"), RANK_MARGIN, False, "rank"))]
    out["C7"] = {"verdict": _in_cell(c7), "pairs": c7}
    # A claim whose methods did not all run in the cell is not tested (its verdict would rest
    # on the pairs that remain).
    for claim, needed in _NEEDS.items():
        if not needed <= present:
            out[claim] = {"verdict": "not tested",
                          "missing": sorted(needed - present)}
    return out


def _c8_cell(rows: list[dict]) -> dict:
    """C8 on every later demonstration of the main table: Online-CKS with σ carried over
    against the same demonstration from σ_0 (worst FD jerk over its limit, margin
    :data:`C8_MARGIN`), and σ never increasing in the carried runs."""
    runs: dict = {}
    for record in rows:
        if record["kind"] == "run" and "error" not in record and record["demo"] > 0 and (
                (record["label"], record["study"]) in (("online-cks", "main"),
                                                      ("online-cks carried", "carried"))):
            runs.setdefault((record["shape"], record["demo"]), {})[record["study"]] = record
    both = [pair for _, pair in sorted(runs.items()) if len(pair) == 2]
    if not both:
        return {"verdict": "not tested"}
    from telesmooth.studies.verdicts import compare_paired

    carried = np.array([p["carried"]["metrics"]["fd_jerk_max_over_limit"] for p in both])
    fresh = np.array([p["main"]["metrics"]["fd_jerk_max_over_limit"] for p in both])
    result = compare_paired(carried, fresh, margin=C8_MARGIN, higher_is_better=False)
    monotone = [p["carried"].get("online_cks", {}).get("sigma_monotone") for p in both]
    monotone_share = float(np.mean([bool(m) for m in monotone]))
    pair = {"a": "carried", "b": "fresh", "figure": "fd_jerk", "n": result.n,
            "median_difference": result.median_difference,
            "interval": list(result.interval), "p_value": result.p_value,
            "verdict": result.verdict}
    verdict = _in_cell([pair])
    if monotone_share < 1.0 and verdict in ("holds", "tie"):
        verdict = "partly"
    return {"verdict": verdict, "pairs": [pair], "sigma_monotone_share": monotone_share,
            "not_rougher_share": float(np.mean(carried <= fresh + C8_MARGIN))}


def _variants(kf_form: str) -> list[dict]:
    """Every combination of :data:`VARIANT_AXES`, the default (``kf_form``) first."""
    import itertools

    default = {**DEFAULT_VARIANT, "kf": kf_form}
    combos = [dict(zip(VARIANT_AXES, values))
              for values in itertools.product(*VARIANT_AXES.values())]
    return [default] + [v for v in combos if v != default]


def variant_name(variant: dict) -> str:
    """e.g. ``kf, command instants, whole run, fresh``."""
    return ", ".join(variant[axis] for axis in VARIANT_AXES)


def paper_verdicts(records: list[dict], kf_form: str = "kf") -> dict:
    """Every claim as the paper states it (:data:`PAPER_CLAIMS`), per cell, under every
    variant of :data:`VARIANT_AXES`; the default variant (:data:`DEFAULT_VARIANT` with
    ``kf_form``) gives the verdict, the others its robustness.

    Returns:
        {"variants": [names, default first], "cells": {cell: {claim: {"verdict" (default
        variant), "detail" (its pairs or figures), "by_variant": {name: verdict},
        "robustness" (:func:`~telesmooth.studies.verdicts.robustness` over the variants that
        differ from the default in one axis), "holding_variants" (how many hold)}}},
        "claims": {claim: {"statement", "verdict" (over cells)}}, "kf_reproduces": {form:
        [cells where that form reproduces the paper's figs. 8, 10 and 11 together]},
        "kf_forms": {cell: {form: {figure: verdict, "all three": bool}}}}.
    """
    from telesmooth.studies.verdicts import claim_over_cells, robustness

    if kf_form not in KF_FORMS:
        raise ValueError(f"kf_form = {kf_form!r} must be one of {KF_FORMS}")
    variants = _variants(kf_form)
    default = variants[0]
    # P is taken per pair from the reading's own e (_p_of): the summaries' P is not needed.
    cells = {cell_name(*key): [r for r in rows if "error" not in r]
             for key, rows in _by_cell(records).items()}
    out_cells: dict = {}
    kf_forms: dict = {}
    for cell, rows in cells.items():
        c8 = _c8_cell(rows)          # the same in every reading
        results = [{**_claims_in_cell(rows, variant), "C8": c8} for variant in variants]
        per_claim = {}
        for claim in PAPER_CLAIMS:
            by_variant = {variant_name(v): r[claim]["verdict"] for v, r in zip(variants, results)}
            # One axis at a time from the default: which reading the verdict depends on.
            single = {}
            for axis, values in VARIANT_AXES.items():
                for value in values:
                    changed = {**default, axis: value}
                    single[f"{axis}: {value}"] = by_variant[variant_name(changed)]
            main = by_variant[variant_name(default)]
            # A reading without the figures (e.g. records from before a figure existed) is
            # not tested, not another verdict.
            flipping = {name.split(": ")[0] for name, verdict in single.items()
                        if verdict not in (main, "not tested")}
            tested = {name: v for name, v in by_variant.items() if v != "not tested"}
            per_claim[claim] = {
                "verdict": main,
                "detail": {k: v for k, v in results[0][claim].items() if k != "verdict"},
                "by_variant": by_variant,
                "robustness": robustness({name: verdict for name, verdict in single.items()
                                          if name.split(": ")[0] in flipping
                                          and verdict != "not tested"} or {"": main}),
                "flipping_axes": sorted(flipping, key=list(VARIANT_AXES).index),
                "holding_variants": sum(v == "holds" for v in tested.values()),
                "variants": len(tested)}
        # Which KF form reproduces the paper's KF: deforming most in its figs. 8 and 10 (C2,
        # C3) while still improving the dynamic response in its fig. 11.
        forms = {}
        for form in KF_FORMS:
            result = results[[variant_name(v) for v in variants].index(
                variant_name({**default, "kf": form}))]
            kf_pair = next((p for p in result["C4"].get("pairs", [])
                            if p["a"] == "KF" and p["b"] == "original"), None)
            figures = {"fig. 8 (C2)": result["C2"]["verdict"],
                       "fig. 10 (C3)": result["C3"]["verdict"],
                       "fig. 11 (the KF's e below the original's)":
                           "not tested" if kf_pair is None else
                           {"better": "holds", "worse": "does not hold"}.get(
                               kf_pair["verdict"], kf_pair["verdict"])}
            forms[form] = {**figures, "all three": all(v == "holds" for v in figures.values())}
        kf_forms[cell] = forms
        out_cells[cell] = per_claim
    kf_reproduces = {form: [cell for cell in out_cells if kf_forms[cell][form]["all three"]]
                     for form in KF_FORMS}
    claims = {}
    for claim, statement in PAPER_CLAIMS.items():
        verdicts = {cell: out_cells[cell][claim]["verdict"] for cell in out_cells
                    if out_cells[cell][claim]["verdict"] != "not tested"}
        claims[claim] = {"statement": statement,
                         "verdict": claim_over_cells(verdicts) if verdicts else "not tested"}
    return {"variants": [variant_name(v) for v in variants], "cells": out_cells,
            "claims": claims, "kf_forms": kf_forms, "kf_reproduces": kf_reproduces}
