"""The operator's status panel (console/status.py): hand-made chain states → the lines the
panel shows, written out in full; ``fd_ratios`` against a hand computation. Each test's
comment says which wrong implementation it catches."""

import math

import numpy as np

from telesmooth.console.input import ConsoleNotice
from telesmooth.console.status import StatusInputs, fd_ratios, status_lines
from telesmooth.safety.guard import GuardMode

NOMINAL = StatusInputs(
    enabled=True, stop=False, notice=int(ConsoleNotice.NONE), saturated=False,
    telemetry_age_s=0.123, telemetry_silence_s=0.05, robot_guard_mode=int(GuardMode.TRACK),
    stream_distance_rad=0.0012, holding=False, collision=False, min_distance_m=0.0456,
    ik_failure="", sigma=np.array([1.5e-3, 2.0e4]),
    acceleration_ratio=np.array([0.5, 0.25]), jerk_ratio=np.array([0.75, 1.0]),
    residual_m=0.0001234, residual_warning_m=0.002)

NOMINAL_LINES = [
    "clutch ENGAGED: you drive the robot",
    "link up: telemetry 123 ms old",
    "robot guard: track, 1.2 mrad from the commands",
    "FIFO: moving; pre-simulator: 46 mm clear",
    "σ [rad²/s⁷]: 1.5e-03 2.0e+04",
    "sent acc/limit 0.50 0.25, jerk/limit 0.75 1.00",
    "prediction: 0.123 mm from the measured robot",
]


def lines(**changes):
    return status_lines(NOMINAL._replace(**changes))


def test_a_nominal_chain_reads_as_written():
    # Catches: units (s shown as ms, m as mm) or formats changed, a line lost or added (no
    # real-time line while the rate is unknown), "OVER" at a ratio of exactly 1.
    assert status_lines(NOMINAL) == NOMINAL_LINES


def test_the_clutch_line_engaged_released_stopped_and_why():
    # Catches: a stop shown as a plain release (the operator must know Enable clears it), a
    # notice lost or shown under a stop, the reach warning not shown.
    assert lines(enabled=False)[0] == "clutch released: press Enable (Space) to drive"
    assert lines(enabled=False, notice=int(ConsoleNotice.NO_BROWSER))[0] == (
        "clutch released: press Enable (Space) to drive (no browser connected: clutch "
        "released)")
    assert lines(enabled=False, notice=int(ConsoleNotice.GAMEPAD_LOST))[0] == (
        "clutch released: press Enable (Space) to drive (gamepad lost: clutch released)")
    assert lines(enabled=False, stop=True, notice=int(ConsoleNotice.STOPPED))[0] == (
        "STOPPED: press Enable (Space) to go on")
    assert lines(saturated=True)[0] == (
        "clutch ENGAGED: you drive the robot; hand at the edge of the reach")


def test_the_link_line_says_no_telemetry_after_the_timeout_and_not_before():
    # Catches: the age shown instead of the silence, ≥ instead of > at the timeout, a link
    # timeout that is not the one given.
    assert lines(telemetry_silence_s=3.2)[1] == (
        "link: NO TELEMETRY FOR 3.2 s: the predicted robot runs on the commands sent")
    assert lines(telemetry_silence_s=1.0)[1] == "link up: telemetry 123 ms old"
    assert lines(telemetry_silence_s=3.2, link_timeout_s=5.0)[1] == (
        "link up: telemetry 123 ms old")
    assert lines(telemetry_silence_s=math.inf)[1] == "link: NO TELEMETRY yet"
    assert lines(telemetry_silence_s=math.nan)[1] == "link: NO TELEMETRY yet"


def test_the_guard_line_names_the_mode_and_is_absent_when_unknown():
    # Catches: the mode shown as a number, a guard line for a chain without a robot guard.
    assert lines(robot_guard_mode=int(GuardMode.HELD))[2] == (
        "robot guard: held, 1.2 mrad from the commands")
    without = lines(robot_guard_mode=-1)
    assert without == NOMINAL_LINES[:2] + NOMINAL_LINES[3:]


