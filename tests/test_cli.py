"""Tests for the ``telesmooth smooth`` command line (telesmooth.scripts.cli).

Driven in-process through ``main([...])`` with files in tmp_path; one subprocess run of the
installed console script proves the entry point. The contract: the output CSV has the input's
rows and joint columns plus ``sent_t``; errors exit with status 2, print one line to stderr
and write nothing.
"""

import csv
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from telesmooth.scripts.cli import main
from telesmooth.smoothing.methods import FIXED_LAG_METHODS, METHODS
from telesmooth.smoothing.metrics import finite_differences, limit_statistics
from telesmooth.smoothing.trajectory_io import write_joint_csv

DT = 0.25
NAMES = ("shoulder", "elbow", "wrist")
A_MAX = 0.05
J_MAX = 0.1
LIMITS = ["--acc-max", str(A_MAX), "--jerk-max", str(J_MAX)]


def reach(t, t0, duration, amplitude):
    s = np.clip((t - t0) / duration, 0.0, 1.0)
    return amplitude * (10 * s**3 - 15 * s**4 + 6 * s**5)


def operator_motion(num_samples=80, seed=0):
    """Three joints, two minimum-jerk reaches each, plus N(0, 1e-3²) noise; t starts at 2 s."""
    t = 2.0 + DT * np.arange(num_samples)
    s = t - 2.0
    q = np.stack(
        [
            0.1 + reach(s, 1.0, 5.0, 0.4) + reach(s, 9.0, 6.0, -0.3),
            -0.2 + reach(s, 2.0, 6.0, -0.5) + reach(s, 11.0, 5.0, 0.2),
            reach(s, 0.5, 5.0, 0.3) + reach(s, 8.0, 7.0, -0.4),
        ],
        axis=1,
    )
    return t, q + np.random.default_rng(seed).normal(0.0, 1e-3, q.shape)


@pytest.fixture
def input_csv(tmp_path):
    t, q = operator_motion()
    path = tmp_path / "operator.csv"
    write_joint_csv(path, t, q, NAMES)
    return path, t, q


def read_csv(path):
    """(header, values (N, columns)) of a CSV written by the CLI."""
    with Path(path).open(newline="") as handle:
        rows = list(csv.reader(handle))
    return rows[0], np.array([[float(cell) for cell in row] for row in rows[1:]])


def run_cli(capsys, *args):
    status = main(["smooth", *map(str, args)])
    captured = capsys.readouterr()
    return status, captured.out, captured.err


# --- output contract ---


@pytest.mark.parametrize("method", METHODS)
def test_every_method_writes_the_input_rows_plus_sent_t(tmp_path, capsys, input_csv, method):
    path, t, q = input_csv
    out = tmp_path / "smoothed.csv"

    status, stdout, stderr = run_cli(capsys, path, "-o", out, "--method", method, *LIMITS)

    assert status == 0, stderr
    assert stdout == ""
    assert f"wrote {out} (80 samples, method {method})" in stderr
    header, values = read_csv(out)
    assert header == ["t", *NAMES, "sent_t"]
    assert values.shape == (80, 5)
    np.testing.assert_array_equal(values[:, 0], t)
    assert np.all(np.isfinite(values))
    delay = 3 * DT if method in FIXED_LAG_METHODS else 0.0
    np.testing.assert_allclose(values[:, 4], t + delay, rtol=0, atol=1e-12)
    # A smoother stays close to the operator (noise 1e-3, reaches ≤ 0.5 rad). Ruckig is not a
    # smoother: it trails the stream (tests/test_ruckig_stream.py).
    if method != "ruckig":
        assert np.abs(values[:, 1:4] - q).max() < 0.1


@pytest.mark.parametrize("lag", [3, 5])
@pytest.mark.parametrize("method", FIXED_LAG_METHODS)
def test_sent_t_is_t_plus_lag_times_dt(tmp_path, capsys, input_csv, method, lag):
    path, t, _ = input_csv
    out = tmp_path / "smoothed.csv"
    status, _, stderr = run_cli(capsys, path, "-o", out, "--method", method, "--lag", lag,
                                *LIMITS)
    assert status == 0, stderr
    _, values = read_csv(out)
    np.testing.assert_allclose(values[:, -1], t + lag * DT, rtol=0, atol=1e-12)


@pytest.mark.parametrize("method", ["original", "kf", "kf-predictor", "offline-ks",
                                    "offline-cks"])
