"""Recorded haptic-device commands: the operator's Cartesian pose and clutch, at a uniform rate.

A :class:`HapticRecording` is what the haptic source system replays: per sample, the pose the
operator commands and whether the clutch (enable) is engaged. It is a pure record (numpy
only); it can be made from an operator session (LASA or synthetic) or read from / written to
CSV and NPZ files. Every reader validates its input and says where a problem is (field or
column, row, value).

File formats:

* CSV: header ``t,<pose names...>[,enable]``; ``t`` in s, pose columns in the units their
  names carry (``x_m``, ``phi_rad``, ...), ``enable`` 0 or 1 (missing column: enabled
  throughout). One data row per sample.
* NPZ: arrays ``t_s`` (K,), ``pose`` (K, m), ``pose_names`` (m,) of str and optionally
  ``enable`` (K,) of bool or 0/1 (missing: enabled throughout). Read without pickle.
"""

from __future__ import annotations

import csv
import dataclasses
import io
import zipfile
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from telesmooth.atomic_files import atomic_write
from telesmooth.smoothing.trajectory_io import (
    check_uniform_time,
    parse_csv_rows,
    read_csv_table,
)
from telesmooth.user_input import (
    MAX_NPZ_ARRAY_BYTES,
    MAX_NPZ_BYTES,
    MAX_NPZ_MEMBERS,
    describe_size,
    quote,
    read_file_bytes,
)

__all__ = [
    "PLANAR_POSE_NAMES",
    "SPATIAL_POSE_NAMES",
    "HapticRecording",
    "read_haptic_csv",
    "read_haptic_npz",
    "write_haptic_csv",
    "write_haptic_npz",
]

PLANAR_POSE_NAMES: tuple[str, str, str] = ("x_m", "y_m", "phi_rad")
"""Pose names for a planar arm: end-effector position (m) and orientation (rad)."""

SPATIAL_POSE_NAMES: tuple[str, ...] = ("x_m", "y_m", "z_m", "roll_rad", "pitch_rad", "yaw_rad")
"""Pose names for a 6-DOF arm: position (m) and roll-pitch-yaw orientation (rad)."""

_TIME_COLUMN = "t"
_ENABLE_COLUMN = "enable"
_NPZ_KEYS = ("t_s", "pose", "pose_names", "enable")
_NPZ_REQUIRED_KEYS = ("t_s", "pose", "pose_names")
_ZIP_MAGIC = (b"PK\x03\x04", b"PK\x05\x06")   # a zip with members / an empty zip
_NPY_MAGIC = b"\x93NUMPY"
_REAL_KINDS = "biuf"   # bool, int, unsigned, float: exactly representable as float64 values


def _as_real_array(values, *, field: str) -> np.ndarray:
    """``values`` as a new float64 array; raises ValueError naming ``field`` for anything that
    is not real numbers (complex values would lose their imaginary part, strings and dates
    have no meaning as seconds or metres)."""
    array = np.asarray(values)
    if array.dtype.kind == "O":   # e.g. a list mixing numbers and other objects
        try:
            return np.array(array, dtype=float)
        except (TypeError, ValueError) as error:
            raise ValueError(f"{field} holds values that are not real numbers ({error})") \
                from None
    if array.dtype.kind not in _REAL_KINDS:
        raise ValueError(
            f"{field} has dtype {array.dtype} (shape {array.shape}); expected real numbers"
        )
    return np.array(array, dtype=float)


def _check_pose_names(pose_names, *, source: str) -> tuple[str, ...]:
    """Returns the names as a tuple of str; raises ValueError for empty/duplicate/reserved."""
    names = tuple(pose_names)
    if not names:
        raise ValueError(f"{source}: pose_names = {names!r} must name at least one pose entry")
    for index, name in enumerate(names):
        if not isinstance(name, str) or not name.strip() or name != name.strip():
            raise ValueError(
                f"{source}: pose_names[{index}] = {name!r} must be a non-empty string "
                "without surrounding spaces"
            )
        if name in (_TIME_COLUMN, _ENABLE_COLUMN):
            raise ValueError(
                f"{source}: pose_names[{index}] = {name!r} is reserved for the "
                f"{'time' if name == _TIME_COLUMN else 'clutch'} column"
            )
        if name in names[:index]:
            raise ValueError(
                f"{source}: pose_names[{index}] = {name!r} duplicates pose_names"
                f"[{names.index(name)}]"
            )
    return names


