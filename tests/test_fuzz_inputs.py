"""Property-based fuzzing of every place a user or a device feeds input into telesmooth.

Contract checked everywhere: a bad input gets a clear error (a ValueError whose message names
the file and the line / column / field / value) or a held, flagged output; never an uncaught
exception of another type; and nothing that was accepted is lost or altered.

* CSV readers (``read_joint_csv``, ``read_csv_table``, ``parse_csv_number``, used by
  ``telesmooth smooth``; ``read_haptic_csv``) and the NPZ reader (``read_haptic_npz``).
* The generated LCM types' ``decode`` (the precise exception set is {ValueError, struct.error}:
  ValueError("Decode error") for a wrong fingerprint, struct.error for short or malformed
  bodies).
* The onboard ``JointCommandReceiver`` and the ground ``HapticCommandReceiver``, against an
  independent model of which packets are accepted.

Every hypothesis test is derandomized and uses no example database, so runs are reproducible
and nothing is written into the repository (files go to a temporary folder). The regression
tests of bugs this fuzzing found (all fixed) say what the bug was in a comment and start with
its minimal failing input as an explicit ``@example``.
"""

from __future__ import annotations

import contextlib
import csv
import io
import math
import struct
import tempfile
import time
import warnings
import zipfile
from dataclasses import dataclass
from pathlib import Path

import hypothesis.extra.numpy as hnp
import numpy as np
import pytest
from hypothesis import HealthCheck, assume, example, given, settings
from hypothesis import strategies as st

from telesmooth.user_input import ASCII_BLANKS, quote
from telesmooth.datasets.haptic_recording import (
    HapticRecording,
    read_haptic_csv,
    read_haptic_npz,
    write_haptic_npz,
)
from telesmooth.lcm_types import (
    decode_exact,
    lcmt_onboard_joint_status,
    lcmt_teleop_collision_event,
    lcmt_teleop_haptic_command,
    lcmt_teleop_joint_command,
)
from telesmooth.smoothing.trajectory_io import (
    parse_csv_number,
    read_csv_table,
    read_joint_csv,
)
from telesmooth.systems.haptic_command_receiver import (
    HapticCommandReceiver,
    HapticCommandReceiverConfig,
)
from telesmooth.systems.joint_command_receiver import (
    JointCommandReceiver,
    JointCommandReceiverConfig,
)


def fuzz(max_examples: int):
    """Deterministic hypothesis settings that write nothing to disk."""
    return settings(derandomize=True, database=None, deadline=None, max_examples=max_examples,
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large,
                                           HealthCheck.filter_too_much])


@pytest.fixture(scope="module")
def work_dir():
    with tempfile.TemporaryDirectory(prefix="telesmooth_fuzz_") as name:
        yield Path(name)


def _write(directory: Path, data: bytes | str, name: str = "fuzz.csv") -> Path:
    path = directory / name
    path.write_bytes(data.encode("utf-8") if isinstance(data, str) else data)
    return path


def _is_finite_number(text: str) -> bool:
    """Independent oracle: is ``text`` a plain finite decimal number? Only ASCII digits,
    signs, '.', 'e'/'E' and spaces or tabs, and Python's float syntax reads it as finite
    (float() alone also takes '1_0', non-ASCII digits and other white space, which the
    readers refuse)."""
    if not set(text) <= set("0123456789+-.eE \t\r\n\v\f"):
        return False
    try:
        return math.isfinite(float(text))
    except ValueError:
        return False


def _same_floats(a, b) -> bool:
    """Bit-for-bit equality of float arrays (distinguishes -0.0 from 0.0)."""
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    return a.shape == b.shape and np.array_equal(a.view(np.uint64), b.view(np.uint64))


def _assert_clear_error(error: BaseException, path: Path, *fragments: str) -> None:
    """The error is a ValueError naming the file and every expected fragment."""
    assert isinstance(error, ValueError), f"{type(error).__name__}: {error}"
    message = str(error)
    assert message.startswith(str(path)), f"message does not name the file: {message!r}"
    for fragment in fragments:
        assert fragment in message, f"{fragment!r} missing from {message!r}"


