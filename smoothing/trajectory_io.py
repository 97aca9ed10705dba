"""Joint trajectory CSV files: ``t,<joint names…>`` in seconds and radians, uniform time step.

Reading checks everything a user can get wrong and says where: the header, the joint names,
every value (row number as in the file, column name, value), and the time step.
"""

from __future__ import annotations

import array
import csv
import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from telesmooth.atomic_files import atomic_write
from telesmooth.user_input import (
    ASCII_BLANKS,
    MAX_CSV_BYTES,
    MAX_CSV_COLUMNS,
    MAX_CSV_LINE_CHARS,
    MAX_CSV_ROWS,
    parse_plain_number,
    quote,
    read_file_bytes,
)

TIME_STEP_RTOL = 1e-6
"""Relative tolerance on the uniformity of the time column."""
TIME_RESOLUTION_ULPS = 4.0
"""Steps may also differ by this many units in the last place of the largest |t|: the file's
decimal times are rounded to doubles, so e.g. epoch times (|t| ~ 1.7e9 s, ulp ~ 2.4e-7 s)
cannot resolve step differences below that. Relative to |t|, so tiny steps near t = 0 are
still checked to ``TIME_STEP_RTOL``."""
_LINE_BREAK = re.compile(r"\r\n|\r|\n")
"""What ends a physical line, for csv.reader on a file opened with ``newline=""``."""
_LINE_BREAK_BYTES = re.compile(rb"\r\n|\r|\n")
_PHYSICAL_LINE = re.compile(r"[^\r\n]*(?:\r\n|\r|\n)|[^\r\n]+\Z")
_LONG_LINE = re.compile(rf"[^\r\n]{{{MAX_CSV_LINE_CHARS + 1}}}")
RESERVED_JOINT_NAMES = ("sent_t",)
"""Columns the smoothed output adds after the joints; no joint may be named so."""
MAX_ABS_JOINT_RAD = 1e6
"""Largest |joint value| read, rad (159 155 turns): beyond it the numbers are not an angle
(and the solvers' arithmetic would overflow on their squares and cubes)."""
DEGREES_SUSPICION_RAD = 4.0 * math.pi
"""Joint values beyond this suggest degrees instead of radians (a warning, not an error)."""


@dataclass(frozen=True, eq=False)
class JointTrajectory:
    """A uniformly sampled joint trajectory.

    Attributes:
        t_s: sample times [s], shape (N,).
        positions: joint positions [rad], shape (N, num_joints).
        joint_names: one name per column.
    """

    t_s: np.ndarray
    positions: np.ndarray
    joint_names: tuple

    @property
    def dt_s(self) -> float:
        return float((self.t_s[-1] - self.t_s[0]) / (len(self.t_s) - 1))

    @property
    def num_joints(self) -> int:
        return len(self.joint_names)