def _check_expected_names(names: Sequence[str], expected, *, source: str) -> None:
    """Raises ValueError if ``names`` differ from ``expected`` (missing, extra, order)."""
    if expected is None:
        return
    expected = tuple(expected)
    if tuple(names) == expected:
        return
    missing = [name for name in expected if name not in names]
    extra = [name for name in names if name not in expected]
    if missing:
        raise ValueError(f"{source}: missing pose column(s) {missing}; expected {list(expected)}")
    if extra:
        raise ValueError(
            f"{source}: unexpected pose column(s) {extra}; expected {list(expected)}"
        )
    raise ValueError(
        f"{source}: pose columns {list(names)} are not in the expected order {list(expected)}"
    )


def _as_enable(values, num_samples: int, *, source: str) -> np.ndarray:
    """Converts bool or 0/1 values of shape (K,) to a bool array; raises ValueError otherwise."""
    array = np.asarray(values)
    if array.shape != (num_samples,):
        raise ValueError(
            f"{source}: enable has shape {array.shape}; expected ({num_samples},), one flag "
            "per sample"
        )
    if array.dtype == bool:
        return array.copy()
    if array.dtype.kind not in "iuf":
        raise ValueError(f"{source}: enable has dtype {array.dtype}; expected bool or 0/1")
    bad = ~((array == 0) | (array == 1))
    if bad.any():
        row = int(np.flatnonzero(bad)[0])
        raise ValueError(f"{source}: enable[{row}] = {array[row].item()!r} must be 0 or 1")
    return array == 1


@dataclasses.dataclass(frozen=True, eq=False)
class HapticRecording:
    """The commands of a haptic device, uniformly sampled.

    Attributes:
        t_s: Sample times, s; shape (K,), K >= 2, strictly increasing and uniform (relative
            1e-6, as for joint CSV files). Need not start at 0. Read-only.
        pose: Commanded Cartesian pose, shape (K, m), columns ordered and united as
            ``pose_names`` (e.g. m and rad). Finite. Read-only.
        enable: Clutch state per sample, bool, shape (K,); True while the operator is
            commanding the robot. Read-only.
        pose_names: Name of each pose column, shape (m,), e.g. :data:`PLANAR_POSE_NAMES`;
            non-empty, unique, not ``"t"`` or ``"enable"``.

    Arrays given are copied (as float / bool) and made read-only; ``enable`` also accepts
    0/1 numbers. Equality is identity (the fields hold arrays).

    Raises:
        ValueError: On wrong shapes, fewer than 2 samples, non-finite values, non-increasing
            or non-uniform time, enable values other than 0/1, or bad pose names; the message
            names the field, the sample (0-based index; the time-step checks shared with
            joint CSV files count data rows from 1 and say so) and column name where
            relevant, and the offending value.
    """

    t_s: np.ndarray
    pose: np.ndarray
    enable: np.ndarray
    pose_names: tuple[str, ...]

    def __post_init__(self) -> None:
        names = _check_pose_names(self.pose_names, source="HapticRecording")
        t_s = _as_real_array(self.t_s, field="t_s")
        if t_s.ndim != 1:
            raise ValueError(f"t_s has shape {t_s.shape}; expected (num_samples,)")
        if t_s.size < 2:
            raise ValueError(f"t_s has {t_s.size} sample(s); at least 2 are needed")
        pose = _as_real_array(self.pose, field="pose")
        if pose.shape != (t_s.size, len(names)):
            raise ValueError(
                f"pose has shape {pose.shape}; expected ({t_s.size}, {len(names)}): one row "
                f"per entry of t_s and one column per pose name {list(names)}"
            )
        bad = ~np.isfinite(t_s)
        if bad.any():
            row = int(np.flatnonzero(bad)[0])
            raise ValueError(f"t_s[{row}] (sample {row}) = {float(t_s[row])!r} is not finite")
        bad = ~np.isfinite(pose)
        if bad.any():
            row, col = (int(i) for i in np.argwhere(bad)[0])
            raise ValueError(
                f"pose[{row}, {col}] (sample {row}, column {names[col]!r}) = "
                f"{float(pose[row, col])!r} is not finite ({int(bad.sum())} non-finite "
                "value(s) in all)"
            )
        # The shared check counts rows from 1; say so, since our other messages index from 0.
        check_uniform_time(t_s, source="t_s (data rows counted from 1)")
        enable = _as_enable(self.enable, t_s.size, source="HapticRecording")
        for array in (t_s, pose, enable):
            array.setflags(write=False)
        object.__setattr__(self, "t_s", t_s)
        object.__setattr__(self, "pose", pose)
        object.__setattr__(self, "enable", enable)
        object.__setattr__(self, "pose_names", names)

    @property
    def num_samples(self) -> int:
        """Number of samples K."""
        return int(self.t_s.size)

    @property
    def num_pose(self) -> int:
        """Number of pose entries m."""
        return len(self.pose_names)

    @property
    def period_s(self) -> float:
        """Sample period, s: (t_s[-1] - t_s[0]) / (K - 1)."""
        return float((self.t_s[-1] - self.t_s[0]) / (self.t_s.size - 1))

    @classmethod
    def from_operator_session(cls, session) -> HapticRecording:
        """The haptic commands of an operator session (LASA or synthetic).

        Args:
            session: An :class:`~telesmooth.datasets.lasa.OperatorSession`.

        Returns:
            A recording on the session's clock with pose (x, y, phi) named
            :data:`PLANAR_POSE_NAMES`: x, y = ``session.xy_m`` (m) and
            phi = ``session.mapping.end_effector_angle_rad`` (rad, constant); enabled
            throughout.
        """
        xy_m = np.asarray(session.xy_m, dtype=float)
        phi_rad = np.full(xy_m.shape[0], float(session.mapping.end_effector_angle_rad))
        return cls(
            t_s=session.t_s,
            pose=np.column_stack([xy_m, phi_rad]),
            enable=np.ones(xy_m.shape[0], dtype=bool),
            pose_names=PLANAR_POSE_NAMES,
        )


