"""What a reader sees in the compare and experiment reports: tables of a width one can take in,
the claims' figures as tables and sentences (no raw JSON), E_def on a logarithmic axis.

Every check runs on small hand-made inputs whose cells are worked out here."""

from __future__ import annotations

import math

import numpy as np
import pytest

from telesmooth.scripts.compare_report import (
    TABLES,
    comparison_table,
    summary_figure,
    table_markdown,
)
from telesmooth.scripts.experiment_report import claim_figures_markdown
from telesmooth.studies.claims import check_claims, summarize


def _row(method, **figures):
    row = dict(method=method, delay_s=0.0, fd_acc_max_over_limit=1.0, fd_acc_fraction_over=0.0,
               fd_jerk_max_over_limit=1.0, fd_jerk_fraction_over=0.0,
               position_deformation_mean_rad=0.0, cartesian_deformation_mean_m=0.0,
               cartesian_deformation_max_m=0.0, e_mean_m=1e-4, e_max_m=2e-4,
               improvement_ratio_percent=0.0, operator_error_mean_m=1e-4,
               residual_motion_m=0.0, settling_time_s=0.0, settled=1.0, added_latency_s=0.0,
               presim_violations=0, latency_s=0.3)
    row.update(figures)
    return row


ROWS = [_row("original", fd_acc_max_over_limit=3.5, fd_acc_fraction_over=0.125),
        _row("offline-hard", cartesian_deformation_mean_m=2e-3,
             cartesian_deformation_max_m=5e-3, e_mean_m=5e-5),
        _row("online-cks", delay_s=0.75, added_latency_s=0.76,
             cartesian_deformation_mean_m=1e-3, cartesian_deformation_max_m=4e-3,
             improvement_ratio_percent=12.5, settled=0.0, settling_time_s=math.nan)]


def _table(text):
    lines = text.splitlines()
    header = [c.strip() for c in lines[0].strip("|").split("|")]
    return {line.split("|")[1].strip(): dict(zip(header, (c.strip() for c in
                                                          line.strip("|").split("|")),
                                                 strict=True))
            for line in lines[2:]}


def test_the_comparison_is_three_tables_of_readable_width_with_every_figure():
    expected = {
        "limits": ["method", "FD acc max/limit", "FD acc over", "FD jerk max/limit",
                   "FD jerk over", "pre-sim violations"],
        "accuracy": ["method", "joint def. mean [mrad]", "E_def mean / max [mm]",
                     "E_def / offline-hard", "e mean / max [mm]", "P [%]",
                     "vs operator mean [mm]"],
        "timing": ["method", "delay [s]", "added latency [s]", "residual motion [mm]",
                   "settling [s]"]}
    assert [name for name, _, _ in TABLES] == list(expected)
    tables = {}
    for name, columns in expected.items():
        text = comparison_table(ROWS, name)
        assert [c.strip() for c in text.splitlines()[0].strip("|").split("|")] == columns
        assert len(columns) <= 7
        tables[name] = _table(text)
        assert list(tables[name]) == ["original", "offline-hard", "online-cks"]
    # The fifteen figures of the one wide table, each in one of the three.
    assert sum(len(columns) - 1 for columns in expected.values()) == 15
    limits, accuracy, timing = tables["limits"], tables["accuracy"], tables["timing"]
    assert limits["original"]["FD acc max/limit"] == "3.50!"
    assert limits["original"]["FD acc over"] == "12.5%"
    # E_def over offline-hard's: 1 mm / 2 mm.
    assert accuracy["online-cks"]["E_def / offline-hard"] == "0.50"
    assert accuracy["online-cks"]["E_def mean / max [mm]"] == "1.00 / 4.00"
    assert accuracy["offline-hard"]["e mean / max [mm]"] == "0.050 / 0.200"
    assert timing["online-cks"]["delay [s]"] == "0.75"
    assert timing["online-cks"]["added latency [s]"] == "0.76"
    assert timing["online-cks"]["settling [s]"] == "not settled in the run"
    without = comparison_table([r for r in ROWS if r["method"] != "offline-hard"], "accuracy")
    assert _table(without)["online-cks"]["E_def / offline-hard"] == \
        "n/a (offline-hard not run)"
    text = table_markdown(ROWS)
    assert [line for line in text.splitlines() if line.startswith("**")] == [
        f"**{title}**" for _, title, _ in TABLES]


