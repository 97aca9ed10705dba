"""Tests for the haptic recording record/files and the HapticSource Drake system."""

import math

import numpy as np
import pytest
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import LogVectorOutput

from telesmooth.datasets.haptic_recording import (
    PLANAR_POSE_NAMES,
    SPATIAL_POSE_NAMES,
    HapticRecording,
    read_haptic_csv,
    read_haptic_npz,
    write_haptic_csv,
    write_haptic_npz,
)
from telesmooth.datasets.lasa import WorkspaceMapping, lasa_operator_session
from telesmooth.datasets.synthetic import SyntheticOperatorConfig, synthetic_operator_session
from telesmooth.systems.haptic_source import HapticSource, HapticSourceConfig


def _recording(num_samples=50, period_s=0.01, names=PLANAR_POSE_NAMES, seed=0, t0_s=0.0):
    """Random poses and a clutch that toggles a few times, on a uniform clock."""
    rng = np.random.default_rng(seed)
    enable = np.ones(num_samples, dtype=bool)
    enable[num_samples // 5:num_samples // 3] = False
    enable[-3:] = False
    return HapticRecording(
        t_s=t0_s + np.arange(num_samples) * period_s,
        pose=rng.uniform(-1.0, 1.0, size=(num_samples, len(names))),
        enable=enable,
        pose_names=names,
    )


def _outputs_at(dut, t):
    context = dut.CreateDefaultContext()
    context.SetTime(t)
    pose = dut.get_pose_desired_output_port().Eval(context)
    enable = dut.get_enable_output_port().Eval(context)
    return pose, enable


# --- HapticRecording ---


def test_from_operator_session_lasa_and_synthetic():
    mapping = WorkspaceMapping(end_effector_angle_rad=0.3)
    session = lasa_operator_session("Angle", 0, mapping=mapping)
    dut = HapticRecording.from_operator_session(session)
    assert dut.pose_names == ("x_m", "y_m", "phi_rad")
    np.testing.assert_array_equal(dut.t_s, session.t_s)
    np.testing.assert_array_equal(dut.pose[:, :2], session.xy_m)
    np.testing.assert_array_equal(dut.pose[:, 2], 0.3)
    assert dut.enable.all()
    assert dut.period_s == pytest.approx(0.01, rel=1e-12)

    synthetic = synthetic_operator_session(SyntheticOperatorConfig(duration_s=8.0))
    dut = HapticRecording.from_operator_session(synthetic)
    np.testing.assert_array_equal(dut.pose[:, :2], synthetic.xy_m)
    assert dut.num_samples == 801 and dut.num_pose == 3


def test_recording_is_read_only_and_copies_its_inputs():
    pose = np.zeros((4, 3))
    dut = HapticRecording(t_s=np.arange(4) * 0.01, pose=pose, enable=[1, 0, 1, 1],
                          pose_names=PLANAR_POSE_NAMES)
    pose[0, 0] = 5.0
    assert dut.pose[0, 0] == 0.0
    np.testing.assert_array_equal(dut.enable, [True, False, True, True])
    for array in (dut.t_s, dut.pose, dut.enable):
        assert not array.flags.writeable


def _bad_recording(**changes):
    fields = dict(t_s=np.arange(6) * 0.01, pose=np.zeros((6, 3)), enable=np.ones(6, dtype=bool),
                  pose_names=PLANAR_POSE_NAMES)
    fields.update(changes)
    return HapticRecording(**fields)


def _with(array, index, value):
    array = np.array(array, dtype=float)
    array[index] = value
    return array


@pytest.mark.parametrize(
    "changes, match",
    [
        (dict(pose=_with(np.zeros((6, 3)), (3, 1), np.nan)),
         r"pose\[3, 1\] \(sample 3, column 'y_m'\) = nan is not finite"),
        (dict(pose=_with(np.zeros((6, 3)), (2, 2), np.inf)),
         r"pose\[2, 2\] \(sample 2, column 'phi_rad'\) = inf"),
        (dict(t_s=_with(np.arange(6) * 0.01, 4, np.inf)),
         r"t_s\[4\] \(sample 4\) = inf is not finite"),
        (dict(t_s=_with(np.arange(6) * 0.01, 3, 0.035)),
         r"t_s \(data rows counted from 1\): the time step must be uniform; "
         r"step 0\.015\d* s between data rows 3 and 4"),
        (dict(t_s=_with(np.arange(6) * 0.01, 3, 0.01)),
         r"t_s .*: time must increase; t = 0\.01 at data row 4"),
        (dict(pose=np.zeros((6, 2))), r"pose has shape \(6, 2\); expected \(6, 3\)"),
        (dict(pose=np.zeros((5, 3))), r"pose has shape \(5, 3\); expected \(6, 3\)"),
        (dict(t_s=np.zeros((6, 1))), r"t_s has shape \(6, 1\)"),
        (dict(t_s=[0.0], pose=np.zeros((1, 3)), enable=[True]), r"t_s has 1 sample"),
        (dict(enable=_with(np.ones(6), 2, 0.5)), r"enable\[2\] = 0\.5 must be 0 or 1"),
        (dict(enable=np.ones(5, dtype=bool)), r"enable has shape \(5,\); expected \(6,\)"),
        (dict(pose_names=("x_m", "y_m", "x_m")),
         r"pose_names\[2\] = 'x_m' duplicates pose_names\[0\]"),
        (dict(pose_names=("x_m", "t", "phi_rad")), r"pose_names\[1\] = 't' is reserved"),
        (dict(pose_names=("x_m", "", "phi_rad")), r"pose_names\[1\] = '' must be a non-empty"),
        (dict(pose_names=(), pose=np.zeros((6, 0))), r"pose_names = \(\) must name"),
    ],
)
def test_recording_rejects_bad_inputs(changes, match):
    with pytest.raises(ValueError, match=match):
        _bad_recording(**changes)


# --- files ---


def _assert_same_recording(actual, expected):
    assert actual.pose_names == expected.pose_names
    np.testing.assert_array_equal(actual.t_s, expected.t_s)
    np.testing.assert_array_equal(actual.pose, expected.pose)
    np.testing.assert_array_equal(actual.enable, expected.enable)


@pytest.mark.parametrize("names", [PLANAR_POSE_NAMES, SPATIAL_POSE_NAMES])
def test_csv_round_trip_is_exact(tmp_path, names):
    recording = _recording(names=names, seed=1, t0_s=12.5)
    path = tmp_path / "sub" / "haptic.csv"
    write_haptic_csv(path, recording)
    _assert_same_recording(read_haptic_csv(path, expected_pose_names=names), recording)
    assert path.read_text().splitlines()[0] == ",".join(["t", *names, "enable"])


@pytest.mark.parametrize("names", [PLANAR_POSE_NAMES, SPATIAL_POSE_NAMES])
def test_npz_round_trip_is_exact(tmp_path, names):
    recording = _recording(names=names, seed=2)
    path = tmp_path / "haptic.npz"
    write_haptic_npz(path, recording)
    _assert_same_recording(read_haptic_npz(path, expected_pose_names=names), recording)


def test_files_without_enable_are_enabled_throughout(tmp_path):
    csv_path = tmp_path / "no_enable.csv"
    csv_path.write_text("t,x_m,y_m\n0.0,0.1,0.2\n0.01,0.3,0.4\n\n0.02,0.5,0.6\n")
    dut = read_haptic_csv(csv_path)
    assert dut.pose_names == ("x_m", "y_m")
    np.testing.assert_array_equal(dut.pose, [[0.1, 0.2], [0.3, 0.4], [0.5, 0.6]])
    assert dut.enable.all()
    npz_path = tmp_path / "no_enable.npz"
    np.savez(npz_path, t_s=dut.t_s, pose=dut.pose, pose_names=np.array(["x_m", "y_m"]))
    dut = read_haptic_npz(npz_path)
    assert dut.enable.all()
    np.testing.assert_array_equal(dut.pose, [[0.1, 0.2], [0.3, 0.4], [0.5, 0.6]])


GOOD_HEADER = "t,x_m,y_m,phi_rad,enable\n"


@pytest.mark.parametrize(
    "text, kwargs, match",
    [
        ("", {}, r"the file is empty"),
        ("time,x_m\n0,1\n0.01,1\n", {}, r"first header column is 'time'"),
        ("t,enable\n0,1\n0.01,1\n", {}, r"names no pose columns"),
        ("t,x_m,y_m,x_m\n0,1,2,3\n0.01,1,2,3\n", {}, r"duplicate column 'x_m'"),
        ("t,x_m,,phi_rad\n0,1,2,3\n0.01,1,2,3\n", {}, r"header column 3 has an empty name"),
        ("t,enable,x_m\n0,1,2\n0.01,1,2\n", {}, r"'enable' column must be the last"),
        ("t,x_m,y_m\n0,1,2\n0.01,1,2\n", dict(expected_pose_names=PLANAR_POSE_NAMES),
         r"missing pose column\(s\) \['phi_rad'\]"),
        ("t,x_m,y_m,z_m\n0,1,2,3\n0.01,1,2,3\n", dict(expected_pose_names=("x_m", "y_m")),
         r"unexpected pose column\(s\) \['z_m'\]"),
        ("t,y_m,x_m\n0,1,2\n0.01,1,2\n", dict(expected_pose_names=("x_m", "y_m")),
         r"not in the expected order"),
        (GOOD_HEADER + "0,1,2,3,1\n0.01,1,abc,3,1\n", {},
         r"line 3, column 'y_m': 'abc' is not a number"),
        (GOOD_HEADER + "0,1,2,3,1\n0.01,1,2,nan,1\n", {},
         r"line 3, column 'phi_rad': value 'nan' is not finite"),
        (GOOD_HEADER + "0,1,2,3,1\n0.01,1,2,3,2\n", {},
         r"line 3, column 'enable': value '2' must be 0 or 1"),
        (GOOD_HEADER + "0,1,2,3,1\n0.01,1,2,3\n", {},
         r"line 3 has 4 value\(s\); the header has 5"),
        (GOOD_HEADER + "0,1,2,3,1\n", {}, r"1 data row\(s\); at least 2"),
        (GOOD_HEADER + "0,1,2,3,1\n0.01,1,2,3,1\n0.03,1,2,3,1\n", {},
         r"column 't': the time step must be uniform; step 0\.0(1|2)"),
        (GOOD_HEADER + "0,1,2,3,1\n0.01,1,2,3,1\n0.005,1,2,3,1\n", {},
         r"column 't': time must increase; t = 0\.005"),
    ],
)
def test_csv_reader_rejects_bad_files(tmp_path, text, kwargs, match):
    path = tmp_path / "bad.csv"
    path.write_text(text)
    with pytest.raises(ValueError, match=match):
        read_haptic_csv(path, **kwargs)


def test_csv_reader_names_the_file_and_missing_files(tmp_path):
    with pytest.raises(ValueError, match=r"missing\.csv: cannot read"):
        read_haptic_csv(tmp_path / "missing.csv")


def _npz(tmp_path, **arrays):
    path = tmp_path / "bad.npz"
    np.savez(path, **arrays)
    return path


GOOD_NPZ = dict(t_s=np.arange(4) * 0.01, pose=np.zeros((4, 3)),
                pose_names=np.array(PLANAR_POSE_NAMES), enable=np.ones(4, dtype=bool))


@pytest.mark.parametrize(
    "changes, match",
    [
        (dict(pose=None), r"missing array\(s\) \['pose'\]"),
        (dict(time=np.zeros(4)), r"unknown array\(s\) \['time'\]"),
        (dict(pose=_with(np.zeros((4, 3)), (1, 0), np.nan)),
         r"bad\.npz: pose\[1, 0\] \(sample 1, column 'x_m'\) = nan"),
        (dict(pose_names=np.array(["x_m", "x_m", "phi_rad"])),
         r"pose_names\[1\] = 'x_m' duplicates"),
        (dict(pose_names=np.array([1.0, 2.0, 3.0])), r"pose_names has shape \(3,\) and dtype"),
        (dict(enable=np.array([1, 0, 3, 1])), r"enable\[2\] = 3 must be 0 or 1"),
        (dict(t_s=np.array([0.0, 0.01, 0.02, 0.05])),
         r"t_s .*: the time step must be uniform; step 0\.03"),
    ],
)
def test_npz_reader_rejects_bad_files(tmp_path, changes, match):
    arrays = {**GOOD_NPZ, **changes}
    arrays = {key: value for key, value in arrays.items() if value is not None}
    with pytest.raises(ValueError, match=match):
        read_haptic_npz(_npz(tmp_path, **arrays))


def test_npz_reader_rejects_pickles_and_garbage(tmp_path):
    path = _npz(tmp_path, **{**GOOD_NPZ, "pose_names": np.array(["x_m", 1, None], dtype=object)})
    with pytest.raises(ValueError, match=r"cannot read without pickle"):
        read_haptic_npz(path)
    garbage = tmp_path / "garbage.npz"
    garbage.write_bytes(b"not a zip file")
    with pytest.raises(ValueError, match=r"garbage\.npz: cannot read"):
        read_haptic_npz(garbage)
    with pytest.raises(ValueError, match=r"expected \['x_m', 'y_m'\]"):
        read_haptic_npz(_npz(tmp_path, **GOOD_NPZ), expected_pose_names=("x_m", "y_m"))


# --- HapticSourceConfig / HapticSource ---


@pytest.mark.parametrize("period", [0.0, -0.01, math.inf, math.nan, True])
def test_config_rejects_bad_period(period):
    with pytest.raises(ValueError, match=rf"period_s = {period!r} must be finite and > 0"):
        HapticSourceConfig(period_s=period)


def test_port_contract():
    dut = HapticSource(_recording(names=SPATIAL_POSE_NAMES))
    assert dut.num_input_ports() == 0
    assert dut.num_output_ports() == 2
    assert dut.get_pose_desired_output_port().get_name() == "pose_desired"
    assert dut.get_pose_desired_output_port().size() == 6
    assert dut.get_enable_output_port().get_name() == "enable"
    assert dut.get_enable_output_port().size() == 1
    assert dut.GetOutputPort("pose_desired").get_index() == \
        dut.get_pose_desired_output_port().get_index()
    assert dut.GetOutputPort("enable").get_index() == dut.get_enable_output_port().get_index()
    assert dut.pose_names == SPATIAL_POSE_NAMES
    # Stateless: nothing in the context but time.
    context = dut.CreateDefaultContext()
    assert context.num_continuous_states() == 0
    assert context.num_discrete_state_groups() == 0
    assert context.num_abstract_states() == 0


def test_values_at_and_between_sample_times():
    recording = _recording(num_samples=40)
    dut = HapticSource(recording)
    for t, j in [(0.0, 0), (0.005, 0), (0.0099999, 0), (0.01, 1), (0.015, 1), (-0.5, 0)]:
        pose, enable = _outputs_at(dut, t)
        np.testing.assert_array_equal(pose, recording.pose[j], err_msg=f"t = {t}")
        assert enable[0] == float(recording.enable[j])
    for k in range(recording.num_samples):
        # k * period as the simulator computes sample times; also just before it.
        pose, enable = _outputs_at(dut, k * 0.01)
        np.testing.assert_array_equal(pose, recording.pose[k], err_msg=f"k = {k}")
        assert enable[0] == (1.0 if recording.enable[k] else 0.0)
        if k:
            pose, _ = _outputs_at(dut, k * 0.01 - 1e-6)
            np.testing.assert_array_equal(pose, recording.pose[k - 1], err_msg=f"k = {k} - 1e-6")


def test_after_the_end_holds_the_last_sample():
    recording = _recording(num_samples=20)
    dut = HapticSource(recording)
    for t in (0.19, 0.2, 0.25, 100.0):
        pose, enable = _outputs_at(dut, t)
        np.testing.assert_array_equal(pose, recording.pose[-1])
        assert enable[0] == 0.0  # the recording ends with the clutch released


def test_recording_not_starting_at_zero_is_replayed_from_time_zero():
    recording = _recording(num_samples=10, t0_s=5.0)
    dut = HapticSource(recording)
    np.testing.assert_array_equal(_outputs_at(dut, 0.0)[0], recording.pose[0])
    np.testing.assert_array_equal(_outputs_at(dut, 0.03)[0], recording.pose[3])


@pytest.mark.parametrize("period_s", [0.01, 1.0 / 30.0])
def test_simulated_log_matches_the_recording_sample_by_sample(period_s):
    recording = _recording(num_samples=120, period_s=period_s, seed=3)
    builder = DiagramBuilder()
    dut = builder.AddNamedSystem("haptic_source",
                                 HapticSource(recording, HapticSourceConfig(period_s=period_s)))
    pose_log = LogVectorOutput(dut.get_pose_desired_output_port(), builder, period_s)
    enable_log = LogVectorOutput(dut.get_enable_output_port(), builder, period_s)
    diagram = builder.Build()
    simulator = Simulator(diagram)
    extra = 15
    end_time = (recording.num_samples + extra - 1) * period_s
    # AdvanceTo does not run events due exactly at the end time: go a little further.
    simulator.AdvanceTo(end_time + 0.5 * period_s)
    context = simulator.get_context()
    times = pose_log.FindLog(context).sample_times()
    poses = pose_log.FindLog(context).data().T
    enables = enable_log.FindLog(context).data().T
    num = recording.num_samples
    assert times.shape == (num + extra,)
    np.testing.assert_allclose(times, np.arange(num + extra) * period_s, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(poses[:num], recording.pose)
    np.testing.assert_array_equal(enables[:num, 0], recording.enable.astype(float))
    # After the end: the last sample, held.
    np.testing.assert_array_equal(poses[num:], np.tile(recording.pose[-1], (extra, 1)))
    np.testing.assert_array_equal(enables[num:, 0], float(recording.enable[-1]))


def test_period_mismatch_is_rejected():
    recording = _recording(period_s=0.02)
    with pytest.raises(ValueError, match=r"recording period_s = 0\.02 .* differs from "
                                         r"config\.period_s = 0\.01"):
        HapticSource(recording)
    # 1e-9 relative is accepted: the rounding of np.arange * period is far below it.
    HapticSource(_recording(period_s=0.01 * (1 + 1e-12)))
    with pytest.raises(ValueError, match=r"recording = ndarray object; expected a Haptic"):
        HapticSource(np.zeros((3, 3)))


def test_from_lasa_and_from_synthetic():
    mapping = WorkspaceMapping(end_effector_angle_rad=0.2)
    dut = HapticSource.from_lasa("Sine", 2, mapping)
    session = lasa_operator_session("Sine", 2, mapping=mapping)
    pose, enable = _outputs_at(dut, 3.0)
    np.testing.assert_array_equal(pose, [*session.xy_m[300], 0.2])
    assert enable[0] == 1.0
    assert dut.pose_names == PLANAR_POSE_NAMES

    config = SyntheticOperatorConfig(duration_s=10.0, haptic_rate_hz=50.0, seed=4)
    dut = HapticSource.from_synthetic(config)
    session = synthetic_operator_session(config)
    pose, _ = _outputs_at(dut, 4.0)
    np.testing.assert_array_equal(pose, [*session.xy_m[200], 0.0])
    with pytest.raises(ValueError, match=r"config\.period_s = 0\.01"):
        HapticSource.from_synthetic(config, source_config=HapticSourceConfig(period_s=0.01))
    with pytest.raises(ValueError, match=r"expected a SyntheticOperatorConfig"):
        HapticSource.from_synthetic(HapticSourceConfig())
