"""Helpers of the property-based fuzzing (tests/test_fuzz_*.py) of every place a user or a device
feeds input into telesmooth.

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

import csv
import io
import math
import struct
import tempfile
import time
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from hypothesis import HealthCheck, assume, settings
from hypothesis import strategies as st

from telesmooth.lcm_types import (
    decode_exact,
    lcmt_onboard_joint_status,
    lcmt_teleop_collision_event,
    lcmt_teleop_haptic_command,
    lcmt_teleop_joint_command,
)
from telesmooth.user_input import ASCII_BLANKS, quote


def fuzz(max_examples: int):
    """Deterministic hypothesis settings that write nothing to disk."""
    return settings(derandomize=True, database=None, deadline=None, max_examples=max_examples,
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large,
                                           HealthCheck.filter_too_much])


def temporary_work_dir():
    """A temporary folder for the fuzzed files (each test module's ``work_dir`` fixture)."""
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
# LCM messages: strategies, decoding as the receivers do, commands built by hand
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
        msg.stop = draw(st.booleans())
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
        msg.sample_utime = draw(INT64)
        msg.joint_velocity_link = draw(st.lists(DOUBLES, min_size=n, max_size=n))
        msg.joint_velocity_motor = draw(st.lists(DOUBLES, min_size=n, max_size=n))
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


def _haptic_command(utime, pose, enable=True, *, num_axes=None):
    msg = lcmt_teleop_haptic_command()
    msg.utime, msg.num_axes = utime, len(pose) if num_axes is None else num_axes
    msg.pose_desired, msg.enable = list(pose), enable
    return msg