def _read_or_error(reader, path, **kwargs):
    """Runs ``reader``; returns (result, None) or (None, exception); never swallows others."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            return reader(path, **kwargs), None
    except Exception as error:  # noqa: BLE001 - the tests classify the type themselves
        return None, error


# ======================================================================================
# CSV tables: a generator of valid files and of single, located mutations
# ======================================================================================

_NAME_CHARS = st.characters(blacklist_categories=("Cs",), blacklist_characters="\r\n")
# Column names as a user may write them: any text without line breaks or surrounding white
# space (header cells are stripped by the reader, so " a" and "a" are the same column).
NAMES = st.text(_NAME_CHARS, min_size=1, max_size=6).filter(lambda s: s == s.strip())
FINITE = st.floats(allow_nan=False, allow_infinity=False)
NEWLINES = st.sampled_from(["\n", "\r\n", "\r"])
BLANKS = st.sampled_from(["", "   ", "\t"])


@dataclass
class Table:
    """A CSV file as a list of lines; each line is a list of cells, or a blank string."""

    lines: list           # list[list[str] | str]
    names: list            # column names after "t" (pose/joint names, plus "enable")
    t: np.ndarray
    values: np.ndarray     # (N, len(names)) as floats
    dt: float
    newline: str
    final_newline: bool

    def header_index(self) -> int:
        return next(i for i, line in enumerate(self.lines) if isinstance(line, list))

    def data_indices(self) -> list[int]:
        rows = [i for i, line in enumerate(self.lines) if isinstance(line, list)]
        return rows[1:]

    def render(self) -> str:
        out = io.StringIO()
        for line in self.lines:
            if isinstance(line, list):
                writer = csv.writer(out, lineterminator="")
                writer.writerow(line)
            else:
                out.write(line)
            out.write(self.newline)
        text = out.getvalue()
        return text if self.final_newline else text[: -len(self.newline)]


@st.composite
def tables(draw, *, enable_column: str = "never", min_rows: int = 2, max_rows: int = 10,
           reserved=("t", "sent_t"), max_abs: float = 1e6):
    """Valid ``t,<names...>[,enable]`` tables with uniform time, repr floats, and harmless
    formatting noise (CRLF/CR/LF, blank lines, white space around cells)."""
    n = draw(st.integers(1, 4))
    names = draw(st.lists(NAMES.filter(lambda s: s not in reserved), min_size=n, max_size=n,
                          unique=True))
    rows = draw(st.integers(min_rows, max_rows))
    dt = draw(st.floats(1e-3, 1e3))
    k0 = draw(st.integers(-1000, 1000))
    t = (k0 + np.arange(rows)) * dt
    value = st.floats(-max_abs, max_abs, allow_nan=False, allow_infinity=False)
    values = np.array(draw(st.lists(st.lists(value, min_size=n, max_size=n),
                                    min_size=rows, max_size=rows)), dtype=float)
    has_enable = enable_column == "always" or (enable_column == "maybe" and draw(st.booleans()))
    pad = st.sampled_from(["", " ", "\t"])
    header = ["t", *names] + (["enable"] if has_enable else [])
    header = [draw(pad) + cell + draw(pad) for cell in header]
    lines: list = [header]
    enable_values = []
    for k in range(rows):
        cells = [repr(float(t[k]))] + [repr(float(v)) for v in values[k]]
        if has_enable:
            flag = draw(st.booleans())
            enable_values.append(flag)
            cells.append(draw(st.sampled_from(["1", "1.0", " 1", "1e0"] if flag
                                              else ["0", "0.0", "-0", "0e3 "])))
        cells = [draw(pad) + cell + draw(pad) if draw(st.booleans()) else cell
                 for cell in cells]
        lines.append(cells)
    # Blank lines anywhere (also before the header); they keep their line numbers.
    for _ in range(draw(st.integers(0, 3))):
        lines.insert(draw(st.integers(0, len(lines))), draw(BLANKS))
    all_names = list(names) + (["enable"] if has_enable else [])
    if has_enable:
        values = np.column_stack([values, np.array(enable_values, dtype=float)])
    return Table(lines=lines, names=all_names, t=t, values=values, dt=float(dt),
                 newline=draw(NEWLINES), final_newline=draw(st.booleans()))


BAD_TOKENS = st.one_of(
    st.sampled_from(["", " ", "nan", "NaN", "-nan", "inf", "-Infinity", "1e309", "-1e400",
                     "1" * 400, "1.2.3", "abc", "0x10", "--1", "1e", "∞", "½", "1 2", "TRUE",
                     "\x00", "1\x00"]),
    st.text(st.characters(blacklist_categories=("Cs",), blacklist_characters=',"\r\n'),
            max_size=8),
).filter(lambda s: not _is_finite_number(s))

MUTATIONS = ["bad_cell", "short_row", "long_row", "first_header", "duplicate_name",
             "empty_name", "too_few_rows", "not_increasing", "not_uniform", "empty_file",
             "bom"]


def mutate(draw, table: Table, kind: str, *, reader: str):
    """Applies one mutation in place; returns the fragments the error message must hold."""
    header_at = table.header_index()
    header = table.lines[header_at]
    names = [cell.strip() for cell in header]
    data_at = table.data_indices()
    if kind == "bad_cell":
        row = draw(st.sampled_from(data_at))
        col = draw(st.integers(0, len(header) - 1))
        token = draw(BAD_TOKENS)
        table.lines[row][col] = token
        return [f"line {row + 1}", f"column {names[col]!r}", quote(token.strip(ASCII_BLANKS))]
    if kind in ("short_row", "long_row"):
        row = draw(st.sampled_from(data_at))
        if kind == "short_row":
            del table.lines[row][draw(st.integers(0, len(header) - 1))]
        else:
            table.lines[row].insert(draw(st.integers(0, len(header))), draw(st.sampled_from(
                ["0", "", "1.5", "x"])))
        return [f"line {row + 1} has {len(table.lines[row])} value(s)",
                f"the header has {len(header)}"]
    if kind == "first_header":
        new = draw(st.one_of(st.sampled_from(["", "T", "time", "t_s", "tt", "'t'"]), NAMES)
                   .filter(lambda s: s.strip() != "t"))
        header[0] = new
        return ["first header column is", repr(new.strip())]
    if kind == "duplicate_name":
        if len(names) < 3:   # t + one column: duplicate that column
            header.append(names[1])
            for row in data_at:
                table.lines[row].append("0")
            dup = names[1]
        else:
            i, j = sorted(draw(st.lists(st.integers(1, len(names) - 1), min_size=2,
                                        max_size=2, unique=True)))
            header[j] = header[i]
            dup = names[i]
        return ["duplicate", repr(dup)]
    if kind == "empty_name":
        j = draw(st.integers(1, len(names) - 1))
        header[j] = draw(BLANKS)
        return [f"column {j if reader == 'joint' else j + 1} has an empty name"]
    if kind == "too_few_rows":
        keep = draw(st.integers(0, 1))
        for row in sorted(data_at[keep:], reverse=True):
            del table.lines[row]
        return [f"{keep} data row(s); at least 2 are needed"]
    if kind == "not_increasing":
        k = draw(st.integers(1, len(data_at) - 1))
        earlier = float(table.t[k - 1])
        new_t = draw(st.sampled_from([earlier, earlier - table.dt, earlier - 1e-9 * table.dt]))
        table.lines[data_at[k]][0] = repr(new_t)
        return ["time must increase", f"data row {k + 1}"]
    if kind == "not_uniform":
        assume(len(data_at) >= 3)
        k = draw(st.integers(1, len(data_at) - 1))
        delta = draw(st.floats(1e-4, 0.45)) * draw(st.sampled_from([1.0, -1.0]))
        table.lines[data_at[k]][0] = repr(float(table.t[k] + delta * table.dt))
        return ["time step must be uniform"]
    if kind == "empty_file":
        table.lines = [draw(BLANKS) for _ in range(draw(st.integers(0, 3)))]
        return ["the file is empty"]
    if kind == "bom":
        header[0] = "\ufeff" + header[0].lstrip()
        return ["first header column is", repr("\ufeff" + names[0])]
    raise AssertionError(kind)


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


# ======================================================================================
# Haptic recordings: CSV and NPZ
# ======================================================================================

HAPTIC_MUTATIONS = MUTATIONS + ["enable_value", "enable_not_last", "expected_names"]


@fuzz(120)
@given(table=tables(enable_column="maybe", reserved=("t", "enable"), max_abs=math.inf))
def test_haptic_csv_valid_tables_round_trip_exactly(work_dir, table):
    path = _write(work_dir, table.render())
    result, error = _read_or_error(read_haptic_csv, path)
    assert error is None, f"valid file refused: {type(error).__name__}: {error}"
    has_enable = table.names[-1] == "enable"
    pose_names = table.names[:-1] if has_enable else table.names
    assert result.pose_names == tuple(pose_names)
    assert _same_floats(result.t_s, table.t)
    assert _same_floats(result.pose, table.values[:, :len(pose_names)])
    expected_enable = (table.values[:, -1] == 1.0) if has_enable else np.ones(len(table.t), bool)
    np.testing.assert_array_equal(result.enable, expected_enable)
    again, error = _read_or_error(read_haptic_csv, path, expected_pose_names=pose_names)
    assert error is None and again.pose_names == tuple(pose_names)


@fuzz(200)
@given(data=st.data(), table=tables(enable_column="maybe", reserved=("t", "enable"),
                                    max_abs=math.inf),
       kind=st.sampled_from(HAPTIC_MUTATIONS))
def test_haptic_csv_every_single_fault_is_a_located_value_error(work_dir, data, table, kind):
    has_enable = table.names[-1] == "enable"
    kwargs = {}
    if kind == "enable_value":
        assume(has_enable)
        row = data.draw(st.sampled_from(table.data_indices()))
        token = data.draw(st.one_of(
            st.sampled_from(["2", "-1", "0.5", "1.0000001", "1e-300", "True", "yes", "",
                             "nan", "inf"]), BAD_TOKENS))
        table.lines[row][-1] = token
        fragments = [f"line {row + 1}", "column 'enable'", quote(token.strip(ASCII_BLANKS))]
    elif kind == "enable_not_last":
        header = table.lines[table.header_index()]
        assume(len(header) >= 3)
        j = data.draw(st.integers(1, len(header) - 2))
        header[j] = "enable"
        if has_enable:
            header[-1] = "enable2"
        fragments = ["'enable' column must be the last"]
    elif kind == "expected_names":
        pose = table.names[:-1] if has_enable else table.names
        other = data.draw(st.one_of(
            st.just(pose[::-1]), st.just(pose[:-1]), st.just([*pose, "extra_m"]),
            st.lists(NAMES, min_size=1, max_size=4, unique=True)))
        assume(list(other) != list(pose))
        kwargs["expected_pose_names"] = other
        fragments = ["expected"]
    else:
        fragments = mutate(data.draw, table, kind, reader="haptic")
        if kind == "duplicate_name":
            fragments = ["duplicate column", fragments[1]]
    path = _write(work_dir, table.render())
    result, error = _read_or_error(read_haptic_csv, path, **kwargs)
    assert error is not None, f"{kind}: bad file accepted: {table.render()!r}"
    _assert_clear_error(error, path, *fragments)


@fuzz(200)
@given(blob=st.one_of(st.binary(max_size=300), st.text(max_size=200).map(str.encode)))
def test_haptic_csv_arbitrary_input_parses_or_gives_a_value_error(work_dir, blob):
    path = _write(work_dir, blob)
    result, error = _read_or_error(read_haptic_csv, path)
    if error is not None:
        assert isinstance(error, ValueError), f"{type(error).__name__}: {error}"
        return
    assert isinstance(result, HapticRecording)
    assert np.all(np.isfinite(result.t_s)) and np.all(np.isfinite(result.pose))


# --- NPZ ---


@st.composite
def recordings(draw):
    table = draw(tables(enable_column="always", reserved=("t", "enable"), max_abs=math.inf))
    # NumPy's str arrays drop trailing NULs (np.array(['a\x00']) == ['a']): not our bug.
    assume(not any(name.endswith("\x00") for name in table.names))
    pose = table.values[:, :-1]
    return HapticRecording(t_s=table.t, pose=pose, enable=table.values[:, -1] == 1.0,
                           pose_names=tuple(table.names[:-1]))


def _npz_bytes(**arrays) -> bytes:
    buffer = io.BytesIO()
    np.savez(buffer, **arrays)
    return buffer.getvalue()


GOOD_NPZ = dict(t_s=np.arange(4) * 0.01, pose=np.zeros((4, 3)),
                pose_names=np.array(["x_m", "y_m", "phi_rad"]), enable=np.ones(4, dtype=bool))
NPZ_DTYPES = st.one_of(hnp.boolean_dtypes(), hnp.integer_dtypes(), hnp.unsigned_integer_dtypes(),
                       hnp.floating_dtypes(), hnp.complex_number_dtypes(),
                       hnp.unicode_string_dtypes(), hnp.byte_string_dtypes(),
                       hnp.datetime64_dtypes(), hnp.timedelta64_dtypes())


@fuzz(40)
@given(recording=recordings(), compressed=st.booleans())
def test_haptic_npz_round_trip_is_exact(work_dir, recording, compressed):
    path = work_dir / "fuzz.npz"
    if compressed:
        np.savez_compressed(path, t_s=recording.t_s, pose=recording.pose,
                            enable=recording.enable, pose_names=np.array(recording.pose_names))
    else:
        write_haptic_npz(path, recording)
    result, error = _read_or_error(read_haptic_npz, path,
                                   expected_pose_names=recording.pose_names)
    assert error is None, f"{type(error).__name__}: {error}"
    assert result.pose_names == recording.pose_names
    assert _same_floats(result.t_s, recording.t_s) and _same_floats(result.pose, recording.pose)
    np.testing.assert_array_equal(result.enable, recording.enable)


@fuzz(150)
@given(key=st.sampled_from(list(GOOD_NPZ) + ["extra"]), dtype=NPZ_DTYPES,
       shape=st.one_of(st.just(None), hnp.array_shapes(min_dims=0, max_dims=3, min_side=0,
                                                       max_side=5)),
       drop=st.booleans(), data=st.data())
def test_haptic_npz_any_array_raises_only_value_errors(work_dir, key, dtype, shape, drop, data):
    arrays = dict(GOOD_NPZ)
    if drop and key in arrays:
        del arrays[key]
    else:
        shape = GOOD_NPZ[key].shape if shape is None and key in GOOD_NPZ else (shape or ())
        arrays[key] = data.draw(hnp.arrays(dtype, shape))
    path = _write(work_dir, _npz_bytes(**arrays), "fuzz.npz")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result, error = _read_or_error(read_haptic_npz, path)
    if error is not None:
        _assert_clear_error(error, path)
    else:
        assert np.all(np.isfinite(result.t_s)) and np.all(np.isfinite(result.pose))


@fuzz(200)
@given(blob=st.one_of(
    st.binary(max_size=400),
    st.builds(lambda head, tail: b"PK\x03\x04" + head + tail, st.binary(max_size=60),
              st.binary(max_size=60)),
    st.builds(lambda tail: b"\x93NUMPY\x01\x00" + tail, st.binary(max_size=80)),
    # A valid NPZ cut short.
    st.integers(0, 1211).map(lambda cut: _npz_bytes(**GOOD_NPZ)[:cut]),
))
def test_haptic_npz_garbage_bytes_give_a_value_error(work_dir, blob):
    path = _write(work_dir, blob, "fuzz.npz")
    result, error = _read_or_error(read_haptic_npz, path)
    if error is not None:
        _assert_clear_error(error, path)


def _corrupt(data: bytes, at: int, xor: int) -> bytes:
    data = bytearray(data)
    data[at % len(data)] ^= xor
    return bytes(data)


# --- NPZ regressions ---


# Regression (fixed): datasets/haptic_recording.py read_haptic_npz uses `with np.load(...) as
# archive`; given a .npy file (np.save(path, np.arange(3.0))), np.load returns an ndarray and
# the reader raises TypeError("'numpy.ndarray' object does not support the context manager
# protocol"); expected ValueError('<path>: cannot read as NPZ ...').
@fuzz(20)
@example(values=[0.0, 1.0, 2.0])
@given(values=st.lists(FINITE, max_size=5))
def test_haptic_npz_given_a_npy_file_is_a_value_error(work_dir, values):
    buffer = io.BytesIO()
    np.save(buffer, np.array(values))
    path = _write(work_dir, buffer.getvalue(), "fuzz.npz")
    result, error = _read_or_error(read_haptic_npz, path)
    _assert_clear_error(error, path, "cannot read as NPZ", ".npy")


# Regression (fixed): datasets/haptic_recording.py read_haptic_npz: a zip whose members are not
# .npy arrays (members 't_s', 'pose', 'pose_names' holding e.g. b'hello') loads as raw bytes and
# the reader raises AttributeError("'bytes' object has no attribute 'ndim'"); expected
# ValueError naming the file and the member.
@fuzz(20)
@example(payload=b"hello", suffix="")
@given(payload=st.binary(max_size=20), suffix=st.sampled_from(["", ".txt", ".bin"]))
def test_haptic_npz_non_array_members_are_a_value_error(work_dir, payload, suffix):
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w") as archive:
        for key in ("t_s", "pose", "pose_names"):
            archive.writestr(key + suffix, payload)
    path = _write(work_dir, buffer.getvalue(), "fuzz.npz")
    result, error = _read_or_error(read_haptic_npz, path)
    _assert_clear_error(error, path, f"archive member 't_s{suffix}' is not a .npy array")


def _good_npz(compressed: bool) -> bytes:
    buffer = io.BytesIO()
    (np.savez_compressed if compressed else np.savez)(buffer, **GOOD_NPZ)
    return buffer.getvalue()


# Regression (fixed): datasets/haptic_recording.py read_haptic_npz catches only OSError,
# BadZipFile, EOFError and ValueError, but a damaged archive also raises zlib.error,
# NotImplementedError and RuntimeError: in np.savez_compressed(GOOD_NPZ) xor-ing byte 63 with
# 0xff (inside a deflate stream) gives zlib.error('Error -3 while decompressing data: invalid
# distance too far back'); in np.savez(GOOD_NPZ) byte 977 ^ 1 (compression method of a local
# header) gives NotImplementedError('That compression method is not supported') and byte 975 ^ 1
# (encryption flag) gives RuntimeError("File 't_s.npy' is encrypted, password required for
# extraction"). Expected ValueError('<path>: cannot read as NPZ ...').
@fuzz(120)
@example(compressed=True, at=63, xor=0xFF)
@example(compressed=False, at=977, xor=1)
@example(compressed=False, at=975, xor=1)
@given(compressed=st.booleans(), at=st.integers(0, 1300), xor=st.integers(1, 255))
def test_haptic_npz_damaged_archive_is_a_value_error(work_dir, compressed, at, xor):
    path = _write(work_dir, _corrupt(_good_npz(compressed), at, xor), "fuzz.npz")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result, error = _read_or_error(read_haptic_npz, path)
    if error is not None:
        _assert_clear_error(error, path)
    else:   # the damage missed everything that matters: the data are intact
        assert _same_floats(result.t_s, GOOD_NPZ["t_s"])
        assert _same_floats(result.pose, GOOD_NPZ["pose"])


# Regression (fixed): datasets/haptic_recording.py HapticRecording.__post_init__ converts with
# np.array(..., dtype=float), which silently drops imaginary parts (ComplexWarning only): an NPZ
# whose pose (or t_s) is complex, e.g. pose=[[1+2j],[3+0j],...], is accepted as
# pose=[[1],[3],...]; expected a ValueError naming the array and its dtype.
@fuzz(30)
@example(key="pose", imag=2.0)
@given(key=st.sampled_from(["pose", "t_s"]), imag=FINITE.filter(lambda v: v != 0))
def test_haptic_npz_complex_arrays_are_not_truncated(work_dir, key, imag):
    arrays = {k: v.copy() for k, v in GOOD_NPZ.items()}
    arrays[key] = arrays[key].astype(complex)
    arrays[key].flat[0] += 1j * imag
    path = _write(work_dir, _npz_bytes(**arrays), "fuzz.npz")
    with warnings.catch_warnings():
        warnings.simplefilter("error")   # no ComplexWarning either: refused before converting
        result, error = _read_or_error(read_haptic_npz, path)
    _assert_clear_error(error, path, f"{key} has dtype complex")


# Regression (fixed): datasets/haptic_recording.py HapticRecording.__post_init__: a t_s or pose
# array of non-numeric strings (e.g. t_s=np.array(['a', 'b', 'c', 'd'])) raises "<path>: could
# not convert string to float: np.str_('a')", naming neither the array nor the sample; expected
# e.g. "t_s has dtype <U1; expected numbers".
@fuzz(30)
@example(key="t_s", text="a")
@given(key=st.sampled_from(["t_s", "pose"]),
       text=st.text(max_size=4).filter(lambda s: not _is_finite_number(s)))
def test_haptic_npz_string_arrays_error_names_the_array(work_dir, key, text):
    arrays = dict(GOOD_NPZ)
    arrays[key] = np.full(GOOD_NPZ[key].shape, text)
    path = _write(work_dir, _npz_bytes(**arrays), "fuzz.npz")
    result, error = _read_or_error(read_haptic_npz, path)
    _assert_clear_error(error, path, f"{key} has dtype <U", "expected real numbers")


# ======================================================================================
# LCM decoding
# ======================================================================================

LCM_TYPES = (lcmt_onboard_joint_status, lcmt_teleop_collision_event,
             lcmt_teleop_haptic_command, lcmt_teleop_joint_command)
DECODE_ERRORS = (ValueError, struct.error)
"""What the lcm-gen 1.5.3 Python decoders raise: ValueError('Decode error') for a wrong
fingerprint (8 first bytes), struct.error for a short body or a negative array length."""

INT64 = st.integers(-2**63, 2**63 - 1)
INT32 = st.integers(-2**31, 2**31 - 1)
DOUBLES = st.floats(allow_nan=True, allow_infinity=True)
LCM_STRINGS = st.text(st.characters(blacklist_categories=("Cs",)), max_size=8)


@st.composite
def lcm_messages(draw, lcm_type=None):
    lcm_type = lcm_type or draw(st.sampled_from(LCM_TYPES))
    msg = lcm_type()
    n = draw(st.integers(0, 6))
    if lcm_type is lcmt_teleop_joint_command:
        msg.utime, msg.seq, msg.sample_utime = draw(INT64), draw(INT32), draw(INT64)
        msg.num_joints = n
        msg.joint_name = draw(st.lists(LCM_STRINGS, min_size=n, max_size=n))
        msg.joint_position_smoothed = draw(st.lists(DOUBLES, min_size=n, max_size=n))
        msg.joint_velocity_smoothed = draw(st.lists(DOUBLES, min_size=n, max_size=n))
        msg.mode = draw(st.integers(-128, 127))
        msg.session_id = draw(INT64)
        msg.auth_tag = draw(st.binary(max_size=40))
        msg.auth_tag_size = len(msg.auth_tag)
    elif lcm_type is lcmt_teleop_haptic_command:
        msg.utime, msg.seq, msg.num_axes = draw(INT64), draw(INT32), n
        msg.pose_desired = draw(st.lists(DOUBLES, min_size=n, max_size=n))
        msg.enable = draw(st.booleans())
    elif lcm_type is lcmt_onboard_joint_status:
        msg.utime, msg.seq, msg.num_joints = draw(INT64), draw(INT32), n
        msg.joint_position_link = draw(st.lists(DOUBLES, min_size=n, max_size=n))
        msg.joint_position_motor = draw(st.lists(DOUBLES, min_size=n, max_size=n))
        msg.tool_position_measured = draw(st.lists(DOUBLES, min_size=3, max_size=3))
        msg.last_command_seq = draw(INT32)
        msg.command_rejected, msg.command_timeout = draw(st.booleans()), draw(st.booleans())
        msg.last_command_session_id = draw(INT64)
        msg.joint_position_commanded = draw(st.lists(DOUBLES, min_size=n, max_size=n))
        msg.guard_mode = draw(st.integers(-128, 127))
        (msg.accepted_count, msg.rejected_invalid_count, msg.rejected_auth_count,
         msg.dropped_duplicate_count, msg.dropped_stale_count,
         msg.undecodable_count) = (draw(INT32) for _ in range(6))
    else:
        msg.utime, msg.seq = draw(INT64), draw(INT32)
        msg.collision_detected, msg.holding = draw(st.booleans()), draw(st.booleans())
        msg.min_distance_m = draw(DOUBLES)
    return msg


def _decode(lcm_type, data: bytes):
    """Decodes as the receivers do (``decode_exact``); returns the message or the exception
    (which must be a DECODE_ERROR), and checks that decoding is quick (no hang on absurd
    lengths)."""
    start = time.perf_counter()
    try:
        result = decode_exact(lcm_type, data)
    except DECODE_ERRORS as error:
        result = error
    assert time.perf_counter() - start < 1.0, "decode took more than 1 s"
    return result


@fuzz(200)
@given(msg=lcm_messages())
def test_lcm_valid_messages_round_trip_bit_exactly(msg):
    data = msg.encode()
    decoded = type(msg).decode(data)
    assert decoded.encode() == data


@fuzz(200)
@given(lcm_type=st.sampled_from(LCM_TYPES), blob=st.binary(max_size=200))
def test_lcm_random_bytes_raise_decode_error(lcm_type, blob):
    assume(blob[:8] != lcm_type._get_packed_fingerprint())
    with pytest.raises(ValueError, match="^Decode error$") as info:
        lcm_type.decode(blob)
    assert type(info.value) is ValueError


@fuzz(300)
@given(lcm_type=st.sampled_from(LCM_TYPES), body=st.one_of(
    st.binary(max_size=200),
    # Headers with extreme counts/lengths, to look for hangs or huge allocations.
    st.builds(lambda head, count, tail: head + struct.pack(">i", count) + tail,
              st.binary(min_size=12, max_size=20), st.sampled_from([-1, -2**31, 2**31 - 1,
                                                                    2**30, 7]),
              st.binary(max_size=40)),
))
def test_lcm_fingerprint_then_garbage_raises_only_decode_errors(lcm_type, body):
    _decode(lcm_type, lcm_type._get_packed_fingerprint() + body)


@fuzz(150)
@given(msg=lcm_messages(), data=st.data())
def test_lcm_every_truncation_is_refused(msg, data):
    encoded = msg.encode()
    cut = data.draw(st.integers(0, len(encoded) - 1))
    result = _decode(type(msg), encoded[:cut])
    assert isinstance(result, DECODE_ERRORS), f"a {cut}/{len(encoded)}-byte prefix decoded"


@fuzz(300)
@given(msg=lcm_messages(), data=st.data())
def test_lcm_bit_flips_decode_or_raise_decode_errors(msg, data):
    encoded = bytearray(msg.encode())
    flips = data.draw(st.lists(st.integers(0, 8 * len(encoded) - 1), min_size=1, max_size=4))
    for bit in flips:
        encoded[bit // 8] ^= 1 << (bit % 8)
    result = _decode(type(msg), bytes(encoded))
    if bytes(encoded[:8]) != type(msg)._get_packed_fingerprint():
        assert type(result) is ValueError and str(result) == "Decode error"


# ======================================================================================
# Onboard JointCommandReceiver against an independent model
# ======================================================================================

JOINT_POOL = ("shoulder", "elbow", "wrist", "Joint 4")


def _default_joint_command(msg) -> bool:
    """Equal to lcmt_teleop_joint_command() (compared through vars: some messages here
    cannot be encoded)."""
    default = lcmt_teleop_joint_command()
    def plain(value):   # decoded arrays are tuples, constructed ones lists
        return list(value) if isinstance(value, (list, tuple)) else value
    return all(plain(getattr(msg, name)) == plain(getattr(default, name))
               for name in default.__slots__)


class JointReceiverModel:
    """What the receiver's docstrings promise, written without looking at its state layout.

    A packet is examined if it is not the default message, has seq ≥ 0 and its
    (session_id, seq) is newer than the last accepted one's (any before the first), once (the
    same pair held again is not examined again). It is fresh (telesmooth.link.session's
    rule, in process: epoch 0) if it carries epoch 0 and, against the last accepted
    (s₀, q₀) ((0, −1) before the first), its session s is s₀ with seq > q₀, or its counter
    (the high bits above the 32-bit nonce) is counter(s₀) + 1. A packet of an earlier session
    or seq is stale or a duplicate (ignored); a wrong epoch or a session that skips ahead is
    refused (flagged). A fresh packet is accepted if it names exactly the robot's joints in
    order, with one finite position per joint inside [lower, upper]; then it becomes the
    command and clears the rejected flag. Otherwise the flag is raised and the command holds.
    Timeout: more than ``timeout_s`` since the last accepted packet (from t = 0 before any).
    """

    def __init__(self, names, lower, upper, q0, timeout_s):
        self.names, self.lower, self.upper = tuple(names), list(lower), list(upper)
        self.timeout_s = timeout_s
        self.q = list(q0)
        # "last_command_seq: −1 before the first" and "seq ≤ last are ignored".
        self.last_seq, self.last_time, self.rejected, self.examined = -1, 0.0, False, None
        self.last_pair = (0, -1)
        self.timeout = False

    def acceptable(self, msg) -> bool:
        positions = list(msg.joint_position_smoothed)
        return (msg.num_joints == len(self.names) and len(positions) == len(self.names)
                and tuple(msg.joint_name) == self.names
                and all(math.isfinite(v) and lo <= v <= hi
                        for v, lo, hi in zip(positions, self.lower, self.upper)))

    def freshness(self, msg) -> str:
        """"fresh", "old" (stale or duplicate: ignored) or "refused" (flagged)."""
        if int(msg.onboard_epoch) != 0:
            return "refused"
        session, seq = int(msg.session_id), int(msg.seq)
        last_session, last_seq = self.last_pair
        if session == last_session:
            return "fresh" if seq > last_seq else "old"
        counter, last_counter = session // 2**32, last_session // 2**32
        if counter == last_counter + 1:
            return "fresh"
        return "old" if counter <= last_counter else "refused"

    def poll(self, msg, now):
        # The subscriber's default message is not a packet; any other one (even with an
        # empty joint list) is examined once.
        pair = None if msg is None else (msg.session_id, msg.seq)
        newer = self.last_seq < 0 or pair > self.last_pair
        if msg is not None and not _default_joint_command(msg) and msg.seq >= 0 and newer \
                and pair != self.examined:
            self.examined = pair
            fresh = self.freshness(msg)
            if fresh == "fresh" and self.acceptable(msg):
                self.q = [float(v) for v in msg.joint_position_smoothed]
                self.last_seq, self.last_time, self.rejected = msg.seq, now, False
                self.last_pair = (int(msg.session_id), int(msg.seq))
            elif fresh != "old":
                self.rejected = True
        self.timeout = now - self.last_time > self.timeout_s


def _joint_command(seq, names, positions, velocities=None, *, num_joints=None, utime=0):
    msg = lcmt_teleop_joint_command()
    msg.seq, msg.utime, msg.sample_utime = seq, utime, utime
    msg.num_joints = len(positions) if num_joints is None else num_joints
    msg.joint_name = list(names)
    msg.joint_position_smoothed = list(positions)
    msg.joint_velocity_smoothed = list(velocities if velocities is not None
                                       else [0.0] * len(positions))
    return msg


def _over_the_wire(msg):
    """What the subscriber would hand over: decode(encode(msg))."""
    return type(msg).decode(msg.encode())


@st.composite
def joint_receiver_setups(draw):
    n = draw(st.integers(1, 4))
    lower = [draw(st.floats(-4.0, -1e-3)) for _ in range(n)]
    upper = [draw(st.floats(1e-3, 4.0)) for _ in range(n)]
    q0 = [draw(st.floats(lo, hi)) for lo, hi in zip(lower, upper)]
    timeout = draw(st.sampled_from([0.05, 0.3, 1.0]))
    return JOINT_POOL[:n], lower, upper, q0, timeout


JOINT_KINDS = ["valid", "valid", "valid", "count", "names", "nonfinite", "limits", "mismatch",
               "empty", "corrupt", "velocity_nan", "poll"]
INT32_MIN, INT32_MAX = -2**31, 2**31 - 1


def _draw_seq(draw, model):
    last = model.last_seq
    choice = draw(st.sampled_from(["next", "next", "jump", "dup", "stale", "examined", "any"]))
    if choice == "next":
        seq = last + 1
    elif choice == "jump":
        seq = last + draw(st.integers(2, 50))
    elif choice == "dup":
        seq = last
    elif choice == "stale":
        seq = last - draw(st.integers(1, 50))
    elif choice == "examined":
        seq = model.examined[1] if model.examined is not None else last + 1
    else:
        seq = draw(st.one_of(INT32, st.sampled_from([INT32_MIN, INT32_MAX, 0, -1])))
    return min(max(seq, INT32_MIN), INT32_MAX)


def _draw_joint_message(draw, kind, model):
    names, lower, upper = list(model.names), model.lower, model.upper
    n = len(names)
    seq = _draw_seq(draw, model)
    valid_q = [draw(st.one_of(st.floats(lo, hi), st.sampled_from([lo, hi])))
               for lo, hi in zip(lower, upper)]
    if kind == "valid":
        return _over_the_wire(_joint_command(seq, names, valid_q))
    if kind == "velocity_nan":   # velocities are not checked; positions are valid
        return _over_the_wire(_joint_command(seq, names, valid_q, [math.nan] * n))
    if kind == "count":
        m = draw(st.sampled_from([k for k in range(1, n + 3) if k != n]))
        extra = [f"extra{k}" for k in range(max(0, m - n))]
        q = (valid_q + [0.0] * m)[:m]
        return _over_the_wire(_joint_command(seq, (names + extra)[:m], q))
    if kind == "names":
        variants = [[*names[:-1], names[-1].upper()], [*names[:-1], names[-1] + " "],
                    [*names[:-1], ""], [*names[:-1], "other"]]
        if n > 1:
            variants.append(names[::-1])
        return _over_the_wire(_joint_command(seq, draw(st.sampled_from(variants)), valid_q))
    if kind == "nonfinite":
        q = list(valid_q)
        q[draw(st.integers(0, n - 1))] = draw(st.sampled_from([math.nan, math.inf, -math.inf]))
        return _over_the_wire(_joint_command(seq, names, q))
    if kind == "limits":
        q = list(valid_q)
        j = draw(st.integers(0, n - 1))
        q[j] = draw(st.sampled_from([
            float(np.nextafter(upper[j], math.inf)), float(np.nextafter(lower[j], -math.inf)),
            upper[j] + 1.0, lower[j] - 10.0, 1e308, -1e308, 5e-324 + upper[j] * 2]))
        return _over_the_wire(_joint_command(seq, names, q))
    if kind == "mismatch":   # in-process message whose count disagrees with its arrays
        bad_q = draw(st.sampled_from([valid_q[:-1], valid_q + [0.0]]))
        return _joint_command(seq, names, bad_q, [0.0] * len(bad_q), num_joints=n)
    if kind == "empty":      # an empty joint list: documented as not examined
        return _over_the_wire(_joint_command(seq, [], []))
    if kind == "corrupt":    # a damaged valid packet that still decodes
        encoded = bytearray(_joint_command(seq, names, valid_q).encode())
        for bit in draw(st.lists(st.integers(64, 8 * len(encoded) - 1), min_size=1,
                                 max_size=3)):
            encoded[bit // 8] ^= 1 << (bit % 8)
        try:
            return lcmt_teleop_joint_command.decode(bytes(encoded))
        except DECODE_ERRORS:
            return None
    raise AssertionError(kind)


def _check_joint_outputs(dut, context, model, lower, upper):
    q = np.array(dut.get_q_commanded_output_port().Eval(context))
    assert np.all(np.isfinite(q)), q
    assert np.all(q >= lower) and np.all(q <= upper), (q, lower, upper)
    assert _same_floats(q, model.q), (q, model.q)
    seq = dut.get_last_command_seq_output_port().Eval(context)[0]
    assert seq == model.last_seq
    assert dut.get_command_rejected_output_port().Eval(context)[0] == float(model.rejected)
    assert dut.get_command_timeout_output_port().Eval(context)[0] == float(model.timeout)


@fuzz(80)
@given(setup=joint_receiver_setups(), data=st.data())
def test_joint_command_receiver_holds_last_accepted_and_flags_rejections(setup, data):
    names, lower, upper, q0, timeout = setup
    dut = JointCommandReceiver(JointCommandReceiverConfig(timeout_s=timeout), joint_names=names,
                               lower_rad=lower, upper_rad=upper, initial_position_rad=q0)
    context = dut.CreateDefaultContext()
    port = dut.get_lcm_message_input_port()
    model = JointReceiverModel(names, lower, upper, q0, timeout)
    port.FixValue(context, lcmt_teleop_joint_command())   # what the subscriber gives first
    current = None
    now = 0.0
    for _ in range(data.draw(st.integers(1, 25))):
        now += data.draw(st.sampled_from([0.0, 0.01, 0.04, 0.25, 0.6]))
        kind = data.draw(st.sampled_from(JOINT_KINDS))
        if kind != "poll":
            msg = _draw_joint_message(data.draw, kind, model)
            if msg is not None:
                current = msg
                port.FixValue(context, msg)
        context.SetTime(now)
        dut.CalcForcedUnrestrictedUpdate(context, context.get_mutable_state())
        model.poll(current, now)
        _check_joint_outputs(dut, context, model, lower, upper)


@fuzz(25)
@given(setup=joint_receiver_setups(), data=st.data())
def test_joint_command_receiver_in_a_simulator_with_periodic_polling(setup, data):
    from pydrake.systems.analysis import Simulator

    names, lower, upper, q0, timeout = setup
    dut = JointCommandReceiver(JointCommandReceiverConfig(timeout_s=timeout), joint_names=names,
                               lower_rad=lower, upper_rad=upper, initial_position_rad=q0)
    simulator = Simulator(dut)
    context = simulator.get_mutable_context()
    port = dut.get_lcm_message_input_port()
    port.FixValue(context, lcmt_teleop_joint_command())
    simulator.Initialize()
    model = JointReceiverModel(names, lower, upper, q0, timeout)
    now = 0.0
    for _ in range(data.draw(st.integers(1, 10))):
        kind = data.draw(st.sampled_from([k for k in JOINT_KINDS if k != "poll"]))
        msg = _draw_joint_message(data.draw, kind, model)
        if msg is None:
            continue
        port.FixValue(context, msg)
        now += data.draw(st.sampled_from([0.015, 0.05, 0.3]))   # at least one poll
        simulator.AdvanceTo(now)
        model.poll(msg, now)
        q = np.array(dut.get_q_commanded_output_port().Eval(context))
        assert np.all(np.isfinite(q)) and np.all(q >= lower) and np.all(q <= upper)
        assert _same_floats(q, model.q)
        assert dut.get_last_command_seq_output_port().Eval(context)[0] == model.last_seq
        assert dut.get_command_rejected_output_port().Eval(context)[0] == float(model.rejected)


# ======================================================================================
# Ground HapticCommandReceiver against an independent model
# ======================================================================================


class HapticReceiverModel:
    """The receiver's docstring: a message is new when its utime differs from the previous
    message's; a new message with the arm's number of axes and finite values becomes the pose
    and its clutch; any other new message is rejected (clutch off, pose held). ``enable`` is
    the last valid message's clutch while it is at most ``timeout_s`` old and the newest
    message was not rejected."""

    def __init__(self, pose0, timeout_s):
        self.pose, self.timeout_s = list(pose0), timeout_s
        self.clutch, self.arrived, self.last_utime, self.rejected = False, None, None, False

    def poll(self, msg, now):
        if msg is None or msg.utime == self.last_utime:
            return
        self.last_utime = msg.utime
        pose = list(msg.pose_desired)
        if msg.num_axes == len(self.pose) and len(pose) == len(self.pose) and \
                all(math.isfinite(v) for v in pose):
            self.pose, self.clutch, self.arrived, self.rejected = pose, bool(msg.enable), now, \
                False
        else:
            self.clutch, self.rejected = False, True

    def enable(self, now) -> float:
        fresh = self.arrived is not None and now - self.arrived <= self.timeout_s
        return float(self.clutch and fresh and not self.rejected)


def _haptic_command(utime, pose, enable=True, *, num_axes=None):
    msg = lcmt_teleop_haptic_command()
    msg.utime, msg.num_axes = utime, len(pose) if num_axes is None else num_axes
    msg.pose_desired, msg.enable = list(pose), enable
    return msg


HAPTIC_KINDS = ["valid", "valid", "valid", "count", "nonfinite", "mismatch", "poll", "silence"]


def _run_haptic(dut, context, model, steps):
    """Feeds (dt, msg-or-None, update?) steps; checks outputs against the model."""
    port = dut.get_lcm_message_input_port()
    now = 0.0
    current = None
    for dt, msg, update in steps:
        now += dt
        context.SetTime(now)
        if msg is not None:
            current = msg
            port.FixValue(context, msg)
        if update:
            dut.CalcForcedDiscreteVariableUpdate(context, context.get_mutable_discrete_state())
            model.poll(current, now)
        pose = np.array(dut.get_pose_desired_output_port().Eval(context))
        assert np.all(np.isfinite(pose))
        assert _same_floats(pose, model.pose), (pose, model.pose)
        assert dut.get_enable_output_port().Eval(context)[0] == model.enable(now)
        assert dut.get_message_rejected_output_port().Eval(context)[0] == float(model.rejected)


@fuzz(80)
@given(m=st.integers(1, 6), timeout=st.sampled_from([0.02, 0.1, 0.5]), data=st.data())
def test_haptic_command_receiver_holds_last_valid_pose_and_flags_rejections(m, timeout, data):
    pose0 = data.draw(st.lists(st.floats(-2, 2), min_size=m, max_size=m))
    dut = HapticCommandReceiver(HapticCommandReceiverConfig(timeout_s=timeout),
                                initial_pose=pose0)
    context = dut.CreateDefaultContext()
    dut.get_lcm_message_input_port().FixValue(context, lcmt_teleop_haptic_command())
    model = HapticReceiverModel(pose0, timeout)
    steps = []
    last_utime = 0
    for _ in range(data.draw(st.integers(1, 25))):
        dt = data.draw(st.sampled_from([0.0, 0.005, 0.01, 0.05, 0.2]))
        kind = data.draw(st.sampled_from(HAPTIC_KINDS))
        if kind in ("poll", "silence"):
            steps.append((dt, None, kind == "poll"))
            continue
        utime = data.draw(st.sampled_from(["next", "next", "same", "older", "any"]))
        utime = {"next": last_utime + data.draw(st.integers(1, 20_000)), "same": last_utime,
                 "older": max(0, last_utime - data.draw(st.integers(1, 20_000))),
                 "any": data.draw(st.integers(0, 2**53 - 1))}[utime]
        last_utime = utime
        pose = data.draw(st.lists(FINITE, min_size=m, max_size=m))
        enable = data.draw(st.booleans())
        if kind == "valid":
            msg = _over_the_wire(_haptic_command(utime, pose, enable))
        elif kind == "count":
            k = data.draw(st.sampled_from([c for c in range(1, m + 3) if c != m]))
            msg = _over_the_wire(_haptic_command(utime, (pose + [0.0] * k)[:k], enable))
        elif kind == "nonfinite":
            pose[data.draw(st.integers(0, m - 1))] = data.draw(
                st.sampled_from([math.nan, math.inf, -math.inf]))
            msg = _over_the_wire(_haptic_command(utime, pose, enable))
        else:   # in-process: num_axes disagrees with the array
            msg = _haptic_command(utime, data.draw(st.sampled_from([pose[:-1], pose + [0.0]])),
                                  enable, num_axes=m)
        steps.append((dt, msg, True))
    _run_haptic(dut, context, model, steps)


def _haptic_dut(pose0=(0.7, 0.0, 0.0), timeout=0.1):
    dut = HapticCommandReceiver(HapticCommandReceiverConfig(timeout_s=timeout),
                                initial_pose=list(pose0))
    context = dut.CreateDefaultContext()
    dut.get_lcm_message_input_port().FixValue(context, lcmt_teleop_haptic_command())
    return dut, context, HapticReceiverModel(pose0, timeout)


# Regression (fixed): systems/haptic_command_receiver.py HapticCommandReceiver._update_pose
# treats every message with num_axes <= 0 as 'no message' (is_new requires num_axes > 0), so a
# device message with zero axes is neither rejected nor flagged, contrary to the docstring
# ('message_rejected: 1 if the newest message had the wrong number of axes'): after a valid
# enabled message (utime 1) at t=0.01, a message (utime 2, num_axes 0) at t=0.02 leaves
# message_rejected = 0 and enable = 1 (expected 1 and 0).
@fuzz(30)
@example(utime=2, num_axes=0, dt=0.01)
@given(utime=st.integers(2, 2**53), num_axes=st.sampled_from([0, -1, -5]),
       dt=st.sampled_from([0.0, 0.01, 0.05]))
def test_haptic_receiver_rejects_messages_without_axes(utime, num_axes, dt):
    dut, context, model = _haptic_dut()
    bad = _haptic_command(utime, [], True, num_axes=num_axes)
    _run_haptic(dut, context, model, [(0.01, _haptic_command(1, [0.8, 0.1, 0.2]), True),
                                      (dt, bad, True)])


# Regression (fixed): systems/haptic_command_receiver.py HapticCommandReceiver starts with 'last
# seen utime' = -1.0 as a sentinel, so a first message with utime == -1 (a valid int64 on the
# wire) is taken as already seen and never examined: the pose stays at initial_pose and enable
# stays 0 for as long as that message is the newest (expected: pose = the message's, enable =
# 1).
@fuzz(20)
@example(pose=[0.8, 0.1, 0.2], utime=-1)
@given(pose=st.lists(st.floats(-2, 2), min_size=3, max_size=3),
       utime=st.sampled_from([-1, 0, -2**63, 2**63 - 1]))
def test_haptic_receiver_accepts_a_first_message_with_utime_minus_one(pose, utime):
    # Any int64 utime, also 0 (only the default-constructed message means "nothing yet").
    dut, context, model = _haptic_dut()
    _run_haptic(dut, context, model, [(0.0, None, True),
                                      (0.01, _haptic_command(utime, pose), True),
                                      (0.01, None, True)])
    assert dut.get_enable_output_port().Eval(context)[0] == 1.0


# Regression (fixed): systems/haptic_command_receiver.py keeps the last seen utime in a float64
# discrete state and compares with numpy, so distinct int64 utimes above 2**53 that round to the
# same double are taken as the same message: after utime 2**53 is accepted, a new message with
# utime 2**53 + 1 (other pose) is ignored, the pose is stale and the clutch times out.
@fuzz(20)
@example(base=2**53, offset=1)
@given(base=st.sampled_from([2**53, 2**62 + 1, -2**63, 2**63 - 2**11, -2**53 - 2]),
       offset=st.integers(1, 2**10))
def test_haptic_receiver_distinguishes_large_utimes(base, offset):
    dut, context, model = _haptic_dut()
    _run_haptic(dut, context, model, [
        (0.01, _over_the_wire(_haptic_command(base, [0.8, 0.1, 0.2])), True),
        (0.01, _over_the_wire(_haptic_command(base + offset, [0.9, 0.1, 0.2])), True),
        (0.01, _over_the_wire(_haptic_command(base, [0.7, 0.1, 0.2])), True)])
    np.testing.assert_array_equal(dut.get_pose_desired_output_port().Eval(context),
                                  [0.7, 0.1, 0.2])


# ======================================================================================
# The live path: bytes on the LCM channel -> subscriber -> receiver (a whole process)
# ======================================================================================


# Regression (fixed): diagrams/teleoperation.py MakeOnboardDiagram (and AddOperatorTargets for
# the live haptic device) connect a plain LcmSubscriberSystem, which decodes inside the
# simulator's event handling; one malformed packet on TELEOP_JOINT_COMMAND (e.g. b'garbage' ->
# ValueError('Decode error'), or a truncated valid packet -> struct.error) makes every later
# Simulator.AdvanceTo raise, i.e. the onboard process dies (exit 2, or a traceback for
# struct.error) instead of holding the last accepted command and raising command_rejected. The
# same holds for TELEOP_HAPTIC_COMMAND in the ground process.
@fuzz(15)
@example(kind="joint", payload=b"garbage")
@example(kind="haptic", payload=b"")
@given(kind=st.sampled_from(["joint", "haptic"]),
       payload=st.one_of(st.binary(max_size=40), st.sampled_from([b"", b"garbage"])))
def test_malformed_packets_on_the_channel_do_not_stop_the_receiver(kind, payload):
    # The process diagrams themselves: onboard (TELEOP_JOINT_COMMAND) and a ground station
    # with a live haptic device (TELEOP_HAPTIC_COMMAND), on a private memq:// bus.
    from pydrake.lcm import DrakeLcm
    from pydrake.systems.analysis import Simulator

    from telesmooth.diagrams.scenario import load_scenario
    from telesmooth.diagrams.teleoperation import MakeGroundDiagram, MakeOnboardDiagram

    lcm = DrakeLcm("memq://")
    if kind == "joint":
        lcm_type, channel = lcmt_teleop_joint_command, "TELEOP_JOINT_COMMAND"
        handles = MakeOnboardDiagram(load_scenario(), lcm=lcm)
        receiver = handles.onboard.receiver
        subscriber = handles.diagram.GetSubsystemByName("joint_command_subscriber")
        arm = handles.scenario.arm_description
        names = list(arm.joint_names)
        middle = (np.asarray(arm.joint_lower_rad) + np.asarray(arm.joint_upper_rad)) / 2
        first, second = middle + 0.01, middle - 0.02
        packets = [_joint_command(seq, names, list(q)) for seq, q in enumerate((first, second))]
        output = receiver.get_q_commanded_output_port()
        rejected = receiver.get_command_rejected_output_port()
    else:
        lcm_type, channel = lcmt_teleop_haptic_command, "TELEOP_HAPTIC_COMMAND"
        handles = MakeGroundDiagram(load_scenario(scenario_text="{haptic: {source: lcm}}"),
                                    lcm=lcm)
        receiver = handles.ground.haptic
        assert isinstance(receiver, HapticCommandReceiver)
        subscriber = handles.diagram.GetSubsystemByName("haptic_subscriber")
        first, second = [0.72, 0.01, 0.0], [0.71, -0.01, 0.0]
        packets = [_haptic_command(utime, pose) for utime, pose in ((1, first), (2, second))]
        output = receiver.get_pose_desired_output_port()
        rejected = receiver.get_message_rejected_output_port()
    assume(payload[:8] != lcm_type._get_packed_fingerprint())
    simulator = Simulator(handles.diagram)
    simulator.Initialize()
    root = simulator.get_context()
    context = receiver.GetMyContextFromRoot(root)
    subscriber_context = subscriber.GetMyContextFromRoot(root)
    lcm.Publish(channel, packets[0].encode())
    simulator.AdvanceTo(0.05)
    np.testing.assert_array_equal(output.Eval(context), first)
    assert rejected.Eval(context)[0] == 0.0
    lcm.Publish(channel, payload)
    simulator.AdvanceTo(0.1)    # must not raise: the robot holds, and says so
    np.testing.assert_array_equal(output.Eval(context), first)
    assert rejected.Eval(context)[0] == 1.0
    assert subscriber.get_undecodable_count_output_port().Eval(subscriber_context)[0] == 1.0
    error = subscriber.get_last_decode_error_output_port().Eval(subscriber_context)
    assert error.startswith(f"{channel}: packet 2 ({len(payload)} bytes) is not a valid "
                            f"{lcm_type.__name__}: "), error
    lcm.Publish(channel, packets[1].encode())   # the next good packet gets through
    simulator.AdvanceTo(0.15)
    np.testing.assert_array_equal(output.Eval(context), second)
    assert rejected.Eval(context)[0] == 0.0
    assert subscriber.get_message_count_output_port().Eval(subscriber_context)[0] == 2.0


def test_every_cut_of_a_signed_command_and_an_extra_byte_are_refused_exactly():
    # Exhaustive: every prefix of a signed command (the HMAC tag last, where the generated
    # decoder reads a short tag without complaint) and one extra byte are decode errors.
    msg = lcmt_teleop_joint_command()
    msg.seq, msg.session_id, msg.num_joints = 5, 77, 2
    msg.joint_name = ["shoulder", "elbow"]
    msg.joint_position_smoothed = [0.1, 0.2]
    msg.joint_velocity_smoothed = [0.0, 0.0]
    msg.auth_tag = bytes(range(32))
    msg.auth_tag_size = 32
    encoded = msg.encode()
    assert lcmt_teleop_joint_command.decode(encoded[:-1]).auth_tag == bytes(range(31))
    for cut in range(len(encoded)):
        assert isinstance(_decode(lcmt_teleop_joint_command, encoded[:cut]), DECODE_ERRORS), cut
    assert isinstance(_decode(lcmt_teleop_joint_command, encoded + b"\x00"), DECODE_ERRORS)
    assert decode_exact(lcmt_teleop_joint_command, encoded).auth_tag == bytes(range(32))
