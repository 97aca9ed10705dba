"""C4, C5 and C6 judged pair by pair (``studies.claims.paired_claims``) on hand-made records
whose verdicts are known: P set per method and demonstration (e against each demonstration's
original), deformations set per method.

Cell "lab 1×": Offline-CKS best by 5 points or more (C4 better); Offline-CKS beats Offline-KS
by 10 points but Online-CKS and BMFLS differ by 0.4 points, a tie (C5 not); Offline-CKS
deforms a third of Online-CKS (C6 better). Cell "lab 4×": Offline-CKS and Offline-KS tie
(0.3 points), Online-CKS beats BMFLS by 20 and Offline-CKS by 9.7 (C4 not, C5 not);
deformations equal within 0.1 µm (C6 tie). Over cells: C4 and C6 partly (lab 1×), C5 does not
hold.
"""

import numpy as np
import pytest

from telesmooth.studies.claims import paired_claims
from telesmooth.studies.experiment import cell_name

DEMOS = 12
P = {  # cell speed → method → P, %
    1.0: {"offline-cks": 30.0, "offline-ks": 20.0, "online-cks": 25.0, "bmfls": 24.6,
          "kf": 10.0},
    4.0: {"offline-cks": 30.3, "offline-ks": 30.0, "online-cks": 40.0, "bmfls": 20.0,
          "kf": 10.0},
}
DEFORMATION = {1.0: {"offline-cks": 1e-5, "online-cks": 3e-5},
               4.0: {"offline-cks": 2e-5, "online-cks": 2e-5 + 1e-7}}


def _record(speed, demo, label, e, deformation):
    return {"kind": "run", "study": "main", "shape": "Angle", "demo": demo, "method": label,
            "label": label, "plant": "lab", "speed": speed,
            "metrics": {"e_sum_m": e, "latency_s": 0.0,
                        "cartesian_deformation_mean_m": deformation}}


def _records():
    records = []
    for speed, methods in P.items():
        for demo in range(DEMOS):
            e_original = speed * (1.0 + 0.1 * demo)     # the originals differ by cell
            wobble = 0.05 * np.sin(1.7 * demo)             # well under every gap and margin
            records.append(_record(speed, demo, "original", e_original, 0.0))
            for label, p in methods.items():
                records.append(_record(
                    speed, demo, label, e_original * (1.0 - (p + wobble) / 100.0),
                    DEFORMATION[speed].get(label, 5e-5) * (1.0 + 0.001 * wobble)))
    return records


@pytest.fixture(scope="module")
def verdicts():
    return paired_claims(_records())


def test_each_pair(verdicts):
    lab1, lab4 = cell_name("lab", 1.0), cell_name("lab", 4.0)

    def pairs(claim, cell):
        return {(p["a"], p["b"]): p["verdict"] for p in verdicts[claim]["cells"][cell]["pairs"]}

    assert pairs("C4", lab1) == {("offline-cks", "offline-ks"): "better",
                                 ("offline-cks", "kf"): "better",
                                 ("offline-cks", "bmfls"): "better",
                                 ("offline-cks", "online-cks"): "better"}
    assert pairs("C4", lab4)[("offline-cks", "offline-ks")] == "tie"
    assert pairs("C4", lab4)[("offline-cks", "online-cks")] == "worse"
    assert pairs("C5", lab1) == {("offline-cks", "offline-ks"): "better",
                                 ("online-cks", "bmfls"): "tie"}
    assert pairs("C5", lab4) == {("offline-cks", "offline-ks"): "tie",
                                 ("online-cks", "bmfls"): "better"}
    assert pairs("C6", lab1) == {("offline-cks", "online-cks"): "better"}
    assert pairs("C6", lab4) == {("offline-cks", "online-cks"): "tie"}
    c5 = verdicts["C5"]["cells"][lab1]["pairs"][0]
    assert c5["n"] == DEMOS and c5["median_difference"] == pytest.approx(10.0, abs=0.2)


def test_over_cells(verdicts):
    lab1 = cell_name("lab", 1.0)
    assert verdicts["C4"]["verdict"] == f"partly ({lab1})"
    assert verdicts["C5"]["verdict"] == "does not hold"
    assert verdicts["C6"]["verdict"] == f"partly ({lab1})"


def test_the_report_section(verdicts):
    from telesmooth.scripts.experiment_report import paired_claims_markdown

    text = paired_claims_markdown(verdicts)
    lab1, lab4 = cell_name("lab", 1.0), cell_name("lab", 4.0)
    lines = text.splitlines()
    assert lines[0] == f"| claim | {lab1} | {lab4} | over cells |"
    assert "| C5 | not | not | does not hold |" in lines
    assert f"| C4 | better | not | partly ({lab1}) |" in lines
    row = next(line for line in lines if line.startswith(f"| C5 | {lab1} | online-cks"))
    assert row.endswith("| tie |") and "| P | 12 |" in row
    row = next(line for line in lines if line.startswith(f"| C6 | {lab1} |"))
    assert "-0.02 [" in row and "mm" in row and row.endswith("| better |")


def test_the_kf_form_robustness_table():
    from telesmooth.scripts.experiment_report import kf_robustness_markdown

    cell = cell_name("lab", 1.0)
    by_form = {"kf": {cell: {"C1": {"verdict": "holds"}, "C2": {"verdict": "partly"}}},
               "kf-predictor": {cell: {"C1": {"verdict": "holds"}, "C2": {"verdict": "holds"}}}}
    lines = kf_robustness_markdown(by_form).splitlines()
    assert lines == [f"| claim | {cell} |", "|---|---|", "| C1 | holds |",
                     "| C2 | depends on kf → partly, kf-predictor → holds |"]
