"""Paired verdicts (``telesmooth.studies.verdicts``) on hand-made figures with known answers.

* the median's interval against the sign test worked out with ``math.comb`` (n = 10: the 2nd
  and 9th order statistics, coverage 1 − 22/1024);
* the Wilcoxon p-value against an exact enumeration of all 2ⁿ sign patterns of the ranks;
* each verdict: better, worse, tie within the margin, tie when significant but smaller than
  the margin, inconclusive, for a figure where higher is better (P) and one where lower is
  (e); NaN pairs left out; identical figures a tie with p = 1;
* claims over cells (holds / tie / does not hold / partly naming cells) and over variants
  (one verdict, or "depends on" naming each).
"""

import itertools
import math

import numpy as np
import pytest

from telesmooth.studies.verdicts import (
    claim_over_cells,
    compare_paired,
    median_interval,
    robustness,
)


def _sign_test_coverage(n: int, k: int) -> float:
    return 1.0 - 2.0 * sum(math.comb(n, i) for i in range(k)) / 2**n


def test_the_median_interval_is_the_sign_tests():
    d = np.array([5.0, -1.0, 3.0, 2.0, 8.0, 0.5, 4.0, 6.0, 7.0, 1.0])
    low, high, coverage = median_interval(d, 0.95)
    ordered = np.sort(d)
    assert (low, high) == (ordered[1], ordered[8])
    assert coverage == pytest.approx(_sign_test_coverage(10, 2)) == pytest.approx(1 - 22 / 1024)
    assert _sign_test_coverage(10, 3) < 0.95          # k = 3 would not cover
    # Too few pairs for the level: the whole range.
    low, high, coverage = median_interval([1.0, 2.0, 3.0], 0.95)
    assert (low, high) == (1.0, 3.0) and coverage == pytest.approx(0.75)


def _exact_wilcoxon_p(d) -> float:
    ranks = np.argsort(np.argsort(np.abs(d))) + 1.0          # no ties in |d| here
    t = ranks[d > 0].sum()
    totals = [sum(r for r, s in zip(ranks, signs) if s)
              for signs in itertools.product((0, 1), repeat=len(d))]
    totals = np.array(totals)
    return min(1.0, 2.0 * min(np.mean(totals <= t), np.mean(totals >= t)))


@pytest.mark.parametrize("d", [
    [0.3, -0.1, 0.7, 1.2, -0.25, 0.9, 0.45, 1.6],
    [1.0, 2.0, 3.0, 4.0, 5.0, 6.0],
    [-0.5, 0.1, -0.9, 0.35, -1.4, -2.2, 0.05, -0.6, -0.75, 1.1],
])
def test_the_p_value_is_the_exact_signed_rank_tests(d):
    d = np.array(d)
    result = compare_paired(d, np.zeros_like(d), margin=0.0, higher_is_better=True)
    assert result.p_value == pytest.approx(_exact_wilcoxon_p(d), rel=1e-9)


RNG = np.random.default_rng(5)
B = RNG.uniform(10.0, 30.0, size=21)


@pytest.mark.parametrize(("shift", "spread", "higher", "margin", "verdict"), [
    (2.0, 0.0, True, 1.0, "better"),          # P two points higher everywhere
    (-2.0, 0.0, True, 1.0, "worse"),
    (0.5, 0.1, True, 1.0, "tie"),             # within the margin
    (0.6, 0.0, True, 0.5, "better"),
    (-0.002, 0.0, False, 0.001, "better"),    # e lower by 2 µm, margin the tracker's 1 µm
    (0.002, 0.0, False, 0.001, "worse"),
    (0.0, 5.0, True, 1.0, "inconclusive"),    # large spread around 0
])
def test_verdicts(shift, spread, higher, margin, verdict):
    noise = spread * np.sin(np.arange(B.size) * 2.1)
    result = compare_paired(B + shift + noise, B, margin=margin, higher_is_better=higher)
    assert result.verdict == verdict, result
    assert result.n == B.size


def test_significant_but_smaller_than_the_margin_is_a_tie():
    d = np.linspace(0.2, 1.6, 21)          # all positive: p tiny; median 0.9 < margin 1
    result = compare_paired(B + d, B, margin=1.0, higher_is_better=True)
    assert result.p_value < 1e-4
    assert result.interval[0] > 0.0 and result.interval[1] > 1.0
    assert result.verdict == "tie"


def test_nan_pairs_are_left_out_and_identical_figures_tie():
    a = B.copy()
    a[[2, 5]] = np.nan
    result = compare_paired(a, B, margin=0.1, higher_is_better=True)
    assert result.n == B.size - 2 and result.p_value == 1.0 and result.verdict == "tie"
    assert result.median_difference == 0.0 and result.interval == (0.0, 0.0)


def test_bad_arguments():
    with pytest.raises(ValueError, match="margin"):
        compare_paired(B, B, margin=-1.0, higher_is_better=True)
    with pytest.raises(ValueError, match="paired"):
        compare_paired(B, B[:-1], margin=1.0, higher_is_better=True)
    with pytest.raises(ValueError, match="no pairs"):
        compare_paired([np.nan], [1.0], margin=1.0, higher_is_better=True)


def test_claims_over_cells_and_variants():
    over = claim_over_cells
    assert over({"lab 1x": "holds", "lab 4x": "holds"}) == "holds"
    assert over({"lab 1x": "tie", "lab 4x": "tie"}) == "tie"
    assert over({"lab 1x": "tie", "lab 4x": "does not hold"}) == "does not hold"
    assert over({"lab 1x": "holds", "lab 4x": "tie",
                 "lightweight 4x": "holds"}) == "partly (in lab 1x and lightweight 4x)"
    assert over({"a": "inconclusive", "b": "inconclusive"}) == "inconclusive"
    assert over({"a": "does not hold", "b": "inconclusive"}) == (
        "does not hold; inconclusive in b")
    assert over({"a": "holds", "b": "inconclusive", "c": "does not hold"}) == (
        "partly (in a; inconclusive in b)")
    # A cell where the claim partly holds is not a cell where it fails.
    assert over({"a": "partly", "b": "does not hold", "c": "partly"}) == (
        "partly (partly in a and c)")
    assert over({"a": "holds", "b": "partly"}) == "partly (in a; partly in b)"
    assert robustness({"kf": "holds", "kf-predictor": "holds"}) == "holds"
    assert robustness({"kf": "holds", "kf-predictor": "does not hold"}) == (
        "depends on kf → holds, kf-predictor → does not hold")


def test_too_few_pairs_for_the_level_are_inconclusive_unless_within_the_margin():
    # Five pairs cannot give a 95 % interval (the whole range covers 1 − 2/32 = 0.94).
    result = compare_paired([12.0, 13.0, 14.0, 15.0, 16.0], [1.0] * 5, margin=1.0,
                            higher_is_better=True)
    assert result.confidence == pytest.approx(1 - 2 / 32) and result.verdict == "inconclusive"
    six = compare_paired([12.0, 13.0, 14.0, 15.0, 16.0, 17.0], [1.0] * 6, margin=1.0,
                         higher_is_better=True)
    assert six.confidence == pytest.approx(1 - 2 / 64) and six.verdict == "better"
    small = compare_paired([1.2, 1.3], [1.0, 1.0], margin=1.0, higher_is_better=True)
    assert small.verdict == "tie"           # every difference within the margin
