"""Bad input in YAML (scenarios, ``--scenario-text``, ``--link``): classes 3, 4 and 5.

The mechanism (``typed_yaml.load_yaml_text``): plain data only, checked on the composed node
tree before anything is built: every mapping key is a string (``{1: 2}``, ``{~: 2}`` are
errors naming the line), given once in its mapping (a duplicate is an error naming the key
path and both places, merge keys ``<<`` aside); and ``config_from_data`` gives a config's
message about its own field the key path (``haptic.period_s``), also for messages that start
with the config's class name.
"""

import pytest
from bad_input_helpers import assert_one_line_error, run, snapshot

from telesmooth.diagrams.scenario import LoadScenario
from telesmooth.typed_yaml import load_yaml_text


@pytest.mark.parametrize("text, words", [
    ("a: 1\na: 2\n", "'a' is given twice (lines 1 and 2)"),
    ("{a: {b: 1, b: 2}}", "'a.b' is given twice (line 1, columns 6 and 12)"),
    ("a: [{x: 1}, {x: 1, x: 2}]", "'a[1].x' is given twice"),
    ("{1: 2}", "line 1: the key '1' in the top level is an integer, not a name"),
    ("{~: 2}", "the key '~' in the top level is null"),
    ("{a: {true: 1}}", "the key 'true' in a is a boolean"),
    ("{a: {2020-01-01: 1}}", "the key '2020-01-01' in a is a date"),
    ("{[1, 2]: 3}", "the key '…' in the top level is a list"),
    ("[1, 2]", "must be a mapping at the top level; got list"),
    ("{a: !Foo {b: 1}}", "could not determine a constructor for the tag '!Foo'"),
])
def test_yaml_that_is_not_plain_named_data_is_refused(text, words):
    with pytest.raises(ValueError) as error:
        load_yaml_text(text, source="S")
    assert str(error.value).startswith("S") and words in str(error.value)


def test_anchors_aliases_and_merge_keys_still_work():
    data = load_yaml_text("_base: &base {x: 1, y: 2}\nA: {<<: *base, y: 3}\nB: [*base, *base]\n")
    assert data == {"A": {"x": 1, "y": 3}, "B": [{"x": 1, "y": 2}, {"x": 1, "y": 2}]}


@pytest.mark.parametrize("text, words", [
    ("{haptic: {period_s: -100}}", "haptic.period_s = -100.0 must be positive and finite"),
    ("{haptic: {lasa_shape: Sshap}}", "haptic.lasa_shape = 'Sshap' is not one of the 30 LASA "
                                      "shapes; did you mean 'Sshape'"),
    ("{haptic: {source: synthetic, period_s: -1}}", "haptic.period_s = -1.0"),
    ("{haptic: {lasa_demo: 9}}", "haptic.lasa_demo = 9 is out of range"),
    ("{haptic: {source: usb}}", "haptic.source = 'usb' is not one of the 5 haptic sources"),
    ("{haptic: {lasa_mapping: {haptic_rate_hz: -5}}}",
     "haptic.lasa_mapping.haptic_rate_hz = -5.0"),
    ("{fifo: {period_s: 0}, smoother: {period_s: 0}, uplink: {period_s: 0}}",
     "fifo.period_s = 0.0 must be positive"),
    ("{smoother: {lag: 2000}, fifo: {delay_s: 500}}", "smoother.lag = 2000 must be an integer "
                                                      "in 0..1000"),
    ("{haptic: {live_initial_pose: [0.7, .nan, 0]}}", "haptic.live_initial_pose = "),
])
def test_scenario_errors_name_the_key_path_the_user_wrote(text, words):
    with pytest.raises(ValueError) as error:
        LoadScenario(scenario_text=text)
    message = str(error.value)
    assert words in message
    assert "haptic_rate_hz = -100" not in message and " shape = 'Sshap'" not in message
    assert "DelayFifoConfig" not in message and "ReducedQSmootherConfig" not in message


CLI_CASES = {
    "duplicate key in a file": ("Defaults:\n  arm: space_arm\n  arm: air_bearing_arm\n",
                                ("--scenario = 's.yaml'", "'Defaults.arm' is given twice "
                                 "(lines 2 and 3)")),
    "duplicate scenario": ("Defaults: {}\nDefaults: {arm: space_arm}\n",
                           ("'Defaults' is given twice",)),
    "integer key in a file": ("1: {}\nDefaults: {}\n", ("the key '1' in the top level",)),
    "entry not a mapping": ("Defaults: 3\n", ("the entry 'Defaults' must be a mapping",)),
    "bad period in a file": ("Defaults: {haptic: {period_s: -100}}\n",
                             ("scenario 'Defaults': haptic.period_s = -100.0",)),
    "not UTF-8": (b"Defaults: {arm: \xff}\n", ("line 1: byte(s) b'\\xff' are not valid UTF-8",)),
}


@pytest.mark.parametrize("case", CLI_CASES)
def test_scenario_files_with_bad_yaml_are_one_line_and_untouched(tmp_path, monkeypatch, capsys,
                                                                case):
    monkeypatch.chdir(tmp_path)
    text, words = CLI_CASES[case]
    path = tmp_path / "s.yaml"
    path.write_bytes(text if isinstance(text, bytes) else text.encode())
    before = snapshot(tmp_path)
    status, stdout, stderr = run(capsys, "simulate", "--scenario", "s.yaml", "--out", "out")
    assert_one_line_error(status, stdout, stderr, "simulate", *words)
    assert snapshot(tmp_path) == before


def test_scenario_text_duplicate_key_names_the_option_and_the_path(capsys):
    status, stdout, stderr = run(capsys, "simulate", "--scenario-text",
                                 "{haptic: {lasa_demo: 1, lasa_demo: 2}}", "--out", "out")
    assert_one_line_error(status, stdout, stderr, "simulate",
                          "--scenario-text: 'haptic.lasa_demo' is given twice")


def test_link_option_duplicate_key_is_an_error(capsys):
    status, stdout, stderr = run(capsys, "link-relay", "--in-url", "memq://a", "--out-url",
                                 "memq://b", "--duration", "0.1",
                                 "--link", "{delay_s: 0.1, delay_s: 0.2}")
    assert_one_line_error(status, stdout, stderr, "link-relay",
                          "--link: 'delay_s' is given twice")
