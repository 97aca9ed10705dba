"""The LASA experiment (studies/experiment.py, `telesmooth experiment`)."""

from __future__ import annotations

import copy
import dataclasses
import json
import math

import numpy as np
import pytest

from telesmooth.arms.self_contact import CLEARANCE_M
from telesmooth.diagrams.scenario import LoadScenario
from telesmooth.scripts.cli import main
from telesmooth.studies.claims import check_claims, summarize, summarize_cells
from telesmooth.studies.comparison import response_latency
from telesmooth.studies.experiment import (
    CARRIED_LABEL,
    ExperimentConfig,
    experiment_scenario,
    make_tasks,
    run_experiment,
    task_groups,
)

# Short runs: short holds; the experiment's speed 2.5 (2.5× the pen's speed) is this time scale.
FAST = "{haptic: {lasa_mapping: {time_scale: 4.0, hold_start_s: 0.5, hold_end_s: 1.0}}}"


@pytest.fixture(scope="module")
def base():
    return LoadScenario(scenario_text=FAST)


def small_config(**overrides):
    fields = dict(shapes=("Angle",), methods=("original", "bmfls"), sensitivity_shapes=(),
                  c8_shapes=(), settle_s=2.0, speeds=(2.5,))
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
                              c8_shapes=("Worm",), kf_sigma0_factors=(10.0,))
    tasks = make_tasks(config)
    assert [t.index for t in tasks] == list(range(len(tasks)))
    main_cells = [(t.shape, t.demo, t.method) for t in tasks if t.study == "main"]
    assert main_cells == [(s, d, m) for s in ("Angle", "Worm") for d in (0, 3)
                          for m in ("original", "kf", "online-cks")]
    # Online-CKS with σ carried over, beside every demonstration's fresh one, in its group.
    carried = [(t.shape, t.demo, t.method, t.label) for t in tasks if t.study == "carried"]
    assert carried == [(s, d, "online-cks", CARRIED_LABEL) for s in ("Angle", "Worm")
                       for d in (0, 3)]
    for group in task_groups(tasks):
        if any(t.study == "carried" for t in group):
            assert any(t.study == "main" and t.method == "online-cks" for t in group)
    study = [(t.shape, t.study, t.value) for t in tasks
             if t.study not in ("main", "reference", "c8", "carried")]
    assert study == [(s, k, v) for s in ("Angle", "Leaf_1")
                     for k, v in (("sigma0", 0.1), ("sigma_min", 0.01), ("rho", 0.5),
                                  ("rho", 0.9), ("kf_sigma0", 10.0),
                                  ("kf-predictor_sigma0", 10.0))]
    assert {t.method for t in tasks if t.study.endswith("_sigma0") and t.study != "sigma0"} \
        == {"kf", "kf-predictor"}
    # Leaf_1 demo 0 is not in the main table, so its original (P's reference) and the
    # default runs of each study's method are added; Angle lacks only kf-predictor.
    assert [(t.shape, t.method) for t in tasks if t.study == "reference"] == [
        ("Angle", "kf-predictor"), ("Leaf_1", "original"), ("Leaf_1", "online-cks"),
        ("Leaf_1", "kf"), ("Leaf_1", "kf-predictor")]
    assert [(t.kind, t.shape) for t in tasks if t.kind == "c8"] == [("c8", "Worm")]
    # The seed is a function of the demonstration only.
    seeds = {(t.shape, t.demo): t.seed for t in tasks if t.kind == "run"}
    assert all(t.seed == seeds[(t.shape, t.demo)] for t in tasks if t.kind == "run")
    assert len(set(seeds.values())) == len(seeds)


@pytest.mark.parametrize("overrides, message", [
    ({"shapes": ("Angle", "Circle")}, r"shapes: unknown LASA shape\(s\) \['Circle'\]"),
    ({"demos": (7,)}, r"demos = \[7\] must be indices 0–6"),
    ({"methods": ("kalman",)}, r"methods \['kalman'\]"),
    ({"plant_time_step_s": -0.001}, r"plant_time_step_s = -0.001"),
    ({"plant_time_step_s": math.nan}, r"plant_time_step_s = nan"),
    ({"rhos": (1.2,)}, r"rhos: 1.2"),
    ({"offline_solver": "cvxpy"}, r"offline_solver = 'cvxpy' must be one of"),
])
def test_bad_configuration_is_named(overrides, message):
    with pytest.raises(ValueError, match=message):
        small_config(**overrides)


