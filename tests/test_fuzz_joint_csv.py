"""Property-based fuzzing of the joint trajectory CSV reader of ``telesmooth smooth``
(``read_joint_csv``, ``read_csv_table``, ``parse_csv_number``).

The contract, the conventions and the shared generators: tests/fuzz_helpers.py (a bad
input gets a clear ValueError or a held, flagged output; never another exception; what was
accepted is not altered).
"""

from __future__ import annotations

import contextlib
import io
import math

import numpy as np
import pytest
from fuzz_helpers import (
    BAD_TOKENS,
    FINITE,
    MUTATIONS,
    NAMES,
    _assert_clear_error,
    _is_finite_number,
    _read_or_error,
    _same_floats,
    _write,
    fuzz,
    mutate,
    tables,
    temporary_work_dir,
)
from hypothesis import assume, example, given
from hypothesis import strategies as st

from telesmooth.smoothing.trajectory_io import (
    parse_csv_number,
    read_csv_table,
    read_joint_csv,
)
from telesmooth.user_input import ASCII_BLANKS, quote


@pytest.fixture(scope="module")
def work_dir():
    yield from temporary_work_dir()


# ======================================================================================
# Joint trajectory CSV (telesmooth smooth)
# ======================================================================================


@fuzz(150)
@given(table=tables(), use_dt=st.booleans())
def test_joint_csv_valid_tables_round_trip_exactly(work_dir, table, use_dt):
    path = _write(work_dir, table.render())
    result, error = _read_or_error(read_joint_csv, path,
                                   expected_dt_s=table.dt if use_dt else None)
    assert error is None, f"valid file refused: {type(error).__name__}: {error}"
    assert result.joint_names == tuple(table.names)
    assert _same_floats(result.t_s, table.t)
    assert _same_floats(result.positions, table.values)
    assert math.isclose(result.dt_s, table.dt, rel_tol=1e-9)


@fuzz(200)
@given(data=st.data(), table=tables(), kind=st.sampled_from(MUTATIONS))
def test_joint_csv_every_single_fault_is_a_located_value_error(work_dir, data, table, kind):
    fragments = mutate(data.draw, table, kind, reader="joint")
    path = _write(work_dir, table.render())
    result, error = _read_or_error(read_joint_csv, path)
    assert error is not None, f"{kind}: bad file accepted: {table.render()!r}"
    _assert_clear_error(error, path, *fragments)


@fuzz(60)
@given(table=tables(), factor=st.floats(1e-4, 0.5), sign=st.sampled_from([1.0, -1.0]))
def test_joint_csv_wrong_expected_dt_is_named(work_dir, table, factor, sign):
    path = _write(work_dir, table.render())
    expected = table.dt * (1.0 + sign * factor)
    result, error = _read_or_error(read_joint_csv, path, expected_dt_s=expected)
    _assert_clear_error(error, path, "--dt", repr(expected))


@fuzz(300)
@given(text=st.one_of(
    st.text(max_size=200),
    st.builds(lambda h, body: h + body,
              st.sampled_from(["t,a\n", "t,a,b\r\n", " t , a\n0,1\n", "t,a\n0,0\n0.5,"]),
              st.text(st.sampled_from(list("0123456789.,-+e \n\r\"\tnaif")), max_size=120)),
))
def test_joint_csv_arbitrary_text_parses_or_gives_a_value_error(work_dir, text):
    path = _write(work_dir, text)
    result, error = _read_or_error(read_joint_csv, path)
    if error is not None:
        _assert_clear_error(error, path)
        return
    # Whatever was accepted satisfies the documented contract.
    assert result.t_s.ndim == 1 and len(result.t_s) >= 2
    assert result.positions.shape == (len(result.t_s), len(result.joint_names))
    assert np.all(np.isfinite(result.t_s)) and np.all(np.isfinite(result.positions))
    assert np.all(np.diff(result.t_s) > 0)
    assert len(set(result.joint_names)) == len(result.joint_names) and all(result.joint_names)


@fuzz(200)
@given(blob=st.binary(max_size=300))
def test_joint_csv_arbitrary_bytes_raise_only_value_errors(work_dir, blob):
    path = _write(work_dir, blob)
    result, error = _read_or_error(read_joint_csv, path)
    if error is not None:   # a ValueError naming the file, also for non-UTF-8 bytes
        _assert_clear_error(error, path)


@fuzz(200)
@given(cell=st.one_of(FINITE.map(repr), BAD_TOKENS, st.text(max_size=12)),
       line=st.integers(1, 10**6), column=NAMES)