def test_sent_t_is_t_without_lag(tmp_path, capsys, input_csv, method):
    path, t, _ = input_csv
    out = tmp_path / "smoothed.csv"
    status, _, _ = run_cli(capsys, path, "-o", out, "--method", method, "--lag", 5, *LIMITS)
    assert status == 0
    _, values = read_csv(out)
    np.testing.assert_array_equal(values[:, -1], t)


def test_original_reproduces_the_input_exactly(tmp_path, capsys, input_csv):
    path, t, q = input_csv
    out = tmp_path / "original.csv"
    status, _, _ = run_cli(capsys, path, "-o", out, "--method", "original", *LIMITS)
    assert status == 0
    _, values = read_csv(out)
    np.testing.assert_array_equal(values[:, 0], t)
    np.testing.assert_array_equal(values[:, 1:4], q)


def test_default_method_is_online_cks(tmp_path, capsys, input_csv):
    path, _, _ = input_csv
    status, _, stderr = run_cli(capsys, path, "-o", tmp_path / "out.csv", *LIMITS)
    assert status == 0
    assert "method online-cks" in stderr


# --- metrics ---


@pytest.mark.parametrize("method", ["original", "bmfls", "offline-cks"])
def test_metrics_json_has_per_joint_entries(tmp_path, capsys, input_csv, method):
    path, _, q = input_csv
    out, metrics_path = tmp_path / "out.csv", tmp_path / "report" / "metrics.json"
    status, _, stderr = run_cli(capsys, path, "-o", out, "--method", method, *LIMITS,
                                "--metrics", metrics_path, "--link-lengths", "0.5,0.4,0.2")
    assert status == 0, stderr
    metrics = json.loads(metrics_path.read_text())
    _, values = read_csv(out)
    positions = values[:, 1:4]

    assert metrics["method"] == method
    assert metrics["joint_names"] == list(NAMES)
    for key in ("fd_acceleration", "fd_jerk"):
        for field in ("max_abs", "max_over_limit", "fraction_over_limit"):
            assert len(metrics[key][field]) == 3
    for field in ("mean", "rms", "max"):
        assert len(metrics["position_deformation_rad"][field]) == 3
    # The numbers describe the written file.
    np.testing.assert_allclose(metrics["fd_jerk"]["max_abs"],
                               np.abs(finite_differences(positions, DT, 3)).max(axis=0),
                               rtol=1e-12)
    np.testing.assert_allclose(metrics["position_deformation_rad"]["max"],
                               np.abs(positions - q).max(axis=0), rtol=1e-12, atol=0)
    cartesian = metrics["cartesian_deformation_m"]
    assert set(cartesian) == {"mean", "rms", "max"}
    assert 0.0 <= cartesian["mean"] <= cartesian["rms"] <= cartesian["max"]
    if method == "original":
        assert cartesian["max"] == 0.0
        assert metrics["position_deformation_rad"]["max"] == [0.0, 0.0, 0.0]
    else:
        assert cartesian["max"] > 0.0


def test_metrics_without_link_lengths_have_no_cartesian_entry(tmp_path, capsys, input_csv):
    path, _, _ = input_csv
    metrics_path = tmp_path / "metrics.json"
    status, _, _ = run_cli(capsys, path, "-o", tmp_path / "out.csv", "--method", "kf", *LIMITS,
                           "--metrics", metrics_path)
    assert status == 0
    metrics = json.loads(metrics_path.read_text())
    assert "cartesian_deformation_m" not in metrics
    assert len(metrics["fd_acceleration"]["max_abs"]) == 3
    assert len(metrics["position_deformation_rad"]["mean"]) == 3