# --- aggregation and claims (hand-made records: an independent computation of P) --------------


def record(shape, demo, method, e_sum, latency, **metrics):
    figures = dict(fd_acc_max_over_limit=1.0, fd_jerk_max_over_limit=1.0,
                   fd_acc_fraction_over=0.0, fd_jerk_fraction_over=0.0,
                   cartesian_deformation_mean_m=0.0, position_deformation_mean_rad=0.0,
                   velocity_deformation_mean_rad_per_s=0.0, e_mean_m=e_sum / 10,
                   operator_error_mean_m=0.0, residual_motion_m=0.0, settling_time_s=0.0)
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
    # E/0: Ruckig's deformation is round-off (1e-16 m): exact too, no ratio of 1e16.
    records += [record("E", 0, "original", 10.0, 0.0),
                record("E", 0, "online-hard", 10.0, 0.0, cartesian_deformation_mean_m=1.0),
                record("E", 0, "ruckig", 10.0, 0.0, cartesian_deformation_mean_m=1e-16)]
    paired = summarize(records)["paired"]
    assert set(paired) == {"online-hard / ruckig"}
    row = paired["online-hard / ruckig"]
    assert row["n"] == 3 and row["mean"] == pytest.approx((0.1 + 0.5 + 0.2) / 3)
    assert row["worst"] == pytest.approx(0.5) and row["worst_demo"] == "B/0"
    assert row["above_share"] == 1 and row["share"] == 0.25 and row["reference_zero"] == 2
    # Without Ruckig in the grid there is nothing to pair.
    assert summarize([r for r in records if r["method"] != "ruckig"])["paired"] == {}


def claims_for(p, deformation, fd, kf_form="kf"):
    records = []
    for method in ("original",) + tuple(p):
        records.append(record("A", 0, method, 10.0 * (1 - p.get(method, 0.0) / 100), 0.0,
                              cartesian_deformation_mean_m=deformation.get(method, 0.0),
                              position_deformation_mean_rad=deformation.get(method, 0.0),
                              velocity_deformation_mean_rad_per_s=deformation.get(method, 0.0),
                              fd_acc_max_over_limit=fd.get(method, 1.0),
                              fd_jerk_max_over_limit=fd.get(method, 1.0)))
    return check_claims(summarize(records), kf_form)


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
    # Every P of the declared KF form's set is positive, but Offline-KS has the largest.
    assert reversed_["C4"]["verdict"] == "partly"
    assert reversed_["C4"]["figures"]["largest"] == "offline-ks"
    assert reversed_["C4"]["figures"]["beside"]["kf-predictor"] == pytest.approx(-1.0)
    assert reversed_["C5"]["verdict"] == "does not hold"
    assert reversed_["C6"]["verdict"] == "does not hold"


def test_every_claim_uses_the_declared_kf_form_and_reports_the_other_beside_it():
    """The same figures judged with each KF form: the a-posteriori filter deforms least here
    and the predictor most, so C2/C3 hold for the predictor only, and the verdict follows the
    declaration, never whichever form fits."""
    figures = dict(
        p={"kf": 3.0, "kf-predictor": -4.0, "offline-ks": 2.0, "bmfls": 2.5,
           "offline-cks": 9.0, "online-cks": 5.0},
        deformation={"kf": 0.1, "kf-predictor": 10.0, "offline-ks": 1.0, "bmfls": 1.0,
                     "offline-cks": 2.0, "online-cks": 3.0},
        fd={"original": 8.0, "kf": 6.0, "kf-predictor": 9.0, "offline-ks": 2.0, "bmfls": 2.0,
            "offline-cks": 1.2, "online-cks": 1.4})
    posterior, predictor = claims_for(**figures), claims_for(**figures, kf_form="kf-predictor")
    assert posterior["C3"]["verdict"] == "does not hold"
    assert predictor["C3"]["verdict"] == "holds"
    key = "cartesian_deformation_mean_m"
    assert posterior["C3"]["figures"][key]["kf-predictor (beside)"] == 10.0
    assert "kf-predictor" not in posterior["C3"]["figures"][key]["means"]
    assert posterior["C4"]["verdict"] == "holds"          # the predictor's P < 0 is beside
    assert predictor["C4"]["verdict"] == "partly"
    with pytest.raises(ValueError, match="kf_form = 'kalman'"):
        check_claims(summarize([record("A", 0, "original", 1.0, 0.0)]), "kalman")