def test_the_fifo_and_pre_simulator_line_shows_holding_collision_and_the_ik_upper_case():
    # Catches: an IK failure shown as given (lower case, easy to miss), a collision shown as
    # a distance, an unknown distance shown as "nan mm".
    assert lines(holding=True, collision=True, ik_failure="joint limit")[3] == (
        "FIFO HOLDING the robot; pre-simulator: COLLISION; IK: JOINT LIMIT (target held)")
    assert lines(min_distance_m=math.nan)[3] == "FIFO: moving; pre-simulator: —"
    assert lines(ik_failure="unreachable")[3] == (
        "FIFO: moving; pre-simulator: 46 mm clear; IK: UNREACHABLE (target held)")


def test_over_is_shown_when_a_ratio_exceeds_one():
    # Catches: OVER on acceleration only (or jerk only), OVER at exactly 1.
    over = " (OVER: the robot's guard cuts)"
    assert lines(jerk_ratio=np.array([0.75, 1.01]))[5] == (
        "sent acc/limit 0.50 0.25, jerk/limit 0.75 1.01" + over)
    assert lines(acceleration_ratio=np.array([1.5, 0.25]))[5] == (
        "sent acc/limit 1.50 0.25, jerk/limit 0.75 1.00" + over)


def test_prediction_off_above_the_warning_and_not_below():
    # Catches: the warning compared with the wrong side, ≥ instead of >, a NaN residual
    # shown as a number.
    assert lines(residual_m=0.0025)[6] == (
        "PREDICTION OFF: 2.50 mm from the measured robot (the model or the link differs)")
    assert lines(residual_m=0.002)[6] == "prediction: 2.000 mm from the measured robot"
    assert lines(residual_m=0.0019)[6] == "prediction: 1.900 mm from the measured robot"
    assert lines(residual_m=math.nan)[6] == "prediction: not measured yet"


def test_the_real_time_line_appears_when_the_rate_is_known():
    # Catches: the real-time rate or the late ticks not shown.
    assert lines(realtime_rate=0.98, late_ticks=3) == NOMINAL_LINES + [
        "real time 0.98×, late ticks 3"]


# Five sent commands of two joints, Δt = 0.5 s:
#   joint 0: 0, 0, 1, 3, 6   Δ 0 1 2 3     Δ² 1 1 1      Δ³ 0 0
#   joint 1: 0, 1, 0, 2, −1  Δ 1 −1 2 −3   Δ² −2 3 −5    Δ³ 5 −8
# acc/limit = max|Δ²| / Δt² / a:  joint 0 1/0.25/2 = 2,  joint 1 5/0.25/4 = 5
# jerk/limit = max|Δ³| / Δt³ / j: joint 0 0,              joint 1 8/0.125/16 = 4
SENT = np.array([[0.0, 0.0], [0.0, 1.0], [1.0, 0.0], [3.0, 2.0], [6.0, -1.0]])
A_MAX = np.array([2.0, 4.0])
J_MAX = np.array([1.0, 16.0])


def test_fd_ratios_by_hand_on_five_commands():
    # Catches: a first difference for the acceleration, one Δt too few, the signed maximum
    # (joint 1's largest Δ² is −5, not 3), one maximum over all joints, limits not per joint.
    acc, jerk = fd_ratios(SENT, 0.5, A_MAX, J_MAX)
    np.testing.assert_array_equal(acc, [2.0, 5.0])
    np.testing.assert_array_equal(jerk, [0.0, 4.0])


def test_fd_ratios_with_too_few_commands_are_zero():
    # Catches: a jerk taken from three commands, an error (or NaN) with fewer than needed.
    acc, jerk = fd_ratios(SENT[:3], 0.5, A_MAX, J_MAX)       # Δ² only: 1 and −2
    np.testing.assert_array_equal(acc, [2.0, 2.0])
    np.testing.assert_array_equal(jerk, [0.0, 0.0])
    for few in (SENT[:2], SENT[:1]):
        acc, jerk = fd_ratios(few, 0.5, A_MAX, J_MAX)
        np.testing.assert_array_equal(acc, [0.0, 0.0])
        np.testing.assert_array_equal(jerk, [0.0, 0.0])
    acc, jerk = fd_ratios(np.array([]), 0.5, A_MAX, J_MAX)
    assert acc.shape == jerk.shape == (0,)