def test_per_joint_limits_as_list_and_as_names_agree(tmp_path, capsys, input_csv):
    path, _, _ = input_csv
    runs = {
        "list": ["--acc-max", "0.05,0.02,0.1", "--jerk-max", "0.1,0.05,0.3"],
        "names": ["--acc-max", "wrist=0.1,shoulder=0.05,elbow=0.02",
                  "--jerk-max", "elbow=0.05, wrist=0.3, shoulder=0.1"],
        "scalar": ["--acc-max", "0.05", "--jerk-max", "0.1"],
    }
    outputs, metrics = {}, {}
    for name, limits in runs.items():
        out, metrics_path = tmp_path / f"{name}.csv", tmp_path / f"{name}.json"
        status, _, stderr = run_cli(capsys, path, "-o", out, "--method", "online-cks", *limits,
                                    "--metrics", metrics_path)
        assert status == 0, stderr
        outputs[name] = read_csv(out)[1]
        metrics[name] = json.loads(metrics_path.read_text())

    for name in ("list", "names"):
        assert metrics[name]["limits"] == {"max_acceleration_rad_per_s2": [0.05, 0.02, 0.1],
                                           "max_jerk_rad_per_s3": [0.1, 0.05, 0.3]}
    np.testing.assert_array_equal(outputs["list"], outputs["names"])
    # Per-joint limits act: only the joints whose limits changed are smoothed differently.
    assert metrics["list"]["final_sigma"][0] == metrics["scalar"]["final_sigma"][0]
    assert metrics["list"]["final_sigma"] != metrics["scalar"]["final_sigma"]


# --- hard FD limits ---


@pytest.mark.parametrize("extra", [[], ["--rest-at-end"], ["--vel-max", "0.15"]])
def test_trajectory_constraint_output_has_no_fd_violations(tmp_path, capsys, input_csv, extra):
    path, _, q = input_csv
    out = tmp_path / "cks.csv"
    status, _, stderr = run_cli(capsys, path, "-o", out, "--method", "offline-cks",
                                "--constraint", "trajectory", *LIMITS, *extra)
    assert status == 0, stderr
    positions = read_csv(out)[1][:, 1:4]

    for order, limit in ((2, A_MAX), (3, J_MAX)):
        original = limit_statistics(finite_differences(q, DT, order), limit)
        smoothed = limit_statistics(finite_differences(positions, DT, order), limit)
        assert min(original["fraction_over_limit"]) > 0.0  # the input breaks every joint's limit
        assert smoothed["fraction_over_limit"] == [0.0, 0.0, 0.0]
        assert max(smoothed["max_over_limit"]) <= 1.0 + 1e-6
    if extra[:1] == ["--vel-max"]:
        velocity = limit_statistics(finite_differences(positions, DT, 1), 0.15)
        assert velocity["fraction_over_limit"] == [0.0, 0.0, 0.0]
        assert max(limit_statistics(finite_differences(q, DT, 1), 0.15)["max_over_limit"]) > 1.0


def test_state_constraint_output_breaks_fd_limits(tmp_path, capsys, input_csv):
    """The paper's state box is soft on the FD values (docs/method.md §2.4); trajectory mode is
    not."""
    path, _, _ = input_csv
    out = tmp_path / "cks.csv"
    status, _, _ = run_cli(capsys, path, "-o", out, "--method", "offline-cks", *LIMITS)
    assert status == 0
    positions = read_csv(out)[1][:, 1:4]
    jerk = limit_statistics(finite_differences(positions, DT, 3), J_MAX)
    assert max(jerk["fraction_over_limit"]) > 0.0


@pytest.mark.parametrize("constraint", ["state", "trajectory"])
def test_both_offline_solvers_write_the_same_trajectory(tmp_path, capsys, input_csv, constraint):
    """--solver banded-ip and the Drake MathematicalProgram agree to 1e-6 rad."""
    path, _, _ = input_csv
    outputs = []
    for solver in ("drake", "banded-ip"):
        out = tmp_path / f"{solver}.csv"
        status, _, stderr = run_cli(capsys, path, "-o", out, "--method", "offline-cks",
                                    "--constraint", constraint, "--solver", solver, *LIMITS)
        assert status == 0, stderr
        outputs.append(read_csv(out)[1][:, 1:4])
    np.testing.assert_allclose(outputs[0], outputs[1], rtol=0, atol=1e-6)
    assert np.abs(outputs[0] - read_csv(path)[1][:, 1:4]).max() > 1e-4   # limits bind


# --- user errors: status 2, one line on stderr, nothing written ---


def nan_csv(tmp_path):
    path = tmp_path / "nan.csv"
    path.write_text("t,shoulder,elbow,wrist\n0,0,0,0\n0.25,0,0,0\n0.5,0,nan,0\n0.75,0,0,0\n")
    return path


