"""The newcomer path: the README's first steps work, and a failed command
leaves nothing behind."""

import os
import stat
import tomllib
from pathlib import Path

import pytest
from bad_input_helpers import assert_one_line_error, digest, run

REPOSITORY = Path(__file__).resolve().parent.parent


def test_keygen_makes_the_missing_private_folder_and_a_private_key(tmp_path, monkeypatch,
                                                                  capsys):
    monkeypatch.setenv("HOME", str(tmp_path))
    path = Path(os.path.expanduser("~/.telesmooth/uplink.key"))
    status, stdout, stderr = run(capsys, "keygen", path)
    assert status == 0, stderr
    assert stat.S_IMODE(path.parent.stat().st_mode) == 0o700
    assert stat.S_IMODE(path.stat().st_mode) == 0o600
    assert len(bytes.fromhex(path.read_text().strip())) == 32
    assert path.read_text().strip() not in stdout + stderr      # the key is never printed


def test_keygen_refuses_an_existing_key_in_one_line(tmp_path, capsys):
    path = tmp_path / "uplink.key"
    assert run(capsys, "keygen", path)[0] == 0
    before = digest(path)
    status, stdout, stderr = run(capsys, "keygen", path)
    assert_one_line_error(status, stdout, stderr, "keygen", "exists (a file); refusing to "
                                                            "overwrite it")
    assert digest(path) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["uplink.key"]


@pytest.mark.parametrize("argv, words", [
    (["demo", "--shape", "Sshap", "--out", "x/report"], "--shape = 'Sshap'"),
    (["demo", "--demo-index", "9", "--out", "x/report"], "--demo-index = 9"),
    (["smooth", "in.csv", "-o", "x/o.csv", "--method", "fast", "--acc-max", "1",
      "--jerk-max", "1"], "argument --method: invalid choice: 'fast'"),
    (["compare", "--methods", "fast", "--out", "x/report"], "--methods = 'fast'"),
    (["simulate", "--scenario-text", "{haptic: {lasa_shape: Sshap}}", "--out", "x/report"],
     "haptic.lasa_shape = 'Sshap'"),
    (["experiment", "--quick", "--methods", "fast", "--workers", "0", "--out", "x/report"],
     "--methods = 'fast'"),
])
def test_a_failed_command_leaves_no_out_folder(tmp_path, monkeypatch, capsys, argv, words):
    monkeypatch.chdir(tmp_path)
    status, stdout, stderr = run(capsys, *argv)
    assert_one_line_error(status, stdout, stderr, argv[0], words)
    assert list(tmp_path.iterdir()) == []


def test_a_command_failing_after_its_work_started_leaves_no_out_folder(tmp_path, monkeypatch,
                                                                        capsys):
    """The report folder is staged beside --out from the start; a failure in the middle of
    the work removes it and every folder made for it."""
    import telesmooth.scripts.demo_report as demo_report

    def fail(*args, **kwargs):
        raise RuntimeError("solver failed half-way")

    monkeypatch.setattr(demo_report, "smooth_recording", fail)
    monkeypatch.chdir(tmp_path)
    status, stdout, stderr = run(capsys, "demo", "--out", "a/b/report")
    assert_one_line_error(status, stdout, stderr, "demo", "solver failed half-way")
    assert list(tmp_path.iterdir()) == []


def test_every_package_data_folder_is_a_package_so_setuptools_installs_without_warning():
    """setuptools warns (40 lines, 'Package would be ignored') for package data in a
    sub-folder that is not listed in ``packages``: every package-data pattern must be a
    plain file pattern of a listed package, and every folder holding shipped data listed."""
    config = tomllib.loads((REPOSITORY / "pyproject.toml").read_text())["tool"]["setuptools"]
    packages, folders = config["packages"], config["package-dir"]
    for package, patterns in config["package-data"].items():
        assert package in packages and package in folders
        for pattern in patterns:
            assert "/" not in pattern, (package, pattern)
            assert list((REPOSITORY / folders[package]).glob(pattern)), (package, pattern)
    for folder in folders.values():
        assert (REPOSITORY / folder).is_dir()
