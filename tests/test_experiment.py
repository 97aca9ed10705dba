"""The LASA experiment (diagrams/experiment.py, `telesmooth experiment`)."""

from __future__ import annotations

import copy
import json
import math

import numpy as np
import pytest

from telesmooth.diagrams.comparison import response_latency
from telesmooth.diagrams.experiment import (
    ExperimentConfig,
    check_claims,
    make_tasks,
    run_experiment,
    summarize,
)
from telesmooth.diagrams.scenario import load_scenario
from telesmooth.scripts.cli import main

# Short runs: the demonstration at 2.5× the pen's speed instead of 1×, a short settle.
FAST = "{haptic: {lasa_mapping: {time_scale: 4.0, hold_start_s: 0.5, hold_end_s: 1.0}}}"


@pytest.fixture(scope="module")
def base():
    return load_scenario(scenario_text=FAST)


def small_config(**overrides):
    fields = dict(shapes=("Angle",), methods=("original", "bmfls"), sensitivity_shapes=(),
                  c8_shapes=(), settle_s=2.0)
    fields.update(overrides)
    return ExperimentConfig(**fields)


# --- latency ----------------------------------------------------------------------------------


@pytest.mark.parametrize("delay", [0.0, 0.37, 1.23])
def test_response_latency_recovers_a_known_delay(delay):
    t = 0.25 * np.arange(60)
    track = lambda s: np.stack([np.sin(0.7 * s), np.cos(0.3 * s), 0 * s], axis=-1)  # noqa: E731
    tracker_t = 0.01 * np.arange(2500)
    tool = track(tracker_t - delay)
    found = response_latency(track(t), t, tracker_t, tool, max_latency_s=3.0)
    assert found == pytest.approx(delay, abs=0.005 + 1e-9)


def test_response_latency_needs_a_long_enough_record():
    with pytest.raises(ValueError, match="max_latency_s"):
        response_latency(np.zeros((3, 3)), [0.0, 1.0, 2.0], [0.0, 0.5], np.zeros((2, 3)),
                         max_latency_s=1.0)


# --- the grid ---------------------------------------------------------------------------------


def test_the_grid_has_every_cell_once_in_report_order():
    config = ExperimentConfig(shapes=("Angle", "Worm"), demos=(0, 3),
                              methods=("kf", "online-cks"), sensitivity_shapes=("Angle", "Leaf_1"),
                              sigma0_factors=(0.1,), sigma_min_ratios=(0.01,), rhos=(0.5, 0.9),
                              c8_shapes=("Worm",))
    tasks = make_tasks(config)
    assert [t.index for t in tasks] == list(range(len(tasks)))
    main_cells = [(t.shape, t.demo, t.method) for t in tasks if t.study == "main"]
    assert main_cells == [(s, d, m) for s in ("Angle", "Worm") for d in (0, 3)
                          for m in ("original", "kf", "online-cks")]
    study = [(t.shape, t.study, t.value) for t in tasks
             if t.study not in ("main", "reference", "c8")]
    assert study == [(s, k, v) for s in ("Angle", "Leaf_1")
                     for k, v in (("sigma0", 0.1), ("sigma_min", 0.01), ("rho", 0.5),
                                  ("rho", 0.9))]
    # Leaf_1 demo 0 is not in the main table, so its original (P's reference) and default
    # Online-CKS runs are added.
    assert [(t.shape, t.method) for t in tasks if t.study == "reference"] == [
        ("Leaf_1", "original"), ("Leaf_1", "online-cks")]
    assert [(t.kind, t.shape) for t in tasks if t.kind == "c8"] == [("c8", "Worm")]
    # The seed is a function of the demonstration only.
    seeds = {(t.shape, t.demo): t.seed for t in tasks if t.kind == "run"}
    assert all(t.seed == seeds[(t.shape, t.demo)] for t in tasks if t.kind == "run")
    assert len(set(seeds.values())) == len(seeds)


@pytest.mark.parametrize("overrides, message", [
    ({"shapes": ("Angle", "Circle")}, r"shapes: unknown LASA shape\(s\) \['Circle'\]"),
    ({"demos": (7,)}, r"demos = \[7\] must be indices 0–6"),
    ({"methods": ("kalman",)}, r"methods \['kalman'\]"),
    ({"plant_time_step_s": 0.0}, r"plant_time_step_s = 0.0"),
    ({"rhos": (1.2,)}, r"rhos: 1.2"),
    ({"offline_solver": "cvxpy"}, r"offline_solver = 'cvxpy' must be one of"),
])
def test_bad_configuration_is_named(overrides, message):
    with pytest.raises(ValueError, match=message):
        small_config(**overrides)