ERROR_CASES = {
    "unknown joint": (
        ["--acc-max", "shoulder=0.05,hand=0.1", "--jerk-max", "0.1"],
        "--acc-max: unknown joint name(s) ['hand']; the joints are ['shoulder', 'elbow', "
        "'wrist']",
    ),
    "negative limit": (
        ["--acc-max", "0.05", "--jerk-max=shoulder=0.1,elbow=-0.2,wrist=0.1"],
        "--jerk-max[1] = -0.2 for joint 1 ('elbow') must be finite and > 0",
    ),
    "negative scalar limit": (
        ["--acc-max", "-0.05", "--jerk-max", "0.1"],
        "--acc-max[0] = -0.05 for joint 0 ('shoulder') must be finite and > 0",
    ),
    "zero limit": (
        ["--acc-max", "0.05,0,0.05", "--jerk-max", "0.1"],
        "--acc-max[1] = 0.0 for joint 1 ('elbow') must be finite and > 0",
    ),
    "missing joint in names": (
        ["--acc-max", "shoulder=0.05,elbow=0.1", "--jerk-max", "0.1"],
        "--acc-max: no value given for joint(s) ['wrist']",
    ),
    "wrong count": (
        ["--acc-max", "0.05", "--jerk-max", "0.1,0.2"],
        "--jerk-max has 2 value(s) [0.1, 0.2] but there are 3 joints",
    ),
    "wrong link count": (
        [*LIMITS, "--link-lengths", "0.5,0.4", "--metrics", "{tmp}/metrics.json"],
        "--link-lengths has 2 value(s)",
    ),
    "dt mismatch": ([*LIMITS, "--dt", "0.1"], "the time step is 0.25 s but --dt 0.1 s was given"),
    "operator without store": ([*LIMITS, "--operator", "alice"],
                               "--operator and --sigma-store go together"),
    "store without operator": ([*LIMITS, "--sigma-store", "{tmp}/sigma.json"],
                               "--operator and --sigma-store go together"),
    "negative lag": ([*LIMITS, "--lag", "-1"], "lag = -1 must be an integer >= 0"),
    "bad rho": ([*LIMITS, "--rho", "1.5"], "rho = 1.5 must be in (0, 1)"),
}


@pytest.mark.parametrize("case", ERROR_CASES)
def test_user_errors_exit_2_with_one_line_and_write_nothing(tmp_path, capsys, input_csv, case):
    path, _, _ = input_csv
    args, message = ERROR_CASES[case]
    args = [arg.replace("{tmp}", str(tmp_path)) for arg in args]
    out = tmp_path / "out.csv"

    status, stdout, stderr = run_cli(capsys, path, "-o", out, *args)

    assert status == 2
    assert stdout == ""
    assert stderr.startswith("telesmooth smooth: error: ")
    assert stderr.endswith("\n") and stderr.count("\n") == 1
    assert message in stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["operator.csv"]  # nothing written


def test_nan_in_csv_exits_2_naming_line_column_and_value(tmp_path, capsys):
    out = tmp_path / "out.csv"
    status, _, stderr = run_cli(capsys, nan_csv(tmp_path), "-o", out, *LIMITS,
                                "--metrics", tmp_path / "m.json")
    assert status == 2
    assert stderr.count("\n") == 1
    assert "line 4, column 'elbow': value 'nan' is not finite" in stderr
    assert not out.exists()
    assert not (tmp_path / "m.json").exists()


def test_missing_input_exits_2(tmp_path, capsys):
    out = tmp_path / "out.csv"
    status, _, stderr = run_cli(capsys, tmp_path / "absent.csv", "-o", out, *LIMITS)
    assert status == 2
    assert "cannot read" in stderr
    assert not out.exists()


def test_unparseable_limit_is_an_argparse_error(tmp_path, capsys, input_csv):
    path, _, _ = input_csv
    out = tmp_path / "out.csv"
    with pytest.raises(SystemExit) as exit_info:
        main(["smooth", str(path), "-o", str(out), "--acc-max", "fast", "--jerk-max", "0.1"])
    assert exit_info.value.code == 2
    assert "'fast': give a number, a comma list" in capsys.readouterr().err
    assert not out.exists()


# --- per-operator σ store ---