def test_parse_csv_number_is_a_finite_float_or_a_located_error(cell, line, column):
    try:
        value = parse_csv_number(cell, path="f.csv", line=line, column=column)
    except ValueError as error:
        assert not _is_finite_number(cell)
        assert str(error).startswith(f"f.csv: line {line}, column {column!r}: ")
        assert quote(cell.strip(ASCII_BLANKS)) in str(error)
    else:
        assert _is_finite_number(cell) and value == float(cell) and math.isfinite(value)


@fuzz(100)
@given(text=st.text(max_size=100))
def test_read_csv_table_keeps_file_line_numbers(work_dir, text):
    path = _write(work_dir, text)
    try:
        header, rows = read_csv_table(path, expected_header_hint="h", after_time_hint="a")
    except ValueError as error:
        assert str(error).startswith(str(path))
        return
    assert header[0] == "t"
    lines = [int(n) for n, _ in rows]
    assert lines == sorted(lines) and len(set(lines)) == len(lines) and min(lines, default=2) >= 2
    if '"' not in text:   # without quoted fields one record is one physical line
        physical = text.replace("\r\n", "\n").replace("\r", "\n").split("\n")
        for number, cells in rows:
            assert ",".join(cells) == physical[number - 1]


def test_cli_smooth_reports_bad_files_as_one_line_errors(work_dir):
    from telesmooth.scripts.cli import main

    bad = {
        "cell.csv": "t,a\n0,1\n0.25,abc\n",
        "count.csv": "t,a,b\n0,1,2\n0.25,1\n",
        "step.csv": "t,a\n0,1\n0.25,1\n0.75,1\n",
        "bom.csv": "\ufefft,a\n0,1\n0.25,1\n",
        "nan.csv": "t,a\n0,1\n0.25,nan\n",
    }
    for name, text in bad.items():
        path = _write(work_dir, text, name)
        out = work_dir / f"{name}.out.csv"
        stderr = io.StringIO()
        with contextlib.redirect_stderr(stderr):
            status = main(["smooth", str(path), "-o", str(out), "--acc-max", "1",
                           "--jerk-max", "1"])
        assert status == 2 and not out.exists(), name
        lines = stderr.getvalue().strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("telesmooth smooth: error: ")
        assert str(path) in lines[0]


# --- CSV regressions ---


# Regression (fixed): smoothing/trajectory_io.py read_csv_table opens the file as text and does
# not catch UnicodeDecodeError, so a file with a non-UTF-8 byte (e.g. b't,a\n0,1\n1,\xff\n', a
# Latin-1 degree sign, ...) raises "'utf-8' codec can't decode byte 0xff in position 10", naming
# neither the file nor the line; expected ValueError('<path>: ... line 3 ...').
@fuzz(40)
@example(prefix=b"t,a\n0,1\n1,", junk=b"\xff", suffix=b"\n")
@given(prefix=st.sampled_from([b"t,a\n0,1\n1,", b"t,", b"t,a\n0,1\n"]),
       junk=st.sampled_from([b"\xff", b"\xb0", b"\xe9", b"\xc3(", b"\x80abc"]),
       suffix=st.sampled_from([b"\n", b"2\n", b""]))
def test_joint_csv_non_utf8_bytes_error_names_the_file(work_dir, prefix, junk, suffix):
    path = _write(work_dir, prefix + junk + suffix)
    result, error = _read_or_error(read_joint_csv, path)
    line = prefix.count(b"\n") + 1   # the junk is on the line the prefix ends on
    _assert_clear_error(error, path, f"line {line}:", "UTF-8")


# Regression (fixed): smoothing/trajectory_io.py read_csv_table does not catch csv.Error: a cell
# longer than csv.field_size_limit() (131072 chars), e.g. 't,a\n0,1\n1,' + '1'*131073, raises
# _csv.Error('field larger than field limit (131072)'), which is not a ValueError, so
# `telesmooth smooth` dies with a traceback; expected a ValueError naming file and line.
@fuzz(5)
@example(size=131073, where="cell")
@given(size=st.integers(131073, 140000), where=st.sampled_from(["cell", "header"]))
def test_joint_csv_huge_field_is_a_value_error(work_dir, size, where):
    text = ("t," + "a" * size + "\n0,1\n1,2\n") if where == "header" else \
        ("t,a\n0,1\n1," + "1" * size + "\n")
    path = _write(work_dir, text)
    result, error = _read_or_error(read_joint_csv, path)
    _assert_clear_error(error, path, f"line {1 if where == 'header' else 3}:",
                        "field larger than field limit")


