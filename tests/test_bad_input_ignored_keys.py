"""Bad input: a scenario key that the scenario's own settings leave unread is an error.

Guards against ``haptic: {file: my.csv}`` without ``source: file`` running the built-in LASA
demonstration and exiting 0. ``diagrams.scenario.check_ignored_keys`` refuses every key of its
table (``_KEYS_READ_ONLY_WHEN``) that the deciding setting leaves unread, naming the key path,
its value, and the setting with its value; keys are taken as the user wrote them (the merged
YAML), the setting from the built scenario (default filled in).
"""

import pytest
from bad_input_helpers import assert_one_line_error, run, snapshot

from telesmooth.diagrams.scenario import (
    _KEYS_READ_ONLY_WHEN,
    HAPTIC_KEY_SOURCES,
    HAPTIC_SOURCES,
    LoadScenario,
)
from telesmooth.typed_yaml import load_yaml_text

# Each rule: (the scenario text that errors, the words its message must hold, a text that
# gives the same key under a setting that reads it, which must load).
RULES = {
    "haptic.file without source": (
        "{haptic: {file: my.csv}}",
        ("haptic.file = 'my.csv' is only read when haptic.source = 'file'",
         "(haptic.source is 'lasa', the default)"),
        "{haptic: {source: file, file: my.csv}}"),
    "haptic.file under synthetic": (
        "{haptic: {source: synthetic, file: my.csv}}",
        ("haptic.file = 'my.csv'", "(haptic.source is 'synthetic')"),
        "{haptic: {source: file, file: my.csv}}"),
    "haptic.lasa_shape under file": (
        "{haptic: {source: file, file: my.csv, lasa_shape: Sshape}}",
        ("haptic.lasa_shape = 'Sshape' is only read when haptic.source = 'lasa'",
         "(haptic.source is 'file')"),
        "{haptic: {lasa_shape: Sshape}}"),
    "haptic.lasa_demo under synthetic": (
        "{haptic: {source: synthetic, lasa_demo: 3}}",
        ("haptic.lasa_demo = 3 is only read when haptic.source = 'lasa'",),
        "{haptic: {source: lasa, lasa_demo: 3}}"),
    "haptic.lasa_mapping under lcm": (
        "{haptic: {source: lcm, lasa_mapping: {time_scale: 5.0}}}",
        ("haptic.lasa_mapping = {'time_scale': 5.0}", "(haptic.source is 'lcm')"),
        "{haptic: {lasa_mapping: {time_scale: 5.0}}}"),
    "haptic.synthetic under lasa": (
        "{haptic: {synthetic: {seed: 4}}}",
        ("haptic.synthetic = {'seed': 4} is only read when haptic.source = 'synthetic'",),
        "{haptic: {source: synthetic, synthetic: {seed: 4}}}"),
    "haptic.live_initial_pose under lasa": (
        "{haptic: {live_initial_pose: [0.6, 0.1, 0.0]}}",
        ("haptic.live_initial_pose = [0.6, 0.1, 0.0] is only read when haptic.source = "
         "'lcm'",),
        "{haptic: {source: lcm, live_initial_pose: [0.6, 0.1, 0.0]}}"),
    "haptic.live_duration_s under file": (
        "{haptic: {source: file, file: my.csv, live_duration_s: 20}}",
        ("haptic.live_duration_s = 20 is only read when haptic.source = 'lcm'",),
        "{haptic: {source: lcm, live_duration_s: 20}}"),
    "lasa_mapping.haptic_rate_hz": (
        "{haptic: {lasa_mapping: {haptic_rate_hz: 50.0}}}",
        ("haptic.lasa_mapping.haptic_rate_hz = 50.0 is not read in a scenario",
         "1 / haptic.period_s"),
        "{haptic: {period_s: 0.02}}"),
    "synthetic.haptic_rate_hz": (
        "{haptic: {source: synthetic, synthetic: {haptic_rate_hz: 50.0}}}",
        ("haptic.synthetic.haptic_rate_hz = 50.0 is not read in a scenario",),
        "{haptic: {source: synthetic, period_s: 0.02}}"),
    "inverse_kinematics.max_iterations on the planar arm": (
        "{inverse_kinematics: {max_iterations: 4}}",
        ("inverse_kinematics.max_iterations = 4 is only read when arm = 'space_arm'",
         "(arm is 'air_bearing_arm', the default)"),
        "{arm: space_arm, inverse_kinematics: {max_iterations: 4}}"),
    "fifo.max_stop_duration_s with on_collision hold": (
        "{fifo: {on_collision: hold, max_stop_duration_s: 5.0}}",
        ("fifo.max_stop_duration_s = 5.0 is only read when fifo.on_collision = 'stop'",
         "(fifo.on_collision is 'hold')"),
        "{fifo: {on_collision: stop, max_stop_duration_s: 5.0}}"),
    "reduced_q.rho with the additive step": (
        "{smoother: {reduced_q: {step_rule: additive, rho: 0.5}}}",
        ("smoother.reduced_q.rho = 0.5 is only read when smoother.reduced_q.step_rule = "
         "'multiplicative'", "(smoother.reduced_q.step_rule is 'additive')"),
        "{smoother: {reduced_q: {rho: 0.5}}}"),
    "reduced_q.delta_sigma with the multiplicative step": (
        "{smoother: {reduced_q: {delta_sigma: 1.0e-5}}}",
        ("smoother.reduced_q.delta_sigma = 1e-05 is only read when "
         "smoother.reduced_q.step_rule = 'additive'", "is 'multiplicative', the default)"),
        "{smoother: {reduced_q: {step_rule: additive, delta_sigma: 1.0e-5}}}"),
    "reduced_q.max_retries with variant A": (
        "{smoother: {reduced_q: {max_retries: 3}}}",
        ("smoother.reduced_q.max_retries = 3 is only read when smoother.reduced_q.variant = "
         "'B1' or 'B2'", "(smoother.reduced_q.variant is 'A', the default)"),
        "{smoother: {reduced_q: {variant: B1, max_retries: 3}}}"),
    "onboard.arm": (
        "{onboard: {arm: space_arm}}",
        ("onboard.arm = 'space_arm' is not read in a scenario: the top-level arm sets it",),
        "{arm: space_arm}"),
    "onboard.initial_position_rad": (
        "{onboard: {initial_position_rad: [0.0, 0.5, 0.5]}}",
        ("onboard.initial_position_rad = [0.0, 0.5, 0.5] is not read in a scenario",),
        "{initial_position_rad: [0.0, 0.5, 0.5]}"),
    "onboard.integration_accuracy on a discrete plant": (
        "{onboard: {time_step_s: 0.005, integration_accuracy: 1.0e-4}}",
        ("onboard.integration_accuracy = 0.0001 is only read when onboard.time_step_s = 0",
         "(onboard.time_step_s is 0.005)"),
        "{onboard: {integration_accuracy: 1.0e-4}}"),
    "onboard.integration_scheme on a discrete plant": (
        "{onboard: {time_step_s: 0.001, integration_scheme: runge_kutta3}}",
        ("onboard.integration_scheme = 'runge_kutta3' is only read when "
         "onboard.time_step_s = 0",),
        "{onboard: {time_step_s: 0, integration_scheme: runge_kutta3}}"),
    "onboard.discrete_contact_approximation on the continuous plant": (
        "{onboard: {time_step_s: 0, discrete_contact_approximation: sap}}",
        ("onboard.discrete_contact_approximation = 'sap' is only read when "
         "onboard.time_step_s > 0", "(onboard.time_step_s is 0.0)"),
        "{onboard: {time_step_s: 0.005, discrete_contact_approximation: sap}}"),
    "onboard.interpolator.ramp_duration_s with zoh": (
        "{onboard: {interpolator: {interpolation: zoh, ramp_duration_s: 0.1}}}",
        ("onboard.interpolator.ramp_duration_s = 0.1 is only read when "
         "onboard.interpolator.interpolation = 'linear'",
         "(onboard.interpolator.interpolation is 'zoh')"),
        "{onboard: {interpolator: {ramp_duration_s: 0.1}}}"),
    "onboard.tracker.seed without noise": (
        "{onboard: {tracker: {seed: 7}}}",
        ("onboard.tracker.seed = 7 is only read when onboard.tracker.noise_m > 0",
         "(onboard.tracker.noise_m is 0.0, the default)"),
        "{onboard: {tracker: {noise_m: 1.0e-4, seed: 7}}}"),
}


