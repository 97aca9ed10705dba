"""``telesmooth smooth`` prints what a user needs: per joint whether the FD acceleration and
jerk limits are met (max/limit, share of samples over), the worst ratios and the deformation,
then the "wrote" lines; and docs/commands.md lists every method it accepts.

Known answers: with ``--method original`` the sent positions are the samples, so on a
parabola q = c·t² the FD acceleration is 2c at every sample and its ratio to a_max is 2c/a_max
(written out here, not taken from the metrics module); the FD jerk is zero up to rounding and
the deformation is zero. The deformation of another method is recomputed from the files.
"""

import re
from pathlib import Path

import numpy as np
import pytest
from bad_input_helpers import run

from telesmooth.smoothing.methods import METHOD_ALIASES, METHODS

DT = 0.25
A_MAX = 0.1
# q = c t²: FD acceleration 2c; joint "over" at 1.5 a_max, joint "within" at 0.5 a_max.
CURVATURE = {"over": 0.75 * A_MAX, "within": 0.25 * A_MAX}
ROWS = 24


def _parabola_csv(folder) -> Path:
    t = DT * np.arange(ROWS)
    lines = ["t," + ",".join(CURVATURE)]
    lines += [",".join(repr(float(v)) for v in (tk, *(c * tk * tk for c in CURVATURE.values())))
              for tk in t]
    path = Path(folder) / "parabola.csv"
    path.write_text("\n".join(lines) + "\n")
    return path


def _table(stderr: str) -> dict:
    """The summary's rows by joint name: the cells split on runs of two spaces or more."""
    lines = stderr.splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith("joint "))
    header = re.split(r"\s{2,}", lines[start].strip())
    rows = {}
    for line in lines[start + 1:]:
        if line.startswith("worst"):
            break
        cells = re.split(r"\s{2,}", line.strip())
        rows[cells[0]] = dict(zip(header, cells))
    return rows


def test_original_on_a_parabola_reports_the_known_ratio_over_and_within(tmp_path, capsys):
    source = _parabola_csv(tmp_path)
    status, _, stderr = run(capsys, "smooth", source, "-o", tmp_path / "out.csv",
                            "--method", "original", "--acc-max", A_MAX, "--jerk-max", 0.5)
    assert status == 0, stderr
    rows = _table(stderr)
    assert set(rows) == set(CURVATURE)
    for name, c in CURVATURE.items():
        expected = 2.0 * c / A_MAX
        cell = rows[name]["acc max/limit"]
        assert abs(float(cell.rstrip("!")) - expected) < 0.005 + 1e-9, (name, cell)
        assert cell.endswith("!") == (expected > 1.0), (name, cell)
        # Every FD acceleration sample of the over joint is over; none of the other.
        assert rows[name]["acc over"] == ("100.0 %" if expected > 1.0 else "0.0 %")
        assert rows[name]["jerk max/limit"] == "0.00" and rows[name]["jerk over"] == "0.0 %"
        assert rows[name]["|Δq| mean / max [mrad]"] == "0.00 / 0.00"
    assert rows["over"]["limits"] == "over: acc"
    assert rows["within"]["limits"] == "met"
    assert "the FD limits are met on 1 of 2 joint(s)" in stderr
    assert "worst max/limit: FD acceleration 1.50! (over), FD jerk 0.00" in stderr
    lines = [line for line in stderr.splitlines() if line.strip()]
    assert lines[-1] == f"wrote {tmp_path / 'out.csv'} ({ROWS} samples, method original)"
    assert lines[0].startswith("original: 24 samples at Δt = 0.25 s")
    assert len(lines) <= 6          # headline, header, one row per joint, worst, wrote


def test_the_deformation_printed_is_the_one_in_the_output_file(tmp_path, capsys):
    source = _parabola_csv(tmp_path)
    out = tmp_path / "out.csv"
    status, _, stderr = run(capsys, "smooth", source, "-o", out, "--method", "offline-hard",
                            "--acc-max", A_MAX, "--jerk-max", 0.5, "--metrics",
                            tmp_path / "m.json")
    assert status == 0, stderr
    original = np.loadtxt(source, delimiter=",", skiprows=1)[:, 1:]
    smoothed = np.loadtxt(out, delimiter=",", skiprows=1)[:, 1:3]
    error_mrad = 1e3 * np.abs(smoothed - original)
    rows = _table(stderr)
    for j, name in enumerate(CURVATURE):
        mean, peak = (float(v) for v in rows[name]["|Δq| mean / max [mrad]"].split(" / "))
        assert abs(mean - error_mrad[:, j].mean()) <= 0.005 + 1e-9
        assert abs(peak - error_mrad[:, j].max()) <= 0.005 + 1e-9
    # offline-hard keeps the FD limits hard: met on both joints, and the deformation of the
    # joint over its limit is not zero.
    assert "the FD limits are met on 2 of 2 joint(s)" in stderr
    assert error_mrad[:, 0].max() > 0.01
    assert stderr.rstrip().endswith(f"wrote {tmp_path / 'm.json'}")


