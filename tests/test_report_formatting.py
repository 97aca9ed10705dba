"""What reports print: a ratio over its limit is never rounded down to 1.00; the operator and
the plant are named."""

import pytest

from telesmooth.diagrams.scenario import describe_operator, load_scenario
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
    assert describe_operator(load_scenario(scenario_text=text)) == expected
