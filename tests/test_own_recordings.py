"""A user's own haptic recordings (docs/commands.md, "Your own recordings"): the mistakes a new
user made from the docs alone each get one line naming the scenario key that fixes them, and
a hand at rest draws its figures without a warning.

* a recording sampled at another rate names ``haptic.period_s`` (the key the docs give), not
  a Python class, and setting it as the line says runs;
* a 6-DOF recording on the planar arm says ``arm: space_arm``;
* ``smooth`` on a haptic recording (metres) refuses it instead of smoothing metres as radians;
* a tool that does not move: the end-effector plot spans 1 cm, no matplotlib warning.
"""

import warnings

import numpy as np
import pytest
from bad_input_helpers import assert_one_line_error, run


def _write(path, header, columns):
    np.savetxt(path, np.column_stack(columns), delimiter=",", header=header, comments="")
    return path


@pytest.fixture()
def at_rest_50_hz(tmp_path):
    t = np.arange(0.0, 3.0, 0.02)
    return _write(tmp_path / "rest50.csv", "t,x_m,y_m,phi_rad",
                  [t, np.full_like(t, 0.7), np.zeros_like(t), np.zeros_like(t)])


def test_another_rate_names_the_scenario_key_and_its_value(tmp_path, capsys, at_rest_50_hz):
    out = tmp_path / "out"
    status, stdout, err = run(capsys, "simulate", "--scenario-text",
                              f"{{haptic: {{source: file, file: {at_rest_50_hz}}}}}",
                              "--out", out)
    line = assert_one_line_error(status, stdout, err, "simulate", "haptic.period_s = 0.01 s",
                                 "set haptic.period_s: 0.02", "50 Hz")
    assert "HapticSourceConfig" not in line
    assert not out.exists()


def test_the_rate_set_as_the_line_says_runs_and_a_hand_at_rest_plots_quietly(
        tmp_path, capsys, at_rest_50_hz):
    out = tmp_path / "out"
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        status, _, err = run(capsys, "simulate", "--scenario-text",
                             f"{{haptic: {{source: file, file: {at_rest_50_hz}, "
                             "period_s: 0.02}}", "--out", out)
    assert status == 0, err
    assert (out / "end_effector.png").stat().st_size > 0


def test_a_six_dof_recording_on_the_planar_arm_names_the_arm(tmp_path, capsys):
    t = np.arange(0.0, 1.0, 0.01)
    path = _write(tmp_path / "six.csv", "t,x_m,y_m,z_m,roll_rad,pitch_rad,yaw_rad",
                  [t, np.full_like(t, 0.7)] + [np.zeros_like(t)] * 5)
    status, stdout, err = run(capsys, "simulate", "--scenario-text",
                              f"{{haptic: {{source: file, file: {path}}}}}",
                              "--out", tmp_path / "o")
    assert_one_line_error(status, stdout, err, "simulate", "needs arm: space_arm",
                          "air_bearing_arm")


def test_smooth_refuses_a_haptic_recording(tmp_path, capsys, at_rest_50_hz):
    output = tmp_path / "smoothed.csv"
    status, stdout, err = run(capsys, "smooth", at_rest_50_hz, "-o", output,
                              "--acc-max", "0.05", "--jerk-max", "0.1")
    assert_one_line_error(status, stdout, err, "smooth", "a hand's pose", "telesmooth simulate")
    assert not output.exists()