def _demos(label, ratios, **metrics):
    return [record("S", demo, label, 10.0, 0.0, fd_acc_max_over_limit=ratio,
                   fd_jerk_max_over_limit=0.5, **metrics) for demo, ratio in enumerate(ratios)]


def test_c1_is_judged_on_the_90th_percentile_with_the_strict_rule_beside_it():
    """Ten demonstrations: Online-CKS is within 1.5× on nine and 3× on one; its 90th
    percentile is 1.5 + 0.1 × (3 − 1.5) = 1.65 with numpy's linear interpolation, so C1 is
    'partly' (Offline-CKS within), and the strict rule on the single worst is also partly."""
    records = []
    for demo in range(10):
        records.append(record("S", demo, "original", 10.0, 0.0))
    records += _demos("offline-cks", [1.0] * 10)
    records += _demos("online-cks", [1.2] * 8 + [1.5, 3.0])
    records += _demos("kf", [4.0] * 10)
    c1 = check_claims(summarize(records))["C1"]
    assert c1["figures"]["online-cks"]["worst_ratio_p90"] == pytest.approx(1.65)
    assert c1["figures"]["online-cks"]["worst_ratio_median"] == pytest.approx(1.2)
    assert c1["verdict"] == "partly" and c1["figures"]["strict_rule"]["verdict"] == "partly"
    # With the outlier at 1.55 the percentile is within (1.4 + 0.1 × 0.15 = 1.415), the
    # strict rule still not.
    records = [r for r in records if r["label"] != "online-cks"]
    records += _demos("online-cks", [1.2] * 8 + [1.4, 1.55])
    c1 = check_claims(summarize(records))["C1"]
    assert c1["verdict"] == "holds" and c1["figures"]["strict_rule"]["verdict"] == "partly"


def test_c6_compares_offline_and_online_at_matched_limit_satisfaction():
    records = [record("S", 0, "original", 10.0, 0.0)]
    for label, e_def in (("offline-cks", 3.0), ("online-cks", 2.0),
                         ("offline-cks-trajectory", 1.0), ("online-hard", 4.0)):
        records.append(record("S", 0, label, 10.0, 0.0, cartesian_deformation_mean_m=e_def))
    c6 = check_claims(summarize(records))["C6"]
    assert c6["verdict"] == "partly"
    pairs = c6["figures"]
    assert [row["verdict"] for row in pairs.values()] == ["does not hold", "holds"]
    within = pairs["both within the limits (offline-cks-trajectory against online-hard)"]
    assert within["offline_over_online_per_demonstration"]["mean"] == pytest.approx(0.25)
    only_paper = [r for r in records if r["label"] not in ("offline-cks-trajectory",
                                                            "online-hard")]
    assert check_claims(summarize(only_paper))["C6"]["verdict"] == "does not hold"


def test_every_method_is_set_beside_offline_hard_demonstration_by_demonstration():
    records = []
    for demo, (hard, cks) in enumerate(((1.0, 3.0), (2.0, 2.0), (0.0, 1.0))):
        records += [record("S", demo, "original", 10.0, 0.0),
                    record("S", demo, "offline-hard", 10.0, 0.0,
                           cartesian_deformation_mean_m=hard),
                    record("S", demo, "online-cks", 10.0, 0.0,
                           cartesian_deformation_mean_m=cks)]
    least = summarize(records)["least_deformation"]
    assert least["online-cks"]["n"] == 2 and least["online-cks"]["mean"] == pytest.approx(2.0)
    assert least["online-cks"]["reference_zero"] == 1     # offline-hard deforms nothing there
    assert least["offline-hard"]["mean"] == pytest.approx(1.0)