def read_joint_csv(path, *, expected_dt_s: float | None = None,
                   reserved_names=RESERVED_JOINT_NAMES, warn=None) -> JointTrajectory:
    """Reads and validates a joint trajectory CSV.

    Args:
        path: the file.
        expected_dt_s: if given, the file's time step must equal it (relative 1e-6).
        reserved_names: column names a joint may not have (by default ``sent_t``, the
            column the smoothed output adds: a joint of that name would be ambiguous there).
        warn: called with a line for each joint whose values look like degrees (the file is
            read as radians all the same); None: not said.

    Raises:
        ValueError: missing/odd header, duplicate, empty or reserved joint names, short rows,
            values that are not finite plain decimal numbers, fewer than 2 rows, a
            non-increasing or non-uniform time column, a time step different from
            ``expected_dt_s``, or a file beyond the bounds of :func:`read_csv_table`.
    """
    path = Path(path)
    header, data_rows = read_csv_table(
        path,
        expected_header_hint="t,<joint names…>",
        after_time_hint="one column per joint (radians)",
    )
    names = header[1:]
    if not names:
        raise ValueError(f"{path}: the header names no joint columns after 't'")
    for index, name in enumerate(names):
        if not name:
            raise ValueError(f"{path}: joint column {index + 1} has an empty name")
        if name == "t" or name in reserved_names:
            raise ValueError(f"{path}: joint column {index + 1} is named {quote(name)}, a "
                             "name reserved for a time column; rename the joint")
    duplicates = sorted({name for name in names if names.count(name) > 1})
    if duplicates:
        raise ValueError(f"{path}: duplicate joint column name(s) {quote(duplicates)}")
    data = parse_csv_rows(path, header, data_rows)
    if data.shape[0] < 2:
        raise ValueError(f"{path}: {data.shape[0]} data row(s); at least 2 are needed")
    t = data[:, 0]
    check_uniform_time(t, source=str(path), expected_dt_s=expected_dt_s)
    positions = data[:, 1:]
    beyond = np.abs(positions) > MAX_ABS_JOINT_RAD
    if beyond.any():
        row, col = (int(i) for i in np.argwhere(beyond)[0])
        raise ValueError(f"{path}: data row {row + 1}, joint {quote(names[col])}: "
                         f"{float(positions[row, col])!r} rad is beyond ±{MAX_ABS_JOINT_RAD:g} "
                         "rad; joint values are angles in radians")
    large = np.abs(positions).max(axis=0) > DEGREES_SUSPICION_RAD
    for index in np.flatnonzero(large) if warn is not None else ():
        warn(f"warning: {path}: joint {quote(names[index])} reaches "
             f"{np.abs(positions[:, index]).max():.3g} rad; values are read as radians "
             "(were degrees meant?)")
    return JointTrajectory(t_s=t, positions=positions, joint_names=tuple(names))


def read_csv_table(path, *, expected_header_hint: str, after_time_hint: str):
    """Reads a UTF-8 CSV file whose header starts with a time column ``t``, within bounds.

    Blank lines are skipped but not renumbered, so every row keeps its line number in the file
    for error messages: the physical line (``\\n``, ``\\r\\n`` or ``\\r`` ends one) on which
    the row starts, also after quoted cells that span lines (see :func:`cell_lines` for the
    line of each cell). Header cells are stripped of white space; data cells are not.

    The file is read through :func:`~telesmooth.user_input.read_file_bytes` (a regular
    file of at most ``MAX_CSV_BYTES``; a device or FIFO is refused before reading), no line
    may exceed ``MAX_CSV_LINE_CHARS`` characters, no row ``MAX_CSV_COLUMNS`` cells, and there
    are at most ``MAX_CSV_ROWS`` data rows: memory stays a small multiple of the file size.

    Args:
        path: The file.
        expected_header_hint: The header the reader expects, quoted in the empty-file message
            (e.g. ``"t,<joint names…>"``).
        after_time_hint: What must follow ``t`` in the header, ending the message for a wrong
            first column (e.g. ``"one column per joint (radians)"``).

    Returns:
        ``(header, data_rows)``: the stripped header cells (a list whose first entry is ``"t"``)
        and an iterator over the data rows as ``(line number, row cells)``, read lazily (the
        row bounds are checked as it goes).

    Raises:
        ValueError: If the file cannot be read or is beyond the bounds above, is not UTF-8
            (the message gives the line and the byte), is not valid CSV for Python's reader
            (e.g. a cell longer than ``csv.field_size_limit()``; the message gives the line),
            is empty (or blank), or its first header column is not ``t``. Iterating the rows
            raises it too (a row beyond the bounds, or invalid CSV further down).
    """
    path = Path(path)
    data = read_file_bytes(path, what=str(path), max_bytes=MAX_CSV_BYTES)
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as error:
        line = 1 + len(_LINE_BREAK_BYTES.findall(data, 0, error.start))
        bad = data[error.start:error.end]
        raise ValueError(
            f"{path}: line {line}: byte(s) {bad!r} at file offset {error.start} are not valid "
            f"UTF-8 ({error.reason}); save the file as UTF-8"
        ) from None
    del data
    long_line = _LONG_LINE.search(text)
    if long_line is not None:
        line = 1 + len(_LINE_BREAK.findall(text, 0, long_line.start()))
        raise ValueError(f"{path}: line {line} is longer than {MAX_CSV_LINE_CHARS} characters "
                         "(is this a CSV file?)")
    rows = _numbered_rows(path, text)
    for _first_line, cells in rows:
        header = [cell.strip() for cell in cells]
        break
    else:
        raise ValueError(f"{path}: the file is empty; expected a header '{expected_header_hint}'")
    if header[0] != "t":
        raise ValueError(
            f"{path}: the first header column is {quote(header[0])}; it must be 't' (seconds), "
            f"followed by {after_time_hint}"
        )
    return header, _bounded_data_rows(path, rows)