def test_e_def_is_drawn_on_a_logarithmic_axis_where_small_values_show():
    """E_def of 0, 0.01, 1 and 30 mm: a logarithmic axis, each positive bar reaching its
    value from below the smallest, the exact 0 written out; e (0.05–0.1 mm) stays linear
    until it spans more than ten times."""
    rows = [_row(name, cartesian_deformation_mean_m=value)
            for name, value in (("original", 0.0), ("kf", 1e-5), ("offline-hard", 1e-3),
                                ("ruckig", 3e-2))]
    fig = summary_figure(rows)
    try:
        e_def, e = fig.axes[0], fig.axes[1]
        assert e_def.get_xscale() == "log" and "log" in e_def.get_title()
        left, right = e_def.get_xlim()
        assert left < 0.01 and right > 30.0
        ends = sorted(patch.get_x() + patch.get_width() for patch in e_def.patches
                      if patch.get_width() > 0)
        np.testing.assert_allclose(ends, [0.01, 1.0, 30.0], rtol=1e-12)
        labels = [text.get_text() for text in e_def.texts]
        assert labels == ["0", "0.01", "1", "30"]
        assert e.get_xscale() == "linear"
    finally:
        import matplotlib.pyplot as plt

        plt.close(fig)
    rows[0]["e_mean_m"] = 5e-3            # e_ORG behind the guard: 5 mm against 0.1 mm
    fig = summary_figure(rows, deployed=True)
    try:
        assert fig.axes[1].get_xscale() == "log"
    finally:
        plt.close(fig)


def _record(shape, demo, method, e_sum, **metrics):
    figures = dict(fd_acc_max_over_limit=1.0, fd_jerk_max_over_limit=1.0,
                   fd_acc_fraction_over=0.0, fd_jerk_fraction_over=0.0,
                   cartesian_deformation_mean_m=0.0, position_deformation_mean_rad=0.0,
                   velocity_deformation_mean_rad_per_s=0.0, e_mean_m=e_sum / 10,
                   operator_error_mean_m=0.0, residual_motion_m=0.0, settling_time_s=0.0)
    figures.update(metrics, e_sum_m=e_sum, latency_s=0.0)
    return {"kind": "run", "shape": shape, "demo": demo, "method": method, "label": method,
            "study": "main", "value": None, "metrics": figures}


@pytest.fixture(scope="module")
def claims():
    """Ten demonstrations (the worst-ratio percentiles of
    tests/test_experiment.py::test_c1_is_judged_on_the_90th_percentile...): Online-CKS's
    median 1.2 and 90th percentile 1.65; P of the Kalman filter 20 %, of Offline-CKS 50 %."""
    records = []
    for demo in range(10):
        records.append(_record("S", demo, "original", 10.0))
        records.append(_record("S", demo, "offline-cks", 5.0, fd_acc_max_over_limit=1.0,
                               fd_jerk_max_over_limit=0.5, cartesian_deformation_mean_m=2e-3,
                               position_deformation_mean_rad=2e-3))
        ratio = [1.2] * 8 + [1.5, 3.0]
        records.append(_record("S", demo, "online-cks", 6.0, fd_acc_max_over_limit=ratio[demo],
                               fd_jerk_max_over_limit=0.5, cartesian_deformation_mean_m=1e-3,
                               position_deformation_mean_rad=1e-3))
        records.append(_record("S", demo, "kf", 8.0, fd_acc_max_over_limit=4.0,
                               cartesian_deformation_mean_m=3e-3,
                               position_deformation_mean_rad=3e-3))
        records.append(_record("S", demo, "bmfls", 7.0, fd_acc_max_over_limit=2.0,
                               cartesian_deformation_mean_m=5e-4,
                               position_deformation_mean_rad=5e-4))
    return check_claims(summarize(records))