def test_cells_are_summarised_apart():
    records = []
    for plant, speed, e_sum in (("lab", 1.0, 8.0), ("lightweight", 2.5, 12.0)):
        for method, e in (("original", 10.0), ("kf", e_sum)):
            records.append({**record("A", 0, method, e, 0.0), "plant": plant, "speed": speed})
    cells = summarize_cells(records)
    assert list(cells) == ["lab, 1×", "lightweight, 2.5×"]
    assert cells["lab, 1×"]["main"]["kf"]["improvement_ratio_percent"]["mean"] == \
        pytest.approx(20.0)
    assert cells["lightweight, 2.5×"]["main"]["kf"]["improvement_ratio_percent"]["mean"] == \
        pytest.approx(-20.0)


def test_the_grid_spans_plants_and_speeds_and_each_task_has_a_stable_key(base):
    config = small_config(plants=("lab", "lightweight"), speeds=(1.0, 2.5),
                          c8_shapes=("Angle",))
    tasks = make_tasks(config)
    cells = [(t.plant, t.speed) for t in tasks]
    assert sorted(set(cells)) == [("lab", 1.0), ("lab", 2.5), ("lightweight", 1.0),
                                  ("lightweight", 2.5)]
    assert all(cells.count(cell) == 3 for cell in set(cells))   # original, bmfls, C8
    assert len({t.key for t in tasks}) == len(tasks)
    assert [t.key for t in make_tasks(config)] == [t.key for t in tasks]
    scenario = experiment_scenario(base, config, "Angle", 0, plant="lightweight", speed=2.5)
    assert scenario.haptic.lasa_mapping.time_scale == pytest.approx(10.0 / 2.5)
    # The speed is the hand's, whatever time scale the base scenario has (FAST has 4).
    assert experiment_scenario(base, config, "Angle", 0, speed=1.0) \
        .haptic.lasa_mapping.time_scale == pytest.approx(10.0)
    assert scenario.onboard.drive.preset == "lightweight"
    with pytest.raises(ValueError, match="speeds"):
        small_config(speeds=(1.0, 1.0))
    with pytest.raises(ValueError, match="plants"):
        small_config(plants=("feather",))


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
                   "--settle", "2", "--solver", "banded-ip", "--speeds", "2.5"])
    captured = capsys.readouterr()
    assert status == 0, captured.err
    assert "report:" in captured.out
    data = json.loads((out / "experiment.json").read_text())
    cell = data["cells"]["lab, 2.5×"]
    assert set(cell["main"]) == {"original", "kf", "offline-cks", "ruckig"}
    assert data["config"]["offline_solver"] == "banded-ip"
    assert {"C1", "C8"} <= set(data["claims"]["lab, 2.5×"])
    assert data["claims"]["lab, 2.5×"]["C8"]["verdict"] == "not tested"
    # The plant's modes about the start pose of the demonstration.
    assert 2.0 < cell["plant_modes"]["lowest_hz_min"] < 3.5
    sensitivity = cell["sensitivity"]
    assert set(sensitivity) == {"sigma0", "sigma_min", "rho", "kf_sigma0",
                                "kf-predictor_sigma0"}
    # Each axis includes the scenario's default point (the default run of its method).
    assert 1.0 in [row["value"] for row in sensitivity["sigma0"]]
    for form in ("kf", "kf-predictor"):
        assert [row["value"] for row in sensitivity[f"{form}_sigma0"]] == [
            0.01, 0.1, 1.0, 10.0, 100.0]
    assert 0.8 in [row["value"] for row in sensitivity["rho"]]
    assert 2.5e-4 in [round(row["value"], 12) for row in sensitivity["sigma_min"]]
    text = (out / "report.md").read_text()
    for name in ("limits.png", "tradeoff.png", "improvement.png", "sensitivity.png"):
        assert (out / name).stat().st_size > 0 and name in text
    assert math.isfinite(cell["main"]["ruckig"]["added_latency_s"]["mean"])
    assert "| C1 |" in text and "Vibration modes of the plant" in text

    status = main(["experiment", "--out", str(out), "--shapes", "Angle,Circle", "--workers",
                   "0"])
    assert status == 2
    assert "--shapes = 'Circle' is not one of the 30 LASA shapes" in capsys.readouterr().err