def read_haptic_csv(path, *, expected_pose_names: Sequence[str] | None = None) -> HapticRecording:
    """Reads a haptic recording from a CSV file ``t,<pose names...>[,enable]``.

    Args:
        path: The file.
        expected_pose_names: If given, the pose columns must be exactly these, in order.

    Returns:
        The recording; enabled throughout if the file has no ``enable`` column.

    Raises:
        ValueError: If the file cannot be read or is empty, the first column is not ``t``,
            there are no pose columns, a column name is empty or repeated, the pose columns
            differ from ``expected_pose_names``, a row has the wrong number of values, a value
            is not a finite number (the message gives the file line, column name and value),
            an enable value is not 0 or 1, there are fewer than 2 rows, or the time column is
            not strictly increasing and uniform.
    """
    path = Path(path)
    header, data_rows = read_csv_table(
        path,
        expected_header_hint="t,<pose names...>",
        after_time_hint="the pose columns and optionally 'enable'",
    )
    for index, name in enumerate(header):
        if not name:
            raise ValueError(f"{path}: header column {index + 1} has an empty name")
        if name in header[:index]:
            raise ValueError(f"{path}: duplicate column {name!r} (header columns "
                             f"{header.index(name) + 1} and {index + 1})")
    has_enable = header[-1] == _ENABLE_COLUMN
    pose_names = header[1:-1] if has_enable else header[1:]
    if _ENABLE_COLUMN in pose_names:
        raise ValueError(f"{path}: the 'enable' column must be the last column; header {header}")
    if not pose_names:
        raise ValueError(f"{path}: the header {header} names no pose columns after 't'")
    _check_expected_names(pose_names, expected_pose_names, source=str(path))

    enable_column = len(header) - 1 if has_enable else None

    def check_enable(column: int, value: float) -> str | None:
        if column == enable_column and value not in (0.0, 1.0):
            return "must be 0 or 1"
        return None

    values = parse_csv_rows(path, header, data_rows, check=check_enable)
    if values.shape[0] < 2:
        raise ValueError(f"{path}: {values.shape[0]} data row(s); at least 2 are needed")
    check_uniform_time(values[:, 0], source=f"{path}: column 't'")
    pose = values[:, 1:1 + len(pose_names)]
    enable = values[:, -1] == 1.0 if has_enable else np.ones(values.shape[0], dtype=bool)
    return HapticRecording(
        t_s=values[:, 0], pose=pose, enable=enable, pose_names=tuple(pose_names)
    )