def _numbered_rows(path, text: str):
    """The non-blank rows of ``text`` as ``(first line, cells)``; see :func:`read_csv_table`."""
    reader = csv.reader(_physical_lines(text))
    last_line = 0
    try:
        for cells in reader:
            # reader.line_num counts physical lines read so far, so a record starts on the
            # line after the one where the previous record ended.
            first_line, last_line = last_line + 1, reader.line_num
            if len(cells) > MAX_CSV_COLUMNS:
                raise ValueError(f"{path}: line {first_line} has {len(cells)} cells; the "
                                 f"limit is {MAX_CSV_COLUMNS} columns")
            if cells and any(cell.strip() for cell in cells):
                yield first_line, cells
    except csv.Error as error:
        raise ValueError(f"{path}: line {reader.line_num}: not valid CSV ({error})") from None


def _bounded_data_rows(path, rows):
    for count, row in enumerate(rows, start=1):
        if count > MAX_CSV_ROWS:
            raise ValueError(f"{path}: more than {MAX_CSV_ROWS} data rows (line {row[0]}); "
                             "split or resample the recording")
        yield row


def _physical_lines(text: str):
    """The lines of ``text`` with their line breaks, as ``open(newline="")`` gives them."""
    for match in _PHYSICAL_LINE.finditer(text):
        if match.group():
            yield match.group()


def parse_csv_rows(path, header, data_rows, *, check=None) -> np.ndarray:
    """The data rows of :func:`read_csv_table` as a float array (rows, len(header)), every
    cell parsed by :func:`parse_csv_number` (errors name the line and column).

    Args:
        path, header, data_rows: As :func:`read_csv_table` returns them.
        check: Optional ``check(column index, value) -> problem or None``; a problem (e.g.
            ``"must be 0 or 1"``) becomes an error naming the cell's line, column and value.
    """
    width = len(header)
    values = array.array("d")
    for row_index, row in data_rows:
        if len(row) != width:
            raise ValueError(
                f"{path}: line {row_index} has {len(row)} value(s); the header has {width} "
                f"columns {quote(header)}"
            )
        for col, (line, cell) in enumerate(zip(cell_lines(row_index, row), row)):
            value = parse_csv_number(cell, path=path, line=line, column=header[col])
            problem = None if check is None else check(col, value)
            if problem is not None:
                raise ValueError(f"{path}: line {line}, column {quote(header[col])}: value "
                                 f"{quote(cell.strip())} {problem}")
            values.append(value)
    return np.frombuffer(values, dtype=float).reshape(-1, width).copy() if values else \
        np.empty((0, width))


def cell_lines(first_line: int, cells) -> list[int]:
    """The file line on which each cell of a row starts.

    Outside quotes a line break ends the row, so the only line breaks inside a row are those
    kept inside its quoted cells; each cell starts on ``first_line`` plus the breaks before it.

    Args:
        first_line: The line the row starts on (as returned by :func:`read_csv_table`).
        cells: The row's cells.

    Returns:
        One line number per cell.
    """
    lines = []
    line = first_line
    for cell in cells:
        lines.append(line)
        line += len(_LINE_BREAK.findall(cell))
    return lines


def parse_csv_number(cell: str, *, path, line: int, column: str) -> float:
    """Parses one CSV cell as a finite float; the error names the file, line, column and value.

    Only plain decimal numbers are numbers here (see
    :func:`~telesmooth.user_input.parse_plain_number`): ``float()`` also takes ``1_0e-3``,
    non-ASCII digits and other spellings nobody means in a data file, and they are refused.
    """
    try:
        value = parse_plain_number(cell)
    except ValueError:
        raise ValueError(
            f"{path}: line {line}, column {quote(column)}: "
            f"{quote(cell.strip(ASCII_BLANKS))} is not a number (plain decimal: digits 0-9, "
            "'.', an exponent)"
        ) from None
    if not math.isfinite(value):
        raise ValueError(
            f"{path}: line {line}, column {quote(column)}: value "
            f"{quote(cell.strip(ASCII_BLANKS))} is not finite"
        )
    return value