# --- the output folder: resuming, refusing a changed grid, shards and merging -----------------


def _fake_run_task(calls, stop_after=None):
    """A stand-in for the runner of a demonstration's tasks (``iter_task_group``), with the
    record layout of a real one, instant."""
    from telesmooth.studies import experiment

    def fake(task, base, config):
        if stop_after is not None and len(calls) >= stop_after:
            raise KeyboardInterrupt       # the run is stopped here
        calls.append(task.key)
        e_sum = 10.0 if task.method == "original" else 8.0 + task.demo
        return {**record(task.shape, task.demo, task.method, e_sum, 0.0),
                "index": task.index, "key": task.key, "label": task.label,
                "study": task.study, "seed": task.seed, "plant": task.plant,
                "speed": task.speed, "wall_s": 0.0}

    def fake_group(tasks, base, config):
        for task in tasks:
            yield fake(task, base, config)

    return experiment, fake_group


def _grid():
    return small_config(demos=(0, 1, 2), methods=("original", "kf", "bmfls"),
                        speeds=(1.0, 2.5))


def test_an_interrupted_run_resumes_where_it_stopped(base, tmp_path, monkeypatch):
    from telesmooth.scripts.experiment_report import write_experiment_report
    from telesmooth.studies.journal import read_records

    config, out = _grid(), tmp_path / "exp"
    tasks = make_tasks(config)
    calls = []
    module, fake = _fake_run_task(calls, stop_after=5)
    monkeypatch.setattr(module, "iter_task_group", fake)
    with pytest.raises(KeyboardInterrupt):
        write_experiment_report(out, base, config, workers=0, progress=lambda line: None)
    assert len(read_records(out)) == 5
    with (out / "records.jsonl").open("a") as handle:
        handle.write('{"key": "cut sh')            # a line the stop cut short
    calls.clear()
    module, fake = _fake_run_task(calls)
    monkeypatch.setattr(module, "iter_task_group", fake)
    lines = []
    write_experiment_report(out, base, config, workers=0, progress=lines.append)
    assert calls == [t.key for t in tasks[5:]]    # only what was not done
    assert "5 already done" in lines[0]
    data = json.loads((out / "experiment.json").read_text())
    assert [r["key"] for r in data["records"]] == [t.key for t in tasks]
    assert set(data["cells"]) == {"lab, 1×", "lab, 2.5×"}
    # A second rerun computes nothing and reports the same.
    calls.clear()
    write_experiment_report(out, base, config, workers=0, progress=lambda line: None)
    assert calls == []


def test_a_folder_of_another_grid_is_refused(base, tmp_path, monkeypatch, capsys):
    from telesmooth.scripts.experiment_report import write_experiment_report

    out = tmp_path / "exp"
    module, fake = _fake_run_task([])
    monkeypatch.setattr(module, "iter_task_group", fake)
    write_experiment_report(out, base, _grid(), workers=0, progress=lambda line: None)
    held = (out / "records.jsonl").read_bytes()
    with pytest.raises(ValueError, match=r"another experiment \(it differs in: speeds\)"):
        write_experiment_report(out, base, dataclasses.replace(_grid(), speeds=(1.0,)),
                                workers=0, progress=lambda line: None)
    other_base = LoadScenario(scenario_text="{smoother: {max_jerk_rad_per_s3: 0.2}}")
    with pytest.raises(ValueError, match="the base scenario"):
        write_experiment_report(out, other_base, _grid(), workers=0,
                                progress=lambda line: None)
    import telesmooth.studies.journal as journal

    with monkeypatch.context() as patch:
        patch.setattr(journal, "code_fingerprint", lambda: "another version")
        with pytest.raises(ValueError, match="the code"):
            write_experiment_report(out, base, _grid(), workers=0,
                                    progress=lambda line: None)
    assert (out / "records.jsonl").read_bytes() == held
    status = main(["experiment", "--out", str(out), "--shapes", "Angle", "--workers", "0",
                   "--sensitivity-shapes", "none", "--c8-shapes", "none"])
    assert status == 2 and "holds the records of another experiment" in capsys.readouterr().err