def write_haptic_csv(path, recording: HapticRecording) -> None:
    """Writes ``t,<pose names...>,enable`` with full float precision (repr round-trips).

    Args:
        path: The file; parent folders are created.
        recording: The recording; ``enable`` is written as 1/0.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_write(path, "w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow([_TIME_COLUMN, *recording.pose_names, _ENABLE_COLUMN])
        for k in range(recording.num_samples):
            writer.writerow([
                repr(float(recording.t_s[k])),
                *(repr(float(v)) for v in recording.pose[k]),
                "1" if recording.enable[k] else "0",
            ])


def read_haptic_npz(path, *, expected_pose_names: Sequence[str] | None = None) -> HapticRecording:
    """Reads a haptic recording from an NPZ file (arrays ``t_s``, ``pose``, ``pose_names``,
    optional ``enable``).

    Args:
        path: The file.
        expected_pose_names: If given, ``pose_names`` must be exactly these, in order.

    Returns:
        The recording; enabled throughout if the file has no ``enable`` array.

    Raises:
        ValueError: If the file cannot be read as NPZ (not a zip archive, e.g. a single
            ``.npy`` array; a damaged archive; a member that is not a ``.npy`` array; pickled
            object arrays, which are refused), a required array is missing or an unknown one
            present, ``pose_names`` is not a 1-D array of strings or differs from
            ``expected_pose_names``, or the arrays fail the checks of :class:`HapticRecording`
            (real-number dtypes, shapes, finiteness, uniform time, enable 0/1). The message
            starts with the file and names the array.
    """
    path = Path(path)
    arrays = _load_npz_arrays(path)
    missing = [key for key in _NPZ_REQUIRED_KEYS if key not in arrays]
    if missing:
        raise ValueError(
            f"{path}: missing array(s) {missing}; a haptic NPZ holds {list(_NPZ_KEYS)} "
            "('enable' optional)"
        )
    unknown = sorted(key for key in arrays if key not in _NPZ_KEYS)
    if unknown:
        raise ValueError(
            f"{path}: unknown array(s) {unknown}; a haptic NPZ holds {list(_NPZ_KEYS)}"
        )
    names_array = arrays["pose_names"]
    if names_array.ndim != 1 or names_array.dtype.kind != "U":
        raise ValueError(
            f"{path}: pose_names has shape {names_array.shape} and dtype {names_array.dtype}; "
            "expected a 1-D array of strings"
        )
    pose_names = _check_pose_names(
        [str(name) for name in names_array], source=f"{path}: pose_names"
    )
    _check_expected_names(pose_names, expected_pose_names, source=str(path))
    t_s = arrays["t_s"]
    enable = arrays.get("enable")
    if enable is None:
        enable = np.ones(t_s.shape[:1], dtype=bool)
    try:
        return HapticRecording(
            t_s=t_s, pose=arrays["pose"], enable=enable, pose_names=pose_names
        )
    except ValueError as error:
        raise ValueError(f"{path}: {error}") from None


def _load_npz_arrays(path: Path) -> dict:
    """All arrays of an NPZ file by name; every way the file can fail is a ValueError that
    starts with ``path`` (and names the member where one is at fault).

    Bounded before anything is decompressed: the file (a regular file of at most
    ``MAX_NPZ_BYTES``), the number of members (``MAX_NPZ_MEMBERS``), and each member's size
    once decompressed, both as its zip entry declares it (the zip reader never returns more)
    and as its ``.npy`` header's shape and dtype claim (``MAX_NPZ_ARRAY_BYTES``).
    """
    data = read_file_bytes(path, what=str(path), max_bytes=MAX_NPZ_BYTES)
    head = data[:len(_NPY_MAGIC)]
    if head.startswith(_NPY_MAGIC):
        raise ValueError(
            f"{path}: cannot read as NPZ: this is a single .npy array, not an archive of the "
            f"named arrays {list(_NPZ_KEYS)} (write it with numpy.savez)"
        )
    if not head.startswith(_ZIP_MAGIC):
        raise ValueError(
            f"{path}: cannot read as NPZ: the file starts with {head!r}, not with a zip "
            "archive's signature"
        )
    # From here on only numpy and zipfile parse the (untrusted) bytes. Damaged archives make
    # them raise an open set of types (BadZipFile, zlib.error, NotImplementedError for an
    # unknown compression method, RuntimeError for an encryption flag, EOFError, struct.error,
    # ValueError for a bad .npy header, MemoryError for an absurd shape, ...): every one
    # means "this file is not a readable NPZ", so all become the documented ValueError.
    try:
        _check_npz_sizes(path, data)
        archive = np.load(io.BytesIO(data), allow_pickle=False)
    except ValueError as error:
        if str(error).startswith(str(path)):
            raise
        raise ValueError(f"{path}: cannot read as NPZ (ValueError: {error})") from None
    except Exception as error:  # noqa: BLE001 - see above
        raise ValueError(
            f"{path}: cannot read as NPZ ({type(error).__name__}: {error})"
        ) from None
    if not isinstance(archive, np.lib.npyio.NpzFile):   # defensive: magic checked above
        raise ValueError(f"{path}: cannot read as NPZ (got a {type(archive).__name__})")
    arrays = {}
    with archive:
        for key in archive.files:
            try:
                value = archive[key]
            except Exception as error:  # noqa: BLE001 - as for np.load above
                if isinstance(error, ValueError) and "allow_pickle" in str(error):
                    raise ValueError(
                        f"{path}: cannot read without pickle: array {key!r} holds Python "
                        f"objects, which we never unpickle ({error})"
                    ) from None
                raise ValueError(
                    f"{path}: cannot read array {quote(key)} ({type(error).__name__}: {error})"
                ) from None
            if not isinstance(value, np.ndarray):
                raise ValueError(
                    f"{path}: archive member {quote(key)} is not a .npy array "
                    f"({len(value)} byte(s) of other data)"
                )
            arrays[key] = value
    return arrays


def _check_npz_sizes(path: Path, data: bytes) -> None:
    """Refuses an archive whose members would decompress beyond the bounds (see
    :func:`_load_npz_arrays`); reads only the zip directory and each ``.npy`` header."""
    with zipfile.ZipFile(io.BytesIO(data)) as archive:
        members = archive.infolist()
        if len(members) > MAX_NPZ_MEMBERS:
            raise ValueError(f"{path}: {len(members)} archive members; a haptic NPZ holds at "
                             f"most {MAX_NPZ_MEMBERS}")
        for member in members:
            name = quote(member.filename)
            if member.file_size > MAX_NPZ_ARRAY_BYTES:
                raise ValueError(
                    f"{path}: member {name} decompresses to {describe_size(member.file_size)}; "
                    f"the limit is {describe_size(MAX_NPZ_ARRAY_BYTES)}")
            if not member.filename.endswith(".npy"):
                continue
            with archive.open(member) as handle:
                version = np.lib.format.read_magic(handle)
                if version == (1, 0):
                    shape, _, dtype = np.lib.format.read_array_header_1_0(handle)
                elif version == (2, 0):
                    shape, _, dtype = np.lib.format.read_array_header_2_0(handle)
                else:
                    raise ValueError(f"{path}: member {name} has .npy format version "
                                     f"{version}; expected 1.0 or 2.0")
            count = 1
            for extent in shape:
                count *= int(extent)
            claimed = count * dtype.itemsize
            if claimed > MAX_NPZ_ARRAY_BYTES:
                raise ValueError(
                    f"{path}: array {name} claims shape {quote(shape)} of {dtype} "
                    f"({describe_size(claimed)}); the limit is "
                    f"{describe_size(MAX_NPZ_ARRAY_BYTES)}")


def write_haptic_npz(path, recording: HapticRecording) -> None:
    """Writes ``t_s``, ``pose``, ``enable`` (bool) and ``pose_names`` (str) to an NPZ file.

    Args:
        path: The file; parent folders are created. NumPy appends ``.npz`` if missing.
        recording: The recording.
    """
    path = Path(path)
    if path.suffix != ".npz":
        path = path.with_name(path.name + ".npz")
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_write(path, "wb") as handle:
        np.savez(
            handle,
            t_s=recording.t_s,
            pose=recording.pose,
            enable=recording.enable,
            pose_names=np.array(recording.pose_names, dtype=str),
        )
