"""Verdicts a referee can check: methods compared pair by pair over the same demonstrations.

A claim such as "Offline-CKS gets a larger P than Offline-KS" is judged on the paired
differences d_i = a_i − b_i of one figure over the demonstrations both methods ran, never on
two means:

* the **median paired difference** and its distribution-free confidence interval, the order
  statistics [d_(k), d_(n−k+1)] whose coverage the binomial distribution gives (the sign
  test's interval, :func:`median_interval`);
* the two-sided **Wilcoxon signed-rank** p-value (``scipy.stats.wilcoxon``; zero differences
  are split between the signs, ``zero_method="zsplit"``; all-zero differences give p = 1);
* a stated **practical-equivalence margin** m (e.g. 1 percentage point of P, or the tracker's
  0.001 mm for e): a difference smaller than m either way is a tie, whatever its p-value.

:func:`compare_paired` turns these into one of :data:`PAIR_VERDICTS`; :func:`claim_over_cells`
and :func:`robustness` combine verdicts over cells and over the reasonable variants of a
rule (the KF form, e at command instants or at 100 Hz, …).
"""

from __future__ import annotations

import dataclasses

import numpy as np

__all__ = ["PAIR_VERDICTS", "PairedComparison", "claim_over_cells", "compare_paired",
           "median_interval", "robustness"]

PAIR_VERDICTS = ("better", "tie", "worse", "inconclusive")
"""``better``: the interval lies beyond 0 on the better side and the median is at least the
margin; ``worse``: the same on the other side; ``tie``: the interval lies within ±margin, or
the difference is significant but smaller than the margin; ``inconclusive``: anything else
(the interval reaches past the margin and includes 0, or there are too few pairs for an
interval of the level: fewer than 6 at 95 %)."""


@dataclasses.dataclass(frozen=True)
class PairedComparison:
    """The paired comparison of a figure of method A against method B.

    Attributes:
        n: Pairs (demonstrations both methods ran, with finite figures).
        median_difference: Median of a − b.
        interval: (low, high), the confidence interval of that median.
        confidence: Its actual coverage (≥ the level asked for; 0 when n is too small).
        p_value: Two-sided Wilcoxon signed-rank p-value.
        margin: The practical-equivalence margin.
        higher_is_better: Whether a larger figure is better (P) or a smaller one (e, E_def).
        verdict: One of :data:`PAIR_VERDICTS`, for A against B.
    """

    n: int
    median_difference: float
    interval: tuple[float, float]
    confidence: float
    p_value: float
    margin: float
    higher_is_better: bool
    verdict: str


def median_interval(differences, level: float = 0.95) -> tuple[float, float, float]:
    """The distribution-free confidence interval of the median of ``differences``: the order
    statistics [d_(k), d_(n−k+1)] with the largest k whose coverage
    1 − 2·P(Bin(n, ½) ≤ k − 1) is at least ``level``; returns (low, high, coverage). With too
    few values for the level the interval is the whole range and the coverage what it is."""
    from scipy.stats import binom

    d = np.sort(np.asarray(differences, dtype=float))
    n = d.size
    if n == 0:
        raise ValueError("no pairs: the methods share no demonstration with finite figures")
    best = 1
    for k in range(1, n // 2 + 1):
        if 1.0 - 2.0 * binom.cdf(k - 1, n, 0.5) >= level:
            best = k
        else:
            break
    coverage = 1.0 - 2.0 * binom.cdf(best - 1, n, 0.5)
    return float(d[best - 1]), float(d[n - best]), float(coverage)


def _wilcoxon_p(differences: np.ndarray) -> float:
    from scipy.stats import wilcoxon

    if not np.any(differences != 0.0):
        return 1.0
    return float(wilcoxon(differences, zero_method="zsplit", alternative="two-sided").pvalue)


def compare_paired(a, b, *, margin: float, higher_is_better: bool,
                   level: float = 0.95) -> PairedComparison:
    """Method A's figure against method B's, paired over the same demonstrations.

    Args:
        a, b: The figure per demonstration, in the same order (NaN: that demonstration is
            left out of both).
        margin: The practical-equivalence margin (≥ 0), in the figure's unit.
        higher_is_better: True for P, False for e or a deformation.
        level: The interval's confidence level.

    Raises:
        ValueError: unequal lengths, a negative margin, or no pair left.
    """
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    if a.shape != b.shape or a.ndim != 1:
        raise ValueError(f"a and b must be paired 1-D figures; got shapes {a.shape}, {b.shape}")
    if not margin >= 0.0:
        raise ValueError(f"margin = {margin!r} must be ≥ 0")
    keep = np.isfinite(a) & np.isfinite(b)
    d = a[keep] - b[keep]
    low, high, coverage = median_interval(d, level)
    median = float(np.median(d))
    p = _wilcoxon_p(d)
    sign = 1.0 if higher_is_better else -1.0
    # In the "better" direction: positive means A is better.
    gain_low, gain_high = sorted((sign * low, sign * high))
    gain = sign * median
    if -margin < gain_low and gain_high < margin:
        verdict = "tie"
    elif coverage < level:
        verdict = "inconclusive"          # too few pairs for an interval of that level
    elif gain_low > 0.0:
        verdict = "better" if gain >= margin else "tie"
    elif gain_high < 0.0:
        verdict = "worse" if -gain >= margin else "tie"
    else:
        verdict = "inconclusive"
    return PairedComparison(n=int(d.size), median_difference=median, interval=(low, high),
                            confidence=coverage, p_value=p, margin=float(margin),
                            higher_is_better=higher_is_better, verdict=verdict)


def claim_over_cells(verdicts: dict) -> str:
    """A claim's verdict over cells from each cell's (``holds``, ``tie``, ``partly``,
    ``inconclusive``, ``does not hold``): ``holds`` when it holds in every cell, ``tie`` or
    ``inconclusive`` when every cell is one, ``does not hold`` when it neither holds nor partly
    holds in any cell, else ``partly (…)`` naming where it holds, where partly and where it is
    inconclusive ("; inconclusive in …" after ``does not hold`` too). Cells are joined by
    " and " (their names may hold commas: "lab, 1×")."""
    if not verdicts:
        raise ValueError("no cells")
    values = list(verdicts.values())
    for single in ("holds", "tie", "inconclusive"):
        if all(verdict == single for verdict in values):
            return single

    def cells(kind):
        return " and ".join(str(c) for c, verdict in verdicts.items() if verdict == kind)

    unclear = ("inconclusive in " + cells("inconclusive")) if "inconclusive" in values else ""
    if "holds" not in values and "partly" not in values:
        return "does not hold" + (f"; {unclear}" if unclear else "")
    parts = [f"{word} in {cells(word)}" if word == "partly" else f"in {cells(word)}"
             for word in ("holds", "partly") if word in values]
    return "partly (" + "; ".join(parts + ([unclear] if unclear else [])) + ")"


def robustness(verdicts_by_variant: dict) -> str:
    """One verdict when every reasonable variant of a rule gives it, else ``depends on …``
    naming each variant with its verdict (e.g. ``depends on kf-form: kf → holds,
    kf-predictor → does not hold``)."""
    if not verdicts_by_variant:
        raise ValueError("no variants")
    distinct = set(verdicts_by_variant.values())
    if len(distinct) == 1:
        return distinct.pop()
    return "depends on " + ", ".join(f"{variant} → {verdict}"
                                     for variant, verdict in verdicts_by_variant.items())