def test_shards_merge_into_the_report_of_the_whole_grid(base, tmp_path, monkeypatch):
    from telesmooth.scripts.experiment_report import (
        merge_experiment_reports,
        write_experiment_report,
    )
    from telesmooth.studies.journal import read_records

    config = _grid()
    module, fake = _fake_run_task([])
    monkeypatch.setattr(module, "iter_task_group", fake)
    quiet = {"progress": lambda line: None}
    write_experiment_report(tmp_path / "whole", base, config, workers=0, **quiet)
    for part in (1, 2):
        write_experiment_report(tmp_path / f"part{part}", base, config, workers=0,
                                shard=(part, 2), **quiet)
    parts = [read_records(tmp_path / f"part{part}") for part in (1, 2)]
    assert parts[0] and parts[1] and not set(parts[0]) & set(parts[1])
    # Each shard holds whole demonstrations (their tasks share the IK and the plant runs).
    demos = [{(r["speed"], r["shape"], r["demo"]) for r in part.values()} for part in parts]
    assert not demos[0] & demos[1]
    assert "Incomplete" in (tmp_path / "part1" / "report.md").read_text()
    merge_experiment_reports(tmp_path / "merged", [tmp_path / "part1", tmp_path / "part2"],
                             base, config, **quiet)

    def claims_and_records(folder):
        data = json.loads((folder / "experiment.json").read_text())
        return data["claims"], [{k: v for k, v in r.items() if k != "wall_s"}
                                for r in data["records"]]

    assert claims_and_records(tmp_path / "merged") == claims_and_records(tmp_path / "whole")
    assert "Incomplete" not in (tmp_path / "merged" / "report.md").read_text()
    # Two cells: P of every method in one figure, a panel per cell, shown in the report.
    assert (tmp_path / "merged" / "p_by_cell.png").stat().st_size > 10_000
    assert "(p_by_cell.png)" in (tmp_path / "merged" / "report.md").read_text()
    with pytest.raises(ValueError, match="another experiment"):
        merge_experiment_reports(tmp_path / "m2", [tmp_path / "part1"], base,
                                 dataclasses.replace(config, settle_s=3.0), **quiet)
    # The KF form only changes the verdicts: the whole grid is judged again with the other.
    merge_experiment_reports(tmp_path / "merged", [tmp_path / "part1", tmp_path / "part2"],
                             base, dataclasses.replace(config, kf_form="kf-predictor"), **quiet)
    claims, _ = claims_and_records(tmp_path / "merged")
    assert "kf-predictor" in claims["lab, 1×"]["C2"]["rule"]


def test_a_method_that_fails_on_one_demonstration_is_reported_not_fatal(base, monkeypatch,
                                                                         tmp_path):
    from telesmooth.scripts.experiment_report import write_experiment_report
    from telesmooth.studies import experiment

    real = experiment.run_method

    def fails_for_bmfls(setup, method, **kwargs):
        if method == "bmfls":
            raise RuntimeError("method 'bmfls' failed: forced")
        return real(setup, method, **kwargs)

    monkeypatch.setattr(experiment, "run_method", fails_for_bmfls)
    report = write_experiment_report(tmp_path / "exp", base, small_config(), workers=0,
                                     progress=lambda line: None)
    data = json.loads((tmp_path / "exp" / "experiment.json").read_text())
    cell = data["cells"]["lab, 2.5×"]
    assert set(cell["main"]) == {"original"}
    assert [row["error"] for row in cell["failed"]] == [
        "RuntimeError: method 'bmfls' failed: forced"]
    assert "1 run(s) failed" in report.read_text()


def test_without_the_originals_p_is_unknown_and_its_claims_not_tested():
    """A shard may hold methods without the original runs of their demonstrations: P is
    unknown there (no mean, no fraction), and C4/C5 are not tested rather than failing."""
    records = [record("A", 0, method, 8.0, 0.0) for method in
               ("kf", "offline-ks", "offline-cks", "bmfls", "online-cks")]
    summary = summarize(records)
    p = summary["main"]["kf"]["improvement_ratio_percent"]
    assert p["mean"] is None and p["fraction_positive"] is None and p["n_finite"] == 0
    claims = check_claims(summary)
    assert claims["C4"]["verdict"] == "not tested" == claims["C5"]["verdict"]
    assert claims["C3"]["verdict"] in ("holds", "does not hold", "partly")