@pytest.mark.parametrize("rule", RULES)
def test_an_unread_key_is_an_error_naming_it_and_the_setting(rule):
    text, words, _ = RULES[rule]
    with pytest.raises(ValueError) as error:
        LoadScenario(scenario_text=text)
    message = str(error.value)
    assert message.startswith("scenario 'Defaults' with scenario_text: "), message
    for word in words:
        assert word in message, (word, message)


@pytest.mark.parametrize("rule", RULES)
def test_the_same_key_under_a_setting_that_reads_it_loads(rule):
    _, _, text = RULES[rule]
    LoadScenario(scenario_text=text)


def test_every_rule_of_the_table_is_tested_both_ways():
    tested = {load_path for text, _, _ in RULES.values()
              for load_path in _paths(load_yaml_text(text))}
    for key, _, _ in _KEYS_READ_ONLY_WHEN:
        assert key in tested, key


def _paths(data, prefix=""):
    for key, value in data.items():
        path = f"{prefix}{key}"
        yield path
        if isinstance(value, dict):
            yield from _paths(value, path + ".")


def test_the_source_table_names_only_known_sources_and_haptic_keys():
    from telesmooth.diagrams.scenario import HapticScenario

    fields = {field for field in HapticScenario.__dataclass_fields__}
    for key, sources in HAPTIC_KEY_SOURCES.items():
        assert key in fields, key
        assert sources and set(sources) <= set(HAPTIC_SOURCES), (key, sources)