def test_operator_sigma_is_created_then_loaded_and_never_increases(tmp_path, capsys, input_csv):
    path, _, _ = input_csv
    store = tmp_path / "operators.json"
    common = [path, "--method", "online-cks", *LIMITS, "--operator", "alice",
              "--sigma-store", store]

    status, _, stderr = run_cli(capsys, *common, "-o", tmp_path / "first.csv")
    assert status == 0, stderr
    assert store.exists()
    assert "from" not in stderr  # nothing to load on the first run
    assert "operator 'alice': new operator" in stderr
    assert f"saved to {store}" in stderr
    first = json.loads(store.read_text())["operators"]["alice"]
    assert sorted(first) == sorted(NAMES)

    status, _, stderr = run_cli(capsys, *common, "-o", tmp_path / "second.csv",
                                "--metrics", tmp_path / "second.json")
    assert status == 0, stderr
    loaded = [first[name] for name in NAMES]
    assert f"operator 'alice': σ_0 = {loaded} from {store}" in stderr
    second = json.loads(store.read_text())["operators"]["alice"]
    metrics = json.loads((tmp_path / "second.json").read_text())
    assert metrics["final_sigma"] == [second[name] for name in NAMES]

    for name in NAMES:
        assert second[name] <= first[name] <= 4e-4
    assert any(first[name] < 4e-4 for name in NAMES)  # the limits did act
    assert any(second[name] < first[name] for name in NAMES)
    # The second run started from the stored σ, so it differs from a fresh run.
    assert not np.array_equal(read_csv(tmp_path / "first.csv")[1],
                              read_csv(tmp_path / "second.csv")[1])


def test_two_operators_share_one_store(tmp_path, capsys, input_csv):
    path, _, _ = input_csv
    store = tmp_path / "operators.json"
    for operator, limits in (("alice", LIMITS), ("bob", ["--acc-max", "1", "--jerk-max", "1"])):
        status, _, stderr = run_cli(capsys, path, "-o", tmp_path / f"{operator}.csv", *limits,
                                    "--operator", operator, "--sigma-store", store)
        assert status == 0, f"{operator}: {stderr}"
    operators = json.loads(store.read_text())["operators"]
    assert sorted(operators) == ["alice", "bob"]
    assert operators["bob"] == {name: 4e-4 for name in NAMES}  # loose limits: σ unchanged
    assert min(operators["alice"].values()) < 4e-4


def test_unknown_operator_in_existing_store_is_an_error(tmp_path, capsys, input_csv):
    path, _, _ = input_csv
    store = tmp_path / "operators.json"
    store.write_text(json.dumps({"format": "telesmooth-operator-sigma/1",
                                 "operators": {"alice": {name: 1e-4 for name in NAMES[:2]}}}))
    out = tmp_path / "out.csv"
    status, _, stderr = run_cli(capsys, path, "-o", out, *LIMITS, "--operator", "alice",
                                "--sigma-store", store)
    assert status == 2
    assert "no value given for joint(s) ['wrist']" in stderr
    assert not out.exists()


# --- the installed console script ---


def test_console_script_entry_point(tmp_path, input_csv):
    path, t, _ = input_csv
    script = Path(sys.executable).parent / "telesmooth"
    out = tmp_path / "cli.csv"
    completed = subprocess.run(
        [str(script), "smooth", str(path), "-o", str(out), "--method", "bmfls", *LIMITS],
        capture_output=True, text=True, timeout=120,
    )
    assert completed.returncode == 0, completed.stderr
    assert f"wrote {out} (80 samples, method bmfls)" in completed.stderr
    header, values = read_csv(out)
    assert header == ["t", *NAMES, "sent_t"]
    np.testing.assert_allclose(values[:, -1], t + 3 * DT, rtol=0, atol=1e-12)


def test_bench_writes_its_figures_and_their_ratios(tmp_path, capsys):
    pytest.importorskip("ruckig")
    status = main(["bench", "--out", str(tmp_path), "--max-n", "100", "--repeat", "1",
                   "--ticks", "20", "--max-drake-n", "100", "--sim-duration", "0"])
    captured = capsys.readouterr()
    assert status == 0, captured.err
    data = json.loads((tmp_path / "bench_core.json").read_text())
    (row,) = data["offline_cks"]
    assert row["num_samples"] == 100
    for mode in ("state", "trajectory"):
        assert row[f"{mode}_drake_success"] and row[f"{mode}_banded_ip_success"]
        assert row[f"{mode}_drake_over_banded_ip"] == pytest.approx(
            row[f"{mode}_drake_s"] / row[f"{mode}_banded_ip_s"])
        assert row[f"{mode}_max_position_difference_rad"] < 1e-6
    assert [r["lag"] for r in data["online_step"]] == [3, 75]
    for r in data["online_step"]:
        assert r["online_cks_over_ruckig"] == pytest.approx(
            r["online_cks_us_per_tick"] / r["ruckig_us_per_tick"])
        assert r["online_hard_over_ruckig"] == pytest.approx(
            r["online_hard_us_per_tick"] / r["ruckig_us_per_tick"])
        assert r["limiter_us_per_tick"] > 0.0
    assert "Online-CKS / Ruckig" in (tmp_path / "bench_core.md").read_text()
    assert "limiter alone [µs/tick]" in (tmp_path / "bench_core.md").read_text()
    assert "Online-CKS / Ruckig" in captured.out