def test_two_runs_on_one_folder_are_refused(base, tmp_path, monkeypatch):
    from telesmooth.scripts.experiment_report import write_experiment_report
    from telesmooth.studies.journal import FolderLock

    module, fake = _fake_run_task([])
    monkeypatch.setattr(module, "iter_task_group", fake)
    out = tmp_path / "exp"
    out.mkdir()
    with FolderLock(out):             # another run holds the folder
        with pytest.raises(ValueError, match="is being used by another experiment run"):
            write_experiment_report(out, base, _grid(), workers=0, progress=lambda line: None)
    assert not (out / "records.jsonl").exists()
    write_experiment_report(out, base, _grid(), workers=0, progress=lambda line: None)
    assert (out / "records.jsonl").exists()       # released: the next run goes ahead


def test_the_experiment_runs_the_plant_that_simulate_and_compare_run(base):
    """By default every run uses the scenario's plant (continuous), as ``simulate`` and
    ``compare`` do: a 5 ms step would triple e on Defaults. An explicit step is kept, and 0 is
    the continuous plant."""
    assert ExperimentConfig().plant_time_step_s is None
    default = experiment_scenario(base, small_config(), "Angle", 0)
    assert default.onboard.time_step_s == base.onboard.time_step_s == 0.0
    stepped = experiment_scenario(base, small_config(plant_time_step_s=0.005), "Angle", 0)
    assert stepped.onboard.time_step_s == 0.005
    assert experiment_scenario(base, small_config(plant_time_step_s=0.0), "Angle", 0) \
        .onboard.time_step_s == 0.0


# --- one unit of work per demonstration -------------------------------------------------------

# Limits that never bind: several methods then send the same packets to the bit.
LOOSE = ("{haptic: {lasa_mapping: {time_scale: 4.0, hold_start_s: 0.5, hold_end_s: 1.0}}, "
         "smoother: {max_acceleration_rad_per_s2: 100.0, max_jerk_rad_per_s3: 1000.0}}")


def test_tasks_are_grouped_by_demonstration():
    from telesmooth.studies.experiment import task_groups

    config = small_config(demos=(0, 1), sensitivity_shapes=("Angle",), c8_shapes=("Angle",),
                          speeds=(1.0, 2.5))
    tasks = make_tasks(config)
    groups = task_groups(tasks)
    assert sorted(t.index for group in groups for t in group) == [t.index for t in tasks]
    for group in groups:
        assert len({(t.kind, t.plant, t.speed, t.shape, t.demo, t.seed) for t in group}) == 1
        assert [t.index for t in group] == sorted(t.index for t in group)
        if group[0].kind == "c8":
            assert len(group) == 1
    # Per speed: demonstration 0 (main table + sensitivity study), demonstration 1, C8.
    assert len(groups) == 2 * 3
    demo0 = next(g for g in groups if (g[0].speed, g[0].demo, g[0].kind) == (1.0, 0, "run"))
    assert {t.study for t in demo0} == {"main", "reference", "sigma0", "sigma_min", "rho",
                                        "kf_sigma0", "kf-predictor_sigma0"}