def test_vel_max_adds_the_velocity_columns(tmp_path, capsys):
    source = _parabola_csv(tmp_path)
    status, _, stderr = run(capsys, "smooth", source, "-o", tmp_path / "out.csv", "--method",
                            "original", "--acc-max", A_MAX, "--jerk-max", 0.5, "--vel-max", 1)
    assert status == 0, stderr
    rows = _table(stderr)
    # FD velocity of c t² over [t_k, t_k+1] is c (2 t_k + Δt); its largest is c (2 t_max − Δt).
    for name, c in CURVATURE.items():
        expected = c * (2.0 * DT * (ROWS - 1) - DT) / 1.0
        assert abs(float(rows[name]["vel max/limit"].rstrip("!")) - expected) < 0.005 + 1e-9


def test_too_few_samples_for_a_jerk_read_n_a(tmp_path, capsys):
    path = tmp_path / "three.csv"
    path.write_text("t,a\n0,0\n0.25,0\n0.5,0.001\n")
    status, _, stderr = run(capsys, "smooth", path, "-o", tmp_path / "out.csv", "--method",
                            "original", "--acc-max", 0.1, "--jerk-max", 0.5)
    assert status == 0, stderr
    row = _table(stderr)["a"]
    assert row["jerk max/limit"] == "n/a" and row["jerk over"] == "n/a"
    assert row["acc max/limit"] == "0.16"       # 0.001 / 0.25² / 0.1


def _smooth_section() -> str:
    text = (Path(__file__).resolve().parent.parent / "docs" / "commands.md").read_text()
    start = text.index("\n## smooth\n")
    return text[start:text.index("\n## ", start + 1)]


@pytest.mark.parametrize("name", METHODS + tuple(METHOD_ALIASES))
def test_the_smooth_section_lists_every_method_and_alias(name):
    # One bullet per name, the name first in code: "* `name` ..."
    assert re.search(rf"^\s*\* `{re.escape(name)}`", _smooth_section(), re.MULTILINE), name


def _numbers(line: str):
    """``line`` split into its numbers and the text around them."""
    parts = re.split(r"(\d+\.\d+)", line)
    return parts[0::2], [float(number) for number in parts[1::2]]


def test_the_summary_example_in_the_docs_is_what_the_command_prints(tmp_path, monkeypatch,
                                                                  capsys):
    section = _smooth_section()
    marker = section.index("<!-- smooth summary example -->")
    block = section[section.index("```text\n", marker) + len("```text\n"):]
    block = block[:block.index("```")]
    lines = [line.strip() for line in block.splitlines() if line.strip()]
    command, expected = lines[0], lines[1:]
    assert command.startswith("$ .venv/bin/telesmooth smooth parabola.csv ")
    # The input as the docs describe it: t = 0, 0.25, …, 5.75; over = 0.075 t², within =
    # 0.025 t².
    monkeypatch.chdir(tmp_path)
    t = [0.25 * k for k in range(24)]
    (tmp_path / "parabola.csv").write_text(
        "t,over,within\n" + "".join(f"{x!r},{0.075 * x * x!r},{0.025 * x * x!r}\n" for x in t))
    status, _, stderr = run(capsys, *command.split()[2:])
    assert status == 0, stderr
    printed = [line.strip() for line in stderr.splitlines() if line.strip()]
    assert len(printed) == len(expected), (printed, expected)
    for got, want in zip(printed, expected):
        got_text, got_numbers = _numbers(got)
        want_text, want_numbers = _numbers(want)
        # The same words and layout; each number within one unit of its last printed place
        # (a value on a rounding edge may print either way on another CPU).
        assert [re.sub(r"\s+", " ", part) for part in got_text] == \
            [re.sub(r"\s+", " ", part) for part in want_text], (got, want)
        assert all(abs(a - b) <= 0.0101 for a, b in zip(got_numbers, want_numbers)), (got, want)