def test_the_built_in_scenarios_still_load():
    for name in ("Defaults", "OneOfEverything"):
        LoadScenario(scenario_name=name)


def test_a_key_merged_from_the_file_entry_is_checked_with_the_text_s_setting(tmp_path):
    path = tmp_path / "s.yaml"
    path.write_text("Base: {haptic: {lasa_shape: Sshape}}\n")
    LoadScenario(filename=path, scenario_name="Base")
    with pytest.raises(ValueError, match=r"scenario 'Base' with scenario_text: "
                       r"haptic.lasa_shape = 'Sshape' is only read when haptic.source = "
                       r"'lasa' \(haptic.source is 'synthetic'\)"):
        LoadScenario(filename=path, scenario_name="Base",
                      scenario_text="{haptic: {source: synthetic}}")


def test_a_null_key_counts_as_not_given():
    LoadScenario(scenario_text="{haptic: {file: null}, smoother: {reduced_q: "
                                "{delta_sigma: null}}}")


def test_an_invalid_deciding_value_is_reported_as_such_not_as_an_unread_key():
    with pytest.raises(ValueError) as error:
        LoadScenario(scenario_text="{haptic: {source: fil, file: my.csv}}")
    assert "haptic.source = 'fil' is not one of the 5 haptic sources" in str(error.value)
    assert "only read" not in str(error.value)


@pytest.mark.parametrize("text", [
    "{fifo: {max_stop_duration_s: 5.0}}",
    "{onboard: {discrete_contact_approximation: sap}}",
])
def test_a_setting_the_command_line_may_still_set_decides_only_where_written(text):
    # --on-collision stop (every scenario command) and experiment --plant-step are applied
    # after the scenario is loaded: a key for them is not refused on the default.
    LoadScenario(scenario_text=text)


def test_on_collision_stop_on_the_command_line_with_a_stop_key_runs(tmp_path, capsys):
    status, _, stderr = run(capsys, "simulate", "--duration", "1.1", "--on-collision", "stop",
                            "--scenario-text", "{fifo: {max_stop_duration_s: 5.0}}",
                            "--out", tmp_path / "out")
    assert status == 0, stderr


@pytest.mark.parametrize("command", ["simulate", "compare", "foresight", "experiment"])
def test_the_cli_gives_one_line_naming_the_key_and_the_source(tmp_path, monkeypatch, capsys,
                                                             command):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "my.csv").write_text("t,x_m,y_m,phi_rad\n0,0.7,0,0\n0.01,0.7,0,0\n")
    before = snapshot(tmp_path)
    status, stdout, stderr = run(capsys, command, "--scenario-text", "{haptic: {file: my.csv}}",
                                 "--out", "out")
    assert_one_line_error(status, stdout, stderr, command, "--scenario-text",
                          "haptic.file = 'my.csv' is only read when haptic.source = 'file'",
                          "(haptic.source is 'lasa', the default)")
    assert snapshot(tmp_path) == before


def test_the_cli_names_a_key_from_a_scenario_file(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "s.yaml").write_text("Mine:\n  onboard:\n    time_step_s: 0.005\n"
                                     "    integration_accuracy: 1.0e-4\n")
    before = snapshot(tmp_path)
    status, stdout, stderr = run(capsys, "simulate", "--scenario", "s.yaml", "--scenario-name",
                                 "Mine", "--out", "out")
    assert_one_line_error(status, stdout, stderr, "simulate", "scenario 'Mine': ",
                          "onboard.integration_accuracy = 0.0001 is only read when "
                          "onboard.time_step_s = 0", "(onboard.time_step_s is 0.005)")
    assert snapshot(tmp_path) == before


def test_the_docs_list_every_key_of_the_table():
    from pathlib import Path

    text = (Path(__file__).resolve().parent.parent / "docs" / "commands.md").read_text()
    start = text.index("\n## Scenarios")
    section = text[start:text.index("\n## ", start + 1)]
    for key, _, _ in _KEYS_READ_ONLY_WHEN:
        assert f"`{key}`" in section, key