def test_a_group_gives_each_task_the_record_it_gets_alone_and_reuses_equal_packets():
    from telesmooth.studies.experiment import run_task, run_task_group

    base = LoadScenario(scenario_text=LOOSE)
    config = small_config(methods=("original", "offline-ks", "offline-cks", "online-cks",
                                   "online-hard", "bmfls"))
    tasks = make_tasks(config)
    grouped = run_task_group(tasks, base, config)
    alone = [run_task(task, base, config) for task in tasks]
    assert strip_timing(grouped) == [{**r, "playback_reused": r2["playback_reused"]}
                                     for r, r2 in zip(strip_timing(alone), grouped)]
    assert not any(r["playback_reused"] for r in alone)
    reused = {r["label"] for r in grouped if r["playback_reused"]}
    # Offline-CKS is the Kalman smoother when no limit binds; BMFLS sends what one of the
    # online smoothers sends (bit for bit: the same arithmetic on the same samples, which this
    # scenario's loose limits never alter); Online-CKS with σ carried over is the fresh one on
    # a shape's first demonstration. Their figures are those of their own simulations (above).
    assert reused == {"offline-cks", "bmfls", "online-cks carried"}
    # These demonstrations stay far from self-contact: every plant run was certified so and
    # ran without collision geometry (the figures above are the same as alone, where it did
    # too; tests/test_self_contact.py compares such a run with the run with geometry).
    runs = [r for r in grouped if "metrics" in r]
    assert runs and all(r["contact_geometry"] is False
                        and r["self_clearance_m"] > CLEARANCE_M for r in runs)


def test_a_group_is_one_demonstration():
    from telesmooth.studies.experiment import run_task_group

    config = small_config(demos=(0, 1))
    tasks = make_tasks(config)
    with pytest.raises(ValueError, match="must be of one demonstration"):
        run_task_group(tasks, LoadScenario(scenario_text=FAST), config)


def test_the_report_says_how_many_plant_runs_were_reused(base, tmp_path, monkeypatch):
    from telesmooth.scripts.experiment_report import write_experiment_report

    calls = []
    module, fake_group = _fake_run_task(calls)

    def reusing(tasks, base, config):
        for record in fake_group(tasks, base, config):
            yield {**record, "playback_reused": record["method"] == "bmfls"}

    monkeypatch.setattr(module, "iter_task_group", reusing)
    config = _grid()
    report = write_experiment_report(tmp_path / "exp", base, config, workers=0,
                                     progress=lambda line: None)
    bmfls = sum(t.method == "bmfls" for t in make_tasks(config))
    assert f"; {bmfls} of them sent the same packets as another method" in report.read_text()
    data = json.loads((tmp_path / "exp" / "experiment.json").read_text())
    assert data["meta"]["reused"] == bmfls


def test_the_report_says_how_many_plant_runs_kept_their_collision_geometry(base, tmp_path,
                                                                          monkeypatch):
    from telesmooth.scripts.experiment_report import write_experiment_report

    calls = []
    module, fake_group = _fake_run_task(calls)

    def checked(tasks, base, config):
        for record in fake_group(tasks, base, config):
            yield {**record, "playback_reused": record["method"] == "bmfls",
                   "contact_geometry": record["method"] == "kf"}

    monkeypatch.setattr(module, "iter_task_group", checked)
    config = _grid()
    report = write_experiment_report(tmp_path / "exp", base, config, workers=0,
                                     progress=lambda line: None)
    count = {m: sum(t.method == m for t in make_tasks(config)) for m in ("original", "kf")}
    assert (f"of the plant runs, {count['original']} were certified free of self-contact "
            "(no two links that could touch came within 1 mm, with a margin for the motion "
            "between the 10 ms samples) and ran without the arm's collision geometry, "
            f"{count['kf']} ran with it)") in report.read_text()
    meta = json.loads((tmp_path / "exp" / "experiment.json").read_text())["meta"]
    assert (meta["certified"], meta["with_geometry"]) == (count["original"], count["kf"])


def test_the_report_counts_kept_runs_that_do_not_say_which_plant_they_had(base, tmp_path,
                                                                          monkeypatch):
    from telesmooth.scripts.experiment_report import write_experiment_report

    module, fake_group = _fake_run_task([])

    def older(tasks, base, config):   # "original" records from before the field existed
        for record in fake_group(tasks, base, config):
            if record["method"] != "original":
                record = {**record, "contact_geometry": False}
            yield record

    monkeypatch.setattr(module, "iter_task_group", older)
    config = _grid()
    report = write_experiment_report(tmp_path / "exp", base, config, workers=0,
                                     progress=lambda line: None)
    count = {m: sum(t.method == m for t in make_tasks(config)) for m in ("original", "kf")}
    assert (f"{2 * count['kf']} were certified free of self-contact" in report.read_text())
    assert f", 0 ran with it, {count['original']} kept from earlier runs do not say)" \
        in report.read_text()
