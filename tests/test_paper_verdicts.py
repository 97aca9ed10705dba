"""The claims as the paper states them, judged pair by pair under every variant
(studies.claims.paper_verdicts), on hand-made records whose verdicts are known by
construction: clear wins, ties under the margin, a claim that flips with one reading."""

from __future__ import annotations

import copy

import pytest

from telesmooth.studies.claims import (
    C8_MARGIN,
    DEFAULT_VARIANT,
    PAPER_CLAIMS,
    VARIANT_AXES,
    paper_verdicts,
    variant_name,
)

DEMOS = 8
METHODS = ("original", "kf", "kf-predictor", "offline-ks", "offline-cks", "bmfls", "online-cks")


def base_metrics(method: str, demo: int) -> dict:
    """Figures where every claim's pairs are clear: the KF forms deform most, every smoother
    improves e, Offline-CKS best, constrained above unconstrained, Offline-CKS deforms less
    than Online-CKS, the constrained states within the limits."""
    rank = {"original": 0, "kf": 6, "kf-predictor": 7, "offline-ks": 2, "offline-cks": 1,
            "bmfls": 4, "online-cks": 3}[method]
    # The demonstrations differ a little, and not alike for every method (no tied pairs).
    jitter = 1.0 + 0.01 * demo * (1.0 + rank / 10.0)
    e = {"original": 10.0, "kf": 8.0, "kf-predictor": 8.5, "offline-ks": 6.0,
         "offline-cks": 3.0, "bmfls": 7.0, "online-cks": 5.0}[method] * 1e-3 * jitter
    deformation = 0.0 if method == "original" else 1e-4 * rank * jitter
    constrained = method in ("offline-cks", "online-cks")
    state = None if method == "original" else (1.0 if constrained else 3.0)
    share = None if method == "original" else (0.0 if constrained else 0.3)
    return {
        "e_sum_m": e * 40, "e_mean_m": e, "e_motion_mean_m": 2 * e,
        "e_tracker_rate_mean_m": 1.5 * e, "e_tracker_rate_motion_mean_m": 3 * e,
        "cartesian_deformation_mean_m": deformation,
        "cartesian_deformation_motion_mean_m": 2 * deformation,
        "position_deformation_mean_rad": deformation, "position_deformation_motion_mean_rad":
            2 * deformation, "velocity_deformation_mean_rad_per_s": deformation,
        "fd_acc_max_over_limit": 1.0 if constrained else 1.0 + rank,
        "fd_jerk_max_over_limit": 1.0 if constrained else 1.0 + rank,
        "fd_acc_fraction_over": 0.0 if constrained else 0.3,
        "fd_jerk_fraction_over": 0.0 if constrained else 0.3,
        "state_acc_max_over_limit": state, "state_jerk_max_over_limit": state,
        "state_acc_fraction_over": share, "state_jerk_fraction_over": share,
        "latency_s": 0.0,
    }


def make_records(edit=None) -> list[dict]:
    records = []
    for demo in range(DEMOS):
        for method in METHODS:
            metrics = base_metrics(method, demo)
            if edit:
                edit(method, demo, metrics)
            records.append({"kind": "run", "shape": "S", "demo": demo, "method": method,
                            "label": method, "study": "main", "plant": "lab", "speed": 1.0,
                            "metrics": metrics})
            if method == "online-cks":
                carried = copy.deepcopy(records[-1])
                carried.update(label="online-cks carried", study="carried",
                               online_cks={"sigma_monotone": True})
                # Later operations with σ carried over: 0.2 of the limit smoother.
                if demo > 0:
                    carried["metrics"]["fd_jerk_max_over_limit"] -= 0.2
                records.append(carried)
    return records


def verdicts(records, kf_form="kf"):
    return paper_verdicts(records, kf_form)["cells"]["lab, 1×"]