def test_a_claims_figures_read_as_tables_and_sentences(claims):
    for name, claim in claims.items():
        text = claim_figures_markdown(name, claim["figures"])
        assert "```" not in text and "{" not in text and '"' not in text, (name, text)
    c1 = claim_figures_markdown("C1", claims["C1"]["figures"])
    table = _table("\n".join(line for line in c1.splitlines() if line.startswith("|")))
    assert list(table["online-cks"]) == ["method", "median", "90th percentile", "largest",
                                         "share of the samples over a limit"]
    assert table["online-cks"]["median"] == "1.20!"
    assert table["online-cks"]["90th percentile"] == "1.65!"
    assert table["online-cks"]["largest"] == "3.00!"
    assert table["offline-cks"]["90th percentile"] == "1.00"
    assert "`offline-cks` yes, `online-cks` no" in c1
    c4 = claim_figures_markdown("C4", claims["C4"]["figures"])
    table = _table("\n".join(line for line in c4.splitlines() if line.startswith("|")))
    assert table["kf"]["mean P [%]"] == "20.0"          # (10 − 8) / 10
    assert table["offline-cks"]["mean P [%]"] == "50.0"
    assert table["offline-cks"]["demonstrations with P > 0"] == "100 %"
    assert "Largest mean P: `offline-cks`." in c4
    c3 = claim_figures_markdown("C3", claims["C3"]["figures"])
    table = _table("\n".join(line for line in c3.splitlines() if line.startswith("|")))
    assert table["kf"]["E_def [mm]"] == "3" and table["bmfls"]["E_def [mm]"] == "0.5"
    c7 = claim_figures_markdown("C7", claims["C7"]["figures"])
    assert c7.splitlines()[2] == "| method | mean rank |"


def test_figures_of_another_shape_are_a_table_not_json():
    figures = {"weights": {"a": 0.5, "b": [1, 2]}, "flag": True, "note": None}
    text = claim_figures_markdown("C9", figures)
    assert text.splitlines()[:2] == ["| figure | value |", "|---|---|"]
    assert "| weights / a | 0.5 |" in text and "| weights / b | 1, 2 |" in text
    assert "| flag | yes |" in text and "| note | n/a |" in text
    # A known claim whose figures changed shape falls back to the same table.
    assert claim_figures_markdown("C8", {"shapes": 3}).startswith("| figure | value |")
    assert claim_figures_markdown("C1", {}) == ""


def test_the_experiment_report_has_no_raw_json_and_names_its_chain(tmp_path, monkeypatch):
    """A whole report from instant stand-in records (every claim judged): no code block, no
    JSON object, the chain in its first lines."""
    import dataclasses

    from telesmooth.diagrams.scenario import LoadScenario
    from telesmooth.scripts.experiment_report import write_experiment_report
    from telesmooth.studies import experiment
    from telesmooth.studies.experiment import ExperimentConfig

    methods = ("original", "kf", "kf-predictor", "offline-ks", "offline-cks", "bmfls",
               "online-cks")

    def fake_group(tasks, base, config):
        for task in tasks:
            base_record = {"index": task.index, "key": task.key, "kind": task.kind,
                           "shape": task.shape, "demo": task.demo, "method": task.method,
                           "label": task.label, "study": task.study, "value": None,
                           "seed": task.seed, "plant": task.plant, "speed": task.speed,
                           "chain": config.chain, "wall_s": 0.0}
            if task.kind == "c8":
                step = {"fd_jerk_max_over_limit": 1.0, "sigma_monotone": True}
                yield {**base_record, "c8": {"demos": [{"demo": d, "fresh": step,
                                                        "carried": step} for d in range(7)]}}
                continue
            rank = methods.index(task.method)
            yield {**base_record, **_record(task.shape, task.demo, task.method,
                                            10.0 - 0.5 * rank,
                                            fd_acc_max_over_limit=1.0 + 0.2 * rank,
                                            cartesian_deformation_mean_m=1e-3 * rank)}

    monkeypatch.setattr(experiment, "iter_task_group", fake_group)
    base = LoadScenario()
    config = ExperimentConfig(shapes=("Angle", "CShape"), methods=methods,
                              sensitivity_shapes=(), c8_shapes=("Angle",))
    for chain in ("paper", "deployed"):
        out = tmp_path / chain
        write_experiment_report(out, base, dataclasses.replace(config, chain=chain),
                                workers=0, progress=lambda line: None)
        text = (out / "report.md").read_text()
        lines = text.splitlines()
        assert lines[2].startswith({"paper": "Chain: the paper's chain",
                                    "deployed": "Chain: the deployed chain"}[chain])
        assert "```" not in text
        assert not any(line.lstrip().startswith(("{", "[", '"')) for line in lines)
        assert '": ' not in text and "['" not in text
        for name in ("C1", "C2", "C3", "C4", "C5", "C6", "C7", "C8"):
            assert f"#### {name}: " in text