# --- aggregation and claims (hand-made records: an independent computation of P) --------------


def record(shape, demo, method, e_sum, latency, **metrics):
    figures = dict(fd_acc_max_over_limit=1.0, fd_jerk_max_over_limit=1.0,
                   cartesian_deformation_mean_m=0.0, position_deformation_mean_rad=0.0,
                   velocity_deformation_mean_rad_per_s=0.0, e_mean_m=e_sum / 10)
    figures.update(metrics, e_sum_m=e_sum, latency_s=latency)
    return {"kind": "run", "shape": shape, "demo": demo, "method": method, "label": method,
            "study": "main", "value": None, "metrics": figures}


def test_p_is_taken_against_the_original_of_the_same_demonstration():
    records = [record("A", 0, "original", 10.0, 0.2), record("A", 0, "kf", 8.0, 0.3),
               record("B", 0, "original", 4.0, 0.1), record("B", 0, "kf", 5.0, 0.1)]
    summary = summarize(copy.deepcopy(records))
    p = summary["main"]["kf"]["improvement_ratio_percent"]
    assert p["mean"] == pytest.approx((20.0 + -25.0) / 2)
    assert p["worst"] == pytest.approx(-25.0)  # P: the smallest is the worst
    assert p["fraction_positive"] == 0.5
    latency = summary["main"]["kf"]["added_latency_s"]
    assert latency["mean"] == pytest.approx(0.05) and latency["worst"] == pytest.approx(0.1)
    assert summary["main"]["original"]["improvement_ratio_percent"]["mean"] == 0.0


def test_online_hard_is_set_against_ruckig_demonstration_by_demonstration():
    # Ratios 0.1, 0.5 and 0.2 (B/0 twice as far as the others); C/0 has no Ruckig run.
    cells = {("A", 0): (1.0, 10.0), ("B", 0): (4.0, 8.0), ("B", 3): (1.0, 5.0)}
    records = []
    for (shape, demo), (hard, ruckig) in cells.items():
        records += [record(shape, demo, "original", 10.0, 0.0),
                    record(shape, demo, "online-hard", 10.0, 0.0,
                           cartesian_deformation_mean_m=hard),
                    record(shape, demo, "ruckig", 10.0, 0.0,
                           cartesian_deformation_mean_m=ruckig)]
    records += [record("C", 0, "original", 10.0, 0.0),
                record("C", 0, "online-hard", 10.0, 0.0, cartesian_deformation_mean_m=9.0)]
    # D/0: Ruckig tracked it exactly (E_def 0): no ratio, counted apart.
    records += [record("D", 0, "original", 10.0, 0.0),
                record("D", 0, "online-hard", 10.0, 0.0, cartesian_deformation_mean_m=1.0),
                record("D", 0, "ruckig", 10.0, 0.0, cartesian_deformation_mean_m=0.0)]
    paired = summarize(records)["paired"]
    assert set(paired) == {"online-hard / ruckig"}
    row = paired["online-hard / ruckig"]
    assert row["n"] == 3 and row["mean"] == pytest.approx((0.1 + 0.5 + 0.2) / 3)
    assert row["worst"] == pytest.approx(0.5) and row["worst_demo"] == "B/0"
    assert row["above_share"] == 1 and row["share"] == 0.25 and row["reference_zero"] == 1
    # Without Ruckig in the grid there is nothing to pair.
    assert summarize([r for r in records if r["method"] != "ruckig"])["paired"] == {}


def claims_for(p, deformation, fd):
    records = []
    for method in ("original",) + tuple(p):
        records.append(record("A", 0, method, 10.0 * (1 - p.get(method, 0.0) / 100), 0.0,
                              cartesian_deformation_mean_m=deformation.get(method, 0.0),
                              position_deformation_mean_rad=deformation.get(method, 0.0),
                              velocity_deformation_mean_rad_per_s=deformation.get(method, 0.0),
                              fd_acc_max_over_limit=fd.get(method, 1.0),
                              fd_jerk_max_over_limit=fd.get(method, 1.0)))
    return check_claims(summarize(records))