def test_clear_figures_make_every_claim_hold_under_every_variant():
    cell = verdicts(make_records())
    for claim in PAPER_CLAIMS:
        assert cell[claim]["verdict"] == "holds", (claim, cell[claim])
        assert cell[claim]["robustness"] == "holds"
        assert cell[claim]["holding_variants"] == cell[claim]["variants"] == 16
    assert paper_verdicts(make_records())["claims"]["C6"]["verdict"] == "holds"


def test_a_difference_under_the_margin_is_a_tie():
    def close(method, demo, m):
        # Offline-CKS deforms 0.1 µm less than Online-CKS: under the tracker's 1 µm.
        if method == "offline-cks":
            for key in ("cartesian_deformation_mean_m", "cartesian_deformation_motion_mean_m"):
                m[key] = base_metrics("online-cks", demo)[key] - 1e-7
    cell = verdicts(make_records(close))
    assert cell["C6"]["verdict"] == "tie"
    pair = cell["C6"]["detail"]["pairs"][0]
    assert pair["n"] == DEMOS and pair["median_difference"] == pytest.approx(-1e-7)


def test_offline_cks_tied_with_another_for_best_still_holds_c4():
    def tied(method, demo, m):
        # Offline-KS's e 0.2 % of the original's above Offline-CKS's: P 0.2 points apart.
        if method == "offline-ks":
            cks = base_metrics("offline-cks", demo)
            for key in ("e_sum_m", "e_mean_m", "e_motion_mean_m", "e_tracker_rate_mean_m",
                        "e_tracker_rate_motion_mean_m"):
                m[key] = cks[key] + 0.002 * base_metrics("original", demo)[key]
    cell = verdicts(make_records(tied))
    best = {p["b"]: p["verdict"] for p in cell["C4"]["detail"]["pairs"]
            if p["a"] == "offline-cks"}
    assert best["offline-ks"] == "tie" and best["bmfls"] == "better"
    assert cell["C4"]["verdict"] == "holds"
    # C5 asks for Offline-CKS *above* Offline-KS: a tie is not that.
    assert cell["C5"]["verdict"] == "partly"


def test_a_verdict_that_flips_with_the_kf_form_names_it():
    def small_kf(method, demo, m):
        # The a-posteriori KF deforms least; its predictor still most.
        if method == "kf":
            for key in ("cartesian_deformation_mean_m", "cartesian_deformation_motion_mean_m"):
                m[key] = 1e-6 * (1 + 0.01 * demo)
    records = make_records(small_kf)
    cell = verdicts(records, "kf")
    assert cell["C3"]["verdict"] == "does not hold"
    assert cell["C3"]["robustness"] == ("depends on kf: kf → does not hold, "
                                        "kf: kf-predictor → holds")
    assert cell["C3"]["holding_variants"] == 8
    # Judged with the predictor as the declared form, the same records give the other side.
    assert verdicts(records, "kf-predictor")["C3"]["verdict"] == "holds"
    # Only the predictor deforms most in the paper's figs. 8 (joints, C2, unchanged here:
    # both forms) and 10; both improve e (fig. 11).
    result = paper_verdicts(records, "kf")
    forms = result["kf_forms"]["lab, 1×"]
    assert forms["kf"]["fig. 10 (C3)"] == "does not hold" and not forms["kf"]["all three"]
    assert forms["kf-predictor"]["all three"]
    assert result["kf_reproduces"] == {"kf": [], "kf-predictor": ["lab, 1×"]}
    from telesmooth.scripts.verdict_report import paper_verdicts_markdown

    text = "\n".join(paper_verdicts_markdown(result))
    assert "`kf-predictor` reproduces all three in lab, 1×." in text
    assert "`kf` deforms most (figs. 8 and 10) in no cell, and improves e (fig. 11) in lab, 1×." \
        in text


def test_a_verdict_that_flips_with_e_at_100_hz_names_it():
    def ruckus(method, demo, m):
        # At 100 Hz Offline-CKS tracks worse than Offline-KS (e.g. its ramps ring).
        if method == "offline-cks":
            for key in ("e_tracker_rate_mean_m", "e_tracker_rate_motion_mean_m"):
                m[key] = base_metrics("bmfls", demo)[key] * 1.2
    cell = verdicts(make_records(ruckus))
    assert cell["C5"]["verdict"] == "holds"
    assert cell["C5"]["robustness"].startswith("depends on e: command instants → holds, "
                                               "e: 100 Hz → does not hold")
    name = variant_name({**DEFAULT_VARIANT, "e": "100 Hz"})
    assert cell["C5"]["by_variant"][name] == "does not hold"


