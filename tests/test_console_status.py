"""The operator's status panel (console/status.py): hand-made chain states → the lines the
panel shows, written out in full; ``fd_ratios`` against a hand computation. Each test's
comment says which wrong implementation it catches."""

import math

import numpy as np

from telesmooth.console.input import ConsoleNotice
from telesmooth.console.status import StatusInputs, fd_ratios, status_lines
from telesmooth.safety.guard import GuardMode
from telesmooth.systems.inverse_kinematics import IkStatus

NOMINAL = StatusInputs(
    enabled=True, stop=False, notice=int(ConsoleNotice.NONE), saturated=False,
    telemetry_age_s=0.123, telemetry_silence_s=0.05, robot_guard_mode=int(GuardMode.TRACK),
    stream_distance_rad=0.0012, holding=False, collision=False, min_distance_m=0.0456,
    ik_failure="", sigma=np.array([1.5e-3, 2.0e4]),
    acceleration_ratio=np.array([0.5, 0.25]), jerk_ratio=np.array([0.75, 1.0]),
    residual_m=0.0001234, residual_warning_m=0.002)

NOMINAL_LINES = [
    "clutch ENGAGED: you drive",
    "link up: telemetry 123 ms old",
    "robot guard: track, 1.2 mrad off",
    "FIFO moving; 46 mm clear",
    "σ max 2.0e+04 rad²/s⁷ (joint 2)",
    "sent/limit: acc 0.50, jerk 1.00",
    "prediction: 0.123 mm off",
]
# Meshcat's control panel is 240 px wide: about 40 characters of its font before a row is cut.
PANEL_CHARACTERS = 40


def lines(**changes):
    return status_lines(NOMINAL._replace(**changes))


def test_a_nominal_chain_reads_as_written():
    # Catches: units (s shown as ms, m as mm) or formats changed, a line lost or added (no
    # real-time line while the rate is unknown), "OVER" at a ratio of exactly 1, σ's or the
    # ratios' largest joint not the one shown.
    assert status_lines(NOMINAL) == NOMINAL_LINES


def test_the_clutch_line_engaged_released_stopped_and_why():
    # Catches: a stop shown as a plain release (the operator must know Enable clears it), a
    # notice lost or shown under a stop, the reach warning not shown.
    assert lines(enabled=False)[0] == "clutch released: Space to drive"
    assert lines(enabled=False, notice=int(ConsoleNotice.NO_BROWSER))[0] == (
        "clutch released: no browser")
    assert lines(enabled=False, notice=int(ConsoleNotice.GAMEPAD_LOST))[0] == (
        "clutch released: gamepad lost")
    assert lines(enabled=False, stop=True, notice=int(ConsoleNotice.STOPPED))[0] == (
        "STOPPED: Space to go on")
    assert lines(saturated=True)[0] == "clutch ENGAGED: hand at REACH EDGE"


def test_the_link_line_says_no_telemetry_after_the_timeout_and_not_before():
    # Catches: the age shown instead of the silence, ≥ instead of > at the timeout, a link
    # timeout that is not the one given.
    assert lines(telemetry_silence_s=3.2)[1] == "link: NO TELEMETRY FOR 3.2 s"
    assert lines(telemetry_silence_s=1.0)[1] == "link up: telemetry 123 ms old"
    assert lines(telemetry_silence_s=3.2, link_timeout_s=5.0)[1] == (
        "link up: telemetry 123 ms old")
    assert lines(telemetry_silence_s=math.inf)[1] == "link: NO TELEMETRY yet"
    assert lines(telemetry_silence_s=math.nan)[1] == "link: NO TELEMETRY yet"


def test_without_telemetry_the_guard_and_the_prediction_say_they_are_not_current():
    # Catches: the last guard distance and prediction residual shown as if measured now
    # while the link is silent (they are as last heard).
    silent = lines(telemetry_silence_s=3.2, robot_guard_mode=int(GuardMode.HELD))
    assert silent[2] == "robot guard: held when last heard"
    assert silent[6] == "prediction: unchecked (no telemetry)"
    assert lines(telemetry_silence_s=1.0)[2] == NOMINAL_LINES[2]
    assert lines(telemetry_silence_s=1.0)[6] == NOMINAL_LINES[6]


def test_the_guard_line_names_the_mode_and_is_absent_when_unknown():
    # Catches: the mode shown as a number, a guard line for a chain without a robot guard.
    assert lines(robot_guard_mode=int(GuardMode.HELD))[2] == "robot guard: held, 1.2 mrad off"
    without = lines(robot_guard_mode=-1)
    assert without == NOMINAL_LINES[:2] + NOMINAL_LINES[3:]