def test_bench_online_only_runs_just_the_online_rows(tmp_path, capsys):
    pytest.importorskip("ruckig")
    status = main(["bench", "--out", str(tmp_path), "--online-only", "--repeat", "1",
                   "--ticks", "20"])
    captured = capsys.readouterr()
    assert status == 0, captured.err
    data = json.loads((tmp_path / "bench_core.json").read_text())
    assert data["offline_cks"] == [] and data["simulation"] == {} and data["experiment"] == {}
    assert [r["lag"] for r in data["online_step"]] == [3, 75]
    table = (tmp_path / "bench_core.md").read_text()
    assert table.startswith("Online step per 4 Hz tick") and "Offline-CKS" not in table


def test_a_solver_that_gives_up_exits_2_naming_the_joints_and_writes_nothing(
        tmp_path, capsys, input_csv, monkeypatch):
    # The banded interior point capped at one Newton step cannot converge: the failure is
    # reported per joint, and no partial output is written.
    import telesmooth.smoothing.offline as offline
    from telesmooth.smoothing.banded_ip import BandedIpOptions

    monkeypatch.setattr(offline, "BandedIpOptions",
                        lambda: BandedIpOptions(max_iterations=1))
    path, _, _ = input_csv
    out = tmp_path / "never.csv"
    status, _, stderr = run_cli(capsys, path, "-o", out, "--method", "offline-cks",
                                "--solver", "banded-ip", *LIMITS)
    assert status == 2
    assert "Offline-CKS failed" in stderr and "banded-ip: max_iterations" in stderr
    assert len(stderr.strip().splitlines()) == 1
    assert not out.exists()


# --- the command line describes itself ---


def _walk(parser, path=("telesmooth",)):
    """Every (command path, parser) below ``parser``, itself first."""
    import argparse

    yield path, parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from _walk(sub, path + (name,))


def _parsers():
    from telesmooth.link.relay import build_parser as relay_parser
    from telesmooth.scripts.bench_core import build_parser as bench_parser
    from telesmooth.scripts.cli import build_parser

    yield from _walk(build_parser())
    yield ("telesmooth", "bench"), bench_parser()
    yield ("telesmooth", "link-relay"), relay_parser()


def test_every_command_has_a_description_and_every_option_a_help_text():
    import argparse

    missing = []
    for path, parser in _parsers():
        if not (parser.description or "").strip():
            missing.append(f"{' '.join(path)}: no description")
        for action in parser._actions:
            if isinstance(action, (argparse._SubParsersAction, argparse._HelpAction)):
                continue
            if not (action.help or "").strip() or action.help == argparse.SUPPRESS:
                name = "/".join(action.option_strings) or action.dest
                missing.append(f"{' '.join(path)} {name}: no help text")
    assert not missing, missing


def test_version_prints_the_package_version(capsys):
    import tomllib
    from importlib import metadata

    from telesmooth.scripts.cli import package_version

    with pytest.raises(SystemExit) as exit_info:
        main(["--version"])
    assert exit_info.value.code == 0
    assert capsys.readouterr().out == f"telesmooth {package_version()}\n"
    try:
        expected = metadata.version("telesmooth")
    except metadata.PackageNotFoundError:
        expected = tomllib.loads((Path(__file__).resolve().parents[1] / "pyproject.toml")
                                 .read_text())["project"]["version"]
    assert package_version() == expected


def test_version_falls_back_to_pyproject_when_not_installed(monkeypatch):
    import tomllib
    from importlib import metadata

    from telesmooth.scripts.cli import package_version

    def not_installed(name):
        raise metadata.PackageNotFoundError(name)

    monkeypatch.setattr(metadata, "version", not_installed)
    pyproject = Path(__file__).resolve().parents[1] / "pyproject.toml"
    assert package_version() == tomllib.loads(pyproject.read_text())["project"]["version"]