def test_c1_needs_the_constrained_states_within_on_most_demonstrations():
    def overshoot(method, demo, m):
        # Online-CKS's states 30 % over on half the demonstrations.
        if method == "online-cks" and demo % 2:
            m["state_jerk_max_over_limit"] = 1.3
    cell = verdicts(make_records(overshoot))
    assert cell["C1"]["verdict"] == "partly"
    figures = cell["C1"]["detail"]["figures"]["online-cks"]
    assert figures["kept_share"] == 0.5 and figures["worst_ratio"] == pytest.approx(1.3)
    # The FD of what is received is judged apart, and unchanged here.
    assert cell["C1 (FD received)"]["verdict"] == "holds"


def test_c8_is_the_carried_runs_against_the_fresh_ones_with_a_tolerance():
    def slight(method, demo, m):
        pass
    records = make_records(slight)
    for record in records:
        if record["label"] == "online-cks carried" and record["demo"] > 0:
            # Rougher by under the tolerance: no better, no worse.
            record["metrics"]["fd_jerk_max_over_limit"] += 0.2 + C8_MARGIN / 2
    cell = verdicts(records)
    assert cell["C8"]["verdict"] == "tie"
    assert cell["C8"]["detail"]["pairs"][0]["n"] == DEMOS - 1     # later operations only
    # σ that grew once makes the claim partly.
    records = make_records()
    next(r for r in records if r["label"] == "online-cks carried" and r["demo"] == 3)[
        "online_cks"]["sigma_monotone"] = False
    c8 = verdicts(records)["C8"]
    assert c8["verdict"] == "partly"
    assert c8["detail"]["sigma_monotone_share"] == pytest.approx(6 / 7)


def test_the_variants_are_every_combination_with_the_default_first():
    names = paper_verdicts(make_records())["variants"]
    assert len(names) == len(set(names)) == 2 ** len(VARIANT_AXES)
    assert names[0] == variant_name(DEFAULT_VARIANT)


def test_a_failed_half_of_c4_fails_the_claim():
    def kf_worse(method, demo, m):
        # The KF's e above the original's: "every smoother improves" fails, whatever the rest.
        if method == "kf":
            for key in ("e_mean_m", "e_motion_mean_m", "e_tracker_rate_mean_m",
                        "e_tracker_rate_motion_mean_m"):
                m[key] = 1.2 * base_metrics("original", demo)[key]
    cell = verdicts(make_records(kf_worse))
    assert cell["C4"]["detail"]["parts"] == {"every smoother improves": "does not hold",
                                             "Offline-CKS best": "holds"}
    assert cell["C4"]["verdict"] == "does not hold"


def test_c1_needs_an_unconstrained_method_that_does_not_keep_the_limits_by_the_same_rule():
    def gentle(method, demo, m):
        # Every unconstrained method within 5 % of its limits on few samples: "approximately"
        # kept by C1's own rule, so nothing sets the constrained methods apart.
        if method in ("kf", "offline-ks", "bmfls"):
            m.update(state_acc_max_over_limit=1.05, state_jerk_max_over_limit=1.05,
                     state_acc_fraction_over=0.01, state_jerk_fraction_over=0.01)
    assert verdicts(make_records(gentle))["C1"]["verdict"] == "partly"


def test_a_claim_whose_methods_did_not_all_run_is_not_tested():
    records = [r for r in make_records() if r["label"] != "bmfls"]
    cell = verdicts(records)
    assert cell["C5"]["verdict"] == "not tested" and cell["C5"]["detail"]["missing"] == ["bmfls"]
    assert cell["C6"]["verdict"] == "holds"           # it names no BMFLS