def test_the_fifo_and_pre_simulator_line_shows_holding_collision_and_the_ik_upper_case():
    # Catches: an IK failure shown as given (lower case, easy to miss), a collision shown as
    # a distance, an unknown distance shown as "nan mm".
    assert lines(holding=True, collision=True, ik_failure="joint limit")[3:5] == [
        "FIFO HOLD; COLLISION", "IK HOLDS: JOINT LIMIT"]
    assert lines(min_distance_m=math.nan)[3] == "FIFO moving; clearance —"
    assert lines(min_distance_m=1.25)[3] == "FIFO moving; 1.2 m clear"
    # Catches: the horizon, which the pre-simulator reports for anything farther, shown as
    # the distance itself.
    assert lines(min_distance_m=0.2, distance_horizon_m=0.2)[3] == "FIFO moving; ≥ 200 mm clear"
    assert lines(min_distance_m=0.199, distance_horizon_m=0.2)[3] == "FIFO moving; 199 mm clear"
    with_ik = lines(ik_failure="unreachable")
    assert with_ik == NOMINAL_LINES[:4] + ["IK HOLDS: UNREACHABLE"] + NOMINAL_LINES[4:]


def test_sigma_shows_the_largest_joint_and_says_when_it_is_not_on_the_bus():
    # Catches: the first joint's σ shown, joints counted from 0, NaN shown as a number.
    assert lines(sigma=np.array([3.0e-2, 1.0e-5, 2.9e-2]))[4] == (
        "σ max 3.0e-02 rad²/s⁷ (joint 1)")
    assert lines(sigma=np.full(2, math.nan))[4] == "σ: not on the bus (see the report)"


def test_over_is_shown_when_a_ratio_exceeds_one_and_large_ratios_stay_short():
    # Catches: OVER on acceleration only (or jerk only), OVER at exactly 1, the largest joint
    # not the one shown, a large ratio that widens the row past the panel.
    assert lines(jerk_ratio=np.array([0.75, 1.01]))[5] == "sent/limit OVER: acc 0.50, jerk 1.01"
    assert lines(acceleration_ratio=np.array([1.5, 0.25]))[5] == (
        "sent/limit OVER: acc 1.50, jerk 1.00")
    assert lines(acceleration_ratio=np.array([0.2, 123.4]),
                 jerk_ratio=np.array([45678.0, 0.0]))[5] == "sent/limit OVER: acc 123, jerk 5e+04"


def test_prediction_off_above_the_warning_and_not_below():
    # Catches: the warning compared with the wrong side, ≥ instead of >, a NaN residual
    # shown as a number.
    assert lines(residual_m=0.0025)[6] == "PREDICTION OFF by 2.50 mm"
    assert lines(residual_m=0.002)[6] == "prediction: 2.000 mm off"
    assert lines(residual_m=0.0019)[6] == "prediction: 1.900 mm off"
    assert lines(residual_m=math.nan)[6] == "prediction: not measured yet"


def test_the_real_time_line_appears_when_the_rate_is_known():
    # Catches: the real-time rate or the late ticks not shown.
    assert lines(realtime_rate=0.98, late_ticks=3) == NOMINAL_LINES + [
        "real time 0.98×, late ticks 3"]


def test_every_line_fits_the_panel_in_the_longest_states():
    # Catches: a row the page cuts off (the panel does not wrap): a 6-DOF arm's per-joint
    # numbers, every alarm at once, large values.
    six = np.array([1.2e-3, 9.9e4, 3.0e-6, 1.0, 2.0, 3.0])
    worst = NOMINAL._replace(
        enabled=False, notice=int(ConsoleNotice.GAMEPAD_LOST), saturated=True,
        telemetry_silence_s=1234.5,
        robot_guard_mode=int(max(GuardMode, key=lambda mode: len(mode.label))),
        stream_distance_rad=12.3456, holding=True, collision=True,
        ik_failure=max((status.name.lower().replace("_", " ") for status in IkStatus), key=len),
        sigma=six,
        acceleration_ratio=six, jerk_ratio=six, residual_m=12.345,
        realtime_rate=0.123, late_ticks=123456)
    for state in (NOMINAL, worst, worst._replace(enabled=True, telemetry_silence_s=0.0,
                                                 telemetry_age_s=99.9, collision=False,
                                                 min_distance_m=1.234)):
        for line in status_lines(state):
            assert len(line) <= PANEL_CHARACTERS, line


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