def test_claims_follow_their_rules_both_ways():
    paper_like = claims_for(
        p={"kf": 1.0, "kf-predictor": 0.5, "offline-ks": 2.0, "bmfls": 2.5, "offline-cks": 9.0,
           "online-cks": 5.0},
        deformation={"kf": 9.0, "kf-predictor": 10.0, "offline-ks": 1.0, "bmfls": 1.0,
                     "offline-cks": 2.0, "online-cks": 3.0},
        fd={"original": 8.0, "kf": 6.0, "kf-predictor": 9.0, "offline-ks": 2.0, "bmfls": 2.0,
            "offline-cks": 1.2, "online-cks": 1.4})
    for name in ("C1", "C2", "C3", "C4", "C5", "C6", "C7"):
        assert paper_like[name]["verdict"] == "holds", (name, paper_like[name])
    assert paper_like["C8"]["verdict"] == "not tested"

    reversed_ = claims_for(
        p={"kf": 3.0, "kf-predictor": -1.0, "offline-ks": 4.0, "bmfls": 2.0, "offline-cks": 1.0,
           "online-cks": 2.5},
        deformation={"kf": 0.5, "kf-predictor": 0.6, "offline-ks": 1.0, "bmfls": 1.0,
                     "offline-cks": 4.0, "online-cks": 3.0},
        fd={"offline-cks": 1.0, "online-cks": 1.9, "kf": 1.0, "kf-predictor": 1.0,
            "offline-ks": 1.0, "bmfls": 1.0})
    assert reversed_["C1"]["verdict"] == "partly"       # Online-CKS 1.9 > 1.5
    assert reversed_["C2"]["verdict"] == "does not hold"  # Offline-CKS deforms most
    assert reversed_["C2"]["figures"]["position_deformation_mean_rad"]["largest"] == \
        "offline-cks"
    assert reversed_["C4"]["verdict"] == "does not hold"  # a negative P, Offline-KS best
    assert reversed_["C5"]["verdict"] == "does not hold"
    assert reversed_["C6"]["verdict"] == "does not hold"


# --- runs: determinism across workers, the command line ---------------------------------------


def strip_timing(records):
    return [{k: v for k, v in r.items() if k != "wall_s"} for r in records]


def test_results_do_not_depend_on_the_number_of_workers(base):
    pytest.importorskip("distributed")
    config = small_config(c8_shapes=("Angle",))
    tasks = [t for t in make_tasks(config)]
    serial = run_experiment(base, config, workers=0, tasks=tasks)
    lines = []
    parallel = run_experiment(base, config, workers=2, tasks=tasks, progress=lines.append)
    assert strip_timing(serial) == strip_timing(parallel)
    assert [r["index"] for r in parallel] == [t.index for t in tasks]
    assert len(lines) == len(tasks) and lines[-1].startswith(f"[{len(tasks)}/{len(tasks)}]")
    # A run is a real simulation: the robot moved and its error is finite and small.
    run = next(r for r in serial if r["method"] == "bmfls")
    assert 0 < run["metrics"]["e_mean_m"] < 0.01
    assert run["metrics"]["delay_s"] == 0.75
    c8 = next(r for r in serial if r["kind"] == "c8")["c8"]["demos"]
    assert len(c8) == 7 and c8[0]["carried"] == c8[0]["fresh"]  # the first starts from σ_0


def test_cli_writes_the_report_and_names_bad_shapes(tmp_path, capsys):
    out = tmp_path / "exp"
    status = main(["experiment", "--scenario-text", FAST, "--out", str(out), "--shapes",
                   "Angle", "--methods", "original,kf,offline-cks,ruckig",
                   "--sensitivity-shapes", "Angle", "--c8-shapes", "none", "--workers", "0",
                   "--settle", "2", "--solver", "banded-ip"])
    captured = capsys.readouterr()
    assert status == 0, captured.err
    assert "report:" in captured.out
    data = json.loads((out / "experiment.json").read_text())
    assert set(data["summary"]["main"]) == {"original", "kf", "offline-cks", "ruckig"}
    assert data["config"]["offline_solver"] == "banded-ip"
    assert {"C1", "C8"} <= set(data["claims"])
    assert data["claims"]["C8"]["verdict"] == "not tested"
    sensitivity = data["summary"]["sensitivity"]
    assert set(sensitivity) == {"sigma0", "sigma_min", "rho"}
    # Each axis includes the scenario's default point (the default Online-CKS run).
    assert 1.0 in [row["value"] for row in sensitivity["sigma0"]]
    assert 0.8 in [row["value"] for row in sensitivity["rho"]]
    assert 2.5e-4 in [round(row["value"], 12) for row in sensitivity["sigma_min"]]
    text = (out / "report.md").read_text()
    for name in ("limits.png", "tradeoff.png", "improvement.png", "sensitivity.png"):
        assert (out / name).stat().st_size > 0 and name in text
    assert math.isfinite(data["summary"]["main"]["ruckig"]["added_latency_s"]["mean"])

    status = main(["experiment", "--out", str(out), "--shapes", "Angle,Circle", "--workers",
                   "0"])
    assert status == 2
    assert "unknown shape(s) ['Circle']" in capsys.readouterr().err
