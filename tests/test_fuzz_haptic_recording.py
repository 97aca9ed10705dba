"""Property-based fuzzing of the haptic recording readers (``read_haptic_csv``,
``read_haptic_npz``).

The contract, the conventions and the shared generators: tests/fuzz_helpers.py (a bad
input gets a clear ValueError or a held, flagged output; never another exception; what was
accepted is not altered).
"""

from __future__ import annotations

import io
import math
import warnings
import zipfile

import hypothesis.extra.numpy as hnp
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

from telesmooth.datasets.haptic_recording import (
    HapticRecording,
    read_haptic_csv,
    read_haptic_npz,
    write_haptic_npz,
)
from telesmooth.user_input import ASCII_BLANKS, quote


@pytest.fixture(scope="module")
def work_dir():
    yield from temporary_work_dir()


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
