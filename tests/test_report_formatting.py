"""What reports print: a ratio over its limit is never rounded down to 1.00; the operator and
the plant are named."""

import pytest

from telesmooth.diagrams.scenario import LoadScenario, describe_operator
from telesmooth.scripts.formatting import limit_ratio


@pytest.mark.parametrize("value, text", [
    (0.5, "0.50"), (1.0, "1.00"),
    (1.0000005, "1.00"),          # within the round-off tolerance (1e-6): not a violation
    (1.0021, "1.0021!"), (1.004, "1.0040!"), (1.000020, "1.000020!"),
    (2.456, "2.46!"), (142.0, "142.00!"), (None, "n/a"), (float("nan"), "n/a"),
])
def test_a_violation_is_flagged_and_visibly_above_one(value, text):
    assert limit_ratio(value) == text


def test_every_violation_reads_above_one():
    for excess in (2e-6, 1e-5, 3e-4, 4.9e-3, 5e-3):
        text = limit_ratio(1.0 + excess)
        assert text.endswith("!") and float(text[:-1]) > 1.0, text


@pytest.mark.parametrize("text, expected", [
    ("{}", "the LASA demonstration `Angle` #0 at 1× the demonstrator's hand speed "
           "(time_scale 10)"),
    ("{haptic: {lasa_shape: Sshape, lasa_demo: 3, lasa_mapping: {time_scale: 4}}}",
     "the LASA demonstration `Sshape` #3 at 2.5× the demonstrator's hand speed "
     "(time_scale 4)"),
    ("{haptic: {source: synthetic}}", "the synthetic operator (seed 0)"),
    ("{haptic: {source: lcm}}", "a live haptic device over LCM"),
])
def test_the_operator_is_named(text, expected):
    assert describe_operator(LoadScenario(scenario_text=text)) == expected


def test_a_run_still_moving_at_its_end_is_not_given_a_settling_time():
    from telesmooth.scripts.compare_report import _cell as compare_cell
    from telesmooth.scripts.formatting import mean_worst_cell as experiment_cell

    assert compare_cell({"settling_time_s": float("nan"), "settled": 0.0}, "settling_time_s",
                        "settling") == "not settled in the run"
    assert compare_cell({"settling_time_s": 1.234, "settled": 1.0}, "settling_time_s",
                        "settling") == "1.23"
    stats = {"mean": 1.25, "worst": 2.0, "n": 4}
    figures = {"settled": {"mean": 0.5, "n": 4}}
    assert experiment_cell(stats, 1.0, "settling", figures) == "1.2 (2.0); 2 not settled"
    assert experiment_cell(stats, 1.0, "settling", {"settled": {"mean": 1.0, "n": 4}}) == \
        "1.2 (2.0)"
    # A figure the records lack (e.g. a reading older records did not measure); no value.
    assert experiment_cell(None, 1.0, "{:.1f}") == "—"
    assert experiment_cell({"mean": None, "worst": None}, 1.0, "{:.1f}") == "n/a"


def test_the_pre_simulators_distance_at_its_horizon_is_a_lower_bound():
    from telesmooth.scripts.simulate_report import _distance_text

    assert _distance_text(0.0421, 0.2) == "42.1 mm"
    assert _distance_text(0.2, 0.2).startswith("at least 200.0 mm (nothing came within")
    assert "distance_horizon_m" in _distance_text(0.2, 0.2)