def check_uniform_time(t_s, *, source: str = "t", expected_dt_s: float | None = None) -> float:
    """Checks a finite, strictly increasing, uniform time column; returns its step [s].

    Uniform means every step is within ``TIME_STEP_RTOL`` (relative) of the mean step
    ``(t[-1] - t[0]) / (N - 1)``, plus ``TIME_RESOLUTION_ULPS`` units in the last place of the
    largest |t| (the resolution of the times themselves). There is no absolute slack: near
    t = 0, steps of 1e-13 s are checked as strictly as steps of 1 s.

    Args:
        t_s: The time column [s], shape (N,), N >= 2.
        source: What the messages name (e.g. ``"<path>: column 't'"``).
        expected_dt_s: If given, a finite positive step [s] the column's step must equal
            (relative ``TIME_STEP_RTOL``).

    Raises:
        ValueError: If a time is not finite, time does not increase, the span ``t[-1] - t[0]``
            overflows a double (no finite step), the step is not uniform, or it differs from
            ``expected_dt_s`` (or that is not a finite positive number). Data rows are
            counted from 1.
    """
    t = np.asarray(t_s, dtype=float)
    if t.ndim != 1 or t.size < 2:
        raise ValueError(f"{source}: {t.size} time value(s) of shape {t.shape}; at least 2 "
                         "in a column are needed")
    if expected_dt_s is not None and not (math.isfinite(expected_dt_s) and expected_dt_s > 0):
        raise ValueError(f"{source}: --dt {expected_dt_s!r} s must be a finite positive step")
    bad = ~np.isfinite(t)
    if bad.any():
        row = int(np.flatnonzero(bad)[0])
        raise ValueError(f"{source}: t = {float(t[row])!r} at data row {row + 1} is not finite")
    with np.errstate(over="ignore", invalid="ignore"):
        steps = np.diff(t)
        span = t[-1] - t[0]
    if np.any(steps <= 0):
        bad = int(np.flatnonzero(steps <= 0)[0])
        raise ValueError(
            f"{source}: time must increase; t = {float(t[bad + 1])!r} at data row {bad + 2} "
            f"follows t = {float(t[bad])!r}"
        )
    if not math.isfinite(span):
        raise ValueError(
            f"{source}: the time span from t = {float(t[0])!r} to t = {float(t[-1])!r} "
            "overflows a double, so the time step is not finite"
        )
    dt = float(span / (len(t) - 1))
    deviation = np.abs(steps - dt)
    resolution = TIME_RESOLUTION_ULPS * np.spacing(max(abs(float(t[0])), abs(float(t[-1]))))
    if np.any(deviation > TIME_STEP_RTOL * dt + resolution):
        bad = int(np.argmax(deviation))
        raise ValueError(
            f"{source}: the time step must be uniform; step {float(steps[bad])!r} s between "
            f"data rows {bad + 1} and {bad + 2} differs from the mean step {dt!r} s "
            "(resample first)"
        )
    if expected_dt_s is not None and abs(dt - expected_dt_s) > TIME_STEP_RTOL * expected_dt_s:
        raise ValueError(
            f"{source}: the time step is {dt!r} s but --dt {expected_dt_s!r} s was given"
        )
    return dt


def write_joint_csv(path, t_s, positions, joint_names, *, extra_columns=None) -> None:
    """Writes ``t,<joints…>[,extra…]`` with full float precision (repr round-trips exactly).

    The file is written atomically (:func:`~telesmooth.atomic_files.atomic_write`): complete,
    or not at all. Parent folders are created.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    positions = np.asarray(positions, dtype=float)
    extra_columns = dict(extra_columns or {})
    with atomic_write(path, "w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(["t", *joint_names, *extra_columns])
        extras = [np.asarray(v, dtype=float) for v in extra_columns.values()]
        for k, t in enumerate(np.asarray(t_s, dtype=float)):
            writer.writerow([repr(float(t)), *(repr(float(v)) for v in positions[k]),
                             *(repr(float(v[k])) for v in extras)])