# Regression (fixed): smoothing/trajectory_io.py read_csv_table numbers csv *records*, not file
# lines: after a quoted cell that spans lines the reported line is too small.
# 't,a\n"0\n",1\n1,x\n' says 'line 3, column \'a\': \'x\' is not a number' but 'x' is on line 4
# (the docstring promises 'its line number in the file').
@fuzz(40)
@example(extra_lines=1, where="data")
@given(extra_lines=st.integers(1, 3), where=st.sampled_from(["data", "header"]))
def test_joint_csv_line_numbers_survive_quoted_line_breaks(work_dir, extra_lines, where):
    if where == "header":
        text = 't,"a' + "\n" * extra_lines + 'b"\n0,1\n1,x\n'
    else:
        text = 't,a\n"0' + "\n" * extra_lines + '",1\n1,x\n'
    bad_line = 4 + extra_lines - 1
    path = _write(work_dir, text)
    result, error = _read_or_error(read_joint_csv, path)
    _assert_clear_error(error, path, f"line {bad_line},", "'x' is not a number")
    # A bad cell after a line break inside its own row is located on its own line.
    path = _write(work_dir, 't,a,b\n0,1,2\n1,"1' + "\r\n" * extra_lines + '",y\n')
    result, error = _read_or_error(read_joint_csv, path)
    _assert_clear_error(error, path, f"line {3 + extra_lines}, column 'b'", "'y' is not a number")


# Regression (fixed): smoothing/trajectory_io.py check_uniform_time accepts finite time columns
# whose step overflows: 't,a\n-1e308,0\n1e308,0\n' is read without error but
# JointTrajectory.dt_s is inf (t[-1]-t[0] overflows, the NaN deviation passes the '>' test);
# with 3 rows (-1e308, 0, 1e308) the real step 1e308 is reported as inf. Expected a ValueError
# (time step not finite) or the finite step.
@fuzz(30)
@example(t0=-1e308, step=1e308, rows=3)
@given(t0=st.floats(-1.7e308, -1e307), step=st.floats(1e307, 1.7e308), rows=st.integers(2, 5))
def test_joint_csv_time_step_is_finite_or_refused(work_dir, t0, step, rows):
    t = [t0]
    for _ in range(rows - 1):
        t.append(t[-1] + step)
    assume(all(math.isfinite(v) for v in t))
    path = _write(work_dir, "t,a\n" + "".join(f"{v!r},0\n" for v in t))
    result, error = _read_or_error(read_joint_csv, path)
    if error is not None:
        _assert_clear_error(error, path)
    else:
        with np.errstate(over="ignore"):
            dt = result.dt_s
        assert math.isfinite(dt) and dt > 0, f"accepted with dt_s = {dt!r} for t = {t!r}"
        assert math.isclose(dt, step, rel_tol=1e-9)


# Regression (fixed): smoothing/trajectory_io.py check_uniform_time adds an undocumented
# absolute slack of 1e-12 s to the documented *relative* 1e-6 uniformity tolerance, so for steps
# below ~1e-7 s grossly non-uniform time columns pass: 't,a\n0,0\n1e-13,0\n5e-13,0\n' (steps
# 1e-13 and 4e-13 s) is accepted; expected 'the time step must be uniform'.
@fuzz(30)
@example(dt=1e-13, factor=3.0)
@given(dt=st.floats(1e-15, 1e-9), factor=st.floats(0.01, 3.0))
def test_joint_csv_tiny_steps_must_be_uniform_too(work_dir, dt, factor):
    t = [0.0, dt, dt + dt * (1.0 + factor)]
    path = _write(work_dir, "t,a\n" + "".join(f"{v!r},0\n" for v in t))
    result, error = _read_or_error(read_joint_csv, path)
    _assert_clear_error(error, path, "uniform")


@fuzz(40)
@example(dt=1e-13, k0=0, rows=3)
@example(dt=1e-3, k0=1_700_000_000_000, rows=10)   # epoch seconds at 1 kHz
@given(dt=st.one_of(st.floats(1e-15, 1e-9), st.floats(1e-4, 1e-2)),
       k0=st.one_of(st.integers(-1000, 1000), st.integers(10**9, 10**13)),
       rows=st.integers(2, 10))
def test_joint_csv_uniform_time_is_accepted_at_any_scale(work_dir, dt, k0, rows):
    # The counterpart of the test above: the relative tolerance (plus the resolution of the
    # time values themselves) accepts every uniform grid, tiny steps and epoch times alike.
    t = [(k0 + k) * dt for k in range(rows)]
    path = _write(work_dir, "t,a\n" + "".join(f"{v!r},0\n" for v in t))
    result, error = _read_or_error(read_joint_csv, path)
    assert error is None, f"{type(error).__name__}: {error}"
    # The step is as exact as times of this magnitude can carry it.
    resolution = 2 * np.spacing(max(abs(t[0]), abs(t[-1])))
    assert abs(result.dt_s - dt) <= 1e-9 * dt + resolution
