"""One registry of method names (telesmooth.smoothing.methods): every command and the scenario's
smoother take the same names, and an alias (``pass-through`` for ``original``) everywhere."""

import dataclasses

import numpy as np
import pytest

from telesmooth.diagrams.scenario import LoadScenario
from telesmooth.scripts.cli import METHOD_CHOICES, build_parser, main
from telesmooth.smoothing.methods import (
    CHAIN_METHODS,
    FIXED_LAG_METHODS,
    METHOD_ALIASES,
    METHODS,
    OFFLINE_METHODS,
    SmoothingSettings,
    method_name,
    method_variant,
    smooth_recording,
)
from telesmooth.smoothing.trajectory_io import write_joint_csv
from telesmooth.studies.comparison import method_settings
from telesmooth.studies.experiment import ExperimentConfig
from telesmooth.systems.reduced_q_smoother import ONLINE_SMOOTHER_METHODS, ReducedQSmootherConfig

DT = 0.25
NAMES = ("a", "b")


def operator_samples(num_samples=60):
    t = DT * np.arange(num_samples)
    s = np.clip(t / 10.0, 0.0, 1.0)
    q = np.stack([0.3 * (10 * s**3 - 15 * s**4 + 6 * s**5), -0.2 * s], axis=1)
    return t, q + np.random.default_rng(1).normal(0.0, 1e-3, q.shape)


def test_the_method_groups_are_methods_of_the_registry():
    for group in (FIXED_LAG_METHODS, OFFLINE_METHODS, CHAIN_METHODS):
        assert set(group) <= set(METHODS)
    assert set(METHOD_ALIASES.values()) <= set(METHODS)
    assert not set(METHOD_ALIASES) & set(METHODS)
    assert METHOD_CHOICES == METHODS + tuple(METHOD_ALIASES)


def test_every_method_runs_through_the_dispatch_table_and_nothing_else_is_in_it():
    from telesmooth.smoothing.methods import _RUNS

    computations = {method_variant(name, SmoothingSettings())[0] for name in METHODS}
    assert set(_RUNS) == computations
    z = np.linspace([0.0, 0.1], [0.2, -0.1], 12)
    for name in METHODS + tuple(METHOD_ALIASES):
        result = smooth_recording(z, 0.25, name, SmoothingSettings(max_acceleration=0.5,
                                                                  max_jerk=1.0))
        assert result.method == method_name(name)
        assert result.positions.shape == z.shape


@pytest.mark.parametrize("alias, method", sorted(METHOD_ALIASES.items()))
def test_an_alias_is_its_method(alias, method):
    assert method_name(alias) == method
    t, q = operator_samples()
    by_alias = smooth_recording(q, DT, alias, joint_names=NAMES)
    by_name = smooth_recording(q, DT, method, joint_names=NAMES)
    assert by_alias.method == method
    np.testing.assert_array_equal(by_alias.positions, by_name.positions)


def test_an_unknown_name_is_refused_with_the_list():
    with pytest.raises(ValueError, match=r"--method = 'fast' is not one of the"):
        method_name("fast", "--method")
    with pytest.raises(ValueError, match=r"method = 'fast' must be one of"):
        smooth_recording(operator_samples()[1], DT, "fast")


def test_offline_cks_trajectory_is_offline_cks_with_trajectory_limits_and_rest():
    settings = SmoothingSettings(max_acceleration=0.05, max_jerk=0.1)
    base, variant = method_variant("offline-cks-trajectory", settings)
    assert base == "offline-cks"
    assert variant == dataclasses.replace(settings, constraint="trajectory", rest_at_end=True)
    t, q = operator_samples()
    named = smooth_recording(q, DT, "offline-cks-trajectory", settings, joint_names=NAMES)
    spelled = smooth_recording(q, DT, base, variant, joint_names=NAMES)
    assert named.method == "offline-cks-trajectory"
    np.testing.assert_array_equal(named.positions, spelled.positions)


def test_smooth_runs_offline_cks_trajectory_as_compare_does(tmp_path, capsys):
    t, q = operator_samples()
    path = tmp_path / "operator.csv"
    write_joint_csv(path, t, q, NAMES)
    limits = ["--acc-max", "0.05", "--jerk-max", "0.1"]
    assert main(["smooth", str(path), "-o", str(tmp_path / "named.csv"), "--method",
                 "offline-cks-trajectory", *limits]) == 0
    assert main(["smooth", str(path), "-o", str(tmp_path / "spelled.csv"), "--method",
                 "offline-cks", "--constraint", "trajectory", "--rest-at-end", *limits]) == 0
    assert main(["smooth", str(path), "-o", str(tmp_path / "alias.csv"), "--method",
                 "pass-through", *limits]) == 0
    assert "method original)" in capsys.readouterr().err
    assert (tmp_path / "named.csv").read_text() == (tmp_path / "spelled.csv").read_text()
    alias = np.loadtxt(tmp_path / "alias.csv", delimiter=",", skiprows=1)
    np.testing.assert_allclose(alias[:, 1:3], q, rtol=0, atol=1e-12)


def _subparser(name):
    parser = build_parser()
    for action in parser._subparsers._group_actions:
        return action.choices[name]


def _option(parser, flag):
    return next(a for a in parser._actions if flag in a.option_strings)


def test_every_command_reads_the_registry():
    assert tuple(_option(_subparser("smooth"), "--method").choices) == METHOD_CHOICES
    assert tuple(_option(_subparser("foresight"), "--method").choices) == METHOD_CHOICES
    for command in ("compare", "experiment"):
        assert _option(_subparser(command), "--methods").default == ",".join(METHODS)
    assert ExperimentConfig().methods == METHODS


def test_the_demo_runs_every_method():
    from telesmooth.scripts.demo_report import demo_runs

    shown = {method for _, method, _ in demo_runs()}
    assert shown | {"ruckig"} == set(METHODS)


def test_the_chain_takes_both_names_of_the_pass_through():
    assert set(ONLINE_SMOOTHER_METHODS) == set(CHAIN_METHODS) | {
        alias for alias, method in METHOD_ALIASES.items() if method in CHAIN_METHODS}
    for name in ("pass-through", "original"):
        assert ReducedQSmootherConfig(method=name).method == name
        scenario = LoadScenario(scenario_text=f"{{smoother: {{method: {name}}}}}")
        assert method_settings(scenario, name)[0] == "original"
    with pytest.raises(ValueError, match="ReducedQSmootherConfig.method = 'kf'"):
        ReducedQSmootherConfig(method="kf")


def test_the_experiment_takes_an_alias_by_its_name():
    config = ExperimentConfig(shapes=("Angle",), methods=("pass-through", "online-cks"))
    assert config.methods == ("original", "online-cks")
