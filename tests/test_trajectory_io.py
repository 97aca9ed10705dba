"""Tests for telesmooth.smoothing.trajectory_io: the joint trajectory CSV contract.

Every validation test asserts the exception type (ValueError) and the parts of the message a
user needs to find the problem: the line number as in the file, the column name and the value.
"""

import math

import numpy as np
import pytest

from telesmooth.smoothing.trajectory_io import (
    DEGREES_SUSPICION_RAD,
    read_joint_csv,
    write_joint_csv,
)


def write_text(tmp_path, text, name="traj.csv"):
    path = tmp_path / name
    path.write_text(text)
    return path


VALID_HEADER = "t,shoulder,elbow\n"
VALID_ROWS = "0.0,0.1,0.2\n0.25,0.11,0.21\n0.5,0.12,0.22\n"


# --- round trip ---


def test_write_read_round_trip_is_exact(tmp_path):
    rng = np.random.default_rng(0)
    dt = 0.1
    t = 3.0 + dt * np.arange(50)
    positions = rng.uniform(-1.0, 1.0, size=(50, 3)) * 10.0 ** rng.integers(-12, 1, (50, 3))
    # Values whose shortest repr needs all 17 significant digits, and signed zero.
    positions[0] = [1.0 / 3.0, -2.0 / 3.0, 0.1 + 0.2]
    positions[1] = [-0.0, 5e-324, 12.5]
    path = tmp_path / "out" / "round_trip.csv"  # parent folder is created
    write_joint_csv(path, t, positions, ["a", "b", "c"])

    dut = read_joint_csv(path)

    assert dut.joint_names == ("a", "b", "c")
    assert dut.num_joints == 3
    np.testing.assert_array_equal(dut.t_s, t)
    np.testing.assert_array_equal(dut.positions, positions)
    assert math.copysign(1.0, dut.positions[1, 0]) == -1.0  # -0.0 kept
    assert dut.dt_s == pytest.approx(dt, rel=1e-12)


def test_extra_columns_are_written_after_the_joints(tmp_path):
    t = np.array([0.0, 0.25, 0.5])
    positions = np.array([[0.1], [0.2], [0.3]])
    path = tmp_path / "extra.csv"
    write_joint_csv(path, t, positions, ["q"], extra_columns={"sent_t": t + 0.75})

    lines = path.read_text().splitlines()

    assert lines[0] == "t,q,sent_t"
    assert lines[1] == "0.0,0.1,0.75"
    assert lines[3] == "0.5,0.3,1.25"


def test_whitespace_and_blank_lines_are_tolerated(tmp_path):
    path = write_text(tmp_path, " t , a \n\n0.0, 1.5\n0.5 ,2.5\n\n")

    dut = read_joint_csv(path)

    assert dut.joint_names == ("a",)
    np.testing.assert_array_equal(dut.t_s, [0.0, 0.5])
    np.testing.assert_array_equal(dut.positions, [[1.5], [2.5]])


# --- header errors ---


@pytest.mark.parametrize("text", ["", "\n\n", " , \n"])
def test_empty_file_is_rejected(tmp_path, text):
    path = write_text(tmp_path, text)
    with pytest.raises(ValueError, match="the file is empty; expected a header 't,"):
        read_joint_csv(path)


def test_missing_file_is_a_value_error(tmp_path):
    with pytest.raises(ValueError, match="cannot read"):
        read_joint_csv(tmp_path / "nope.csv")


def test_header_must_start_with_t(tmp_path):
    path = write_text(tmp_path, "time,a\n0,1\n1,2\n")
    with pytest.raises(ValueError, match="first header column is 'time'; it must be 't'"):
        read_joint_csv(path)


def test_header_without_joint_columns_is_rejected(tmp_path):
    path = write_text(tmp_path, "t\n0\n1\n")
    with pytest.raises(ValueError, match="names no joint columns after 't'"):
        read_joint_csv(path)


@pytest.mark.parametrize(
    "header, column", [("t,,b", 1), ("t,a, ", 2), ("t,a,b,", 3)]
)
def test_empty_joint_name_is_rejected(tmp_path, header, column):
    n = header.count(",")
    rows = "".join(f"{k}" + ",0" * n + "\n" for k in range(3))
    path = write_text(tmp_path, header + "\n" + rows)
    with pytest.raises(ValueError, match=f"joint column {column} has an empty name"):
        read_joint_csv(path)


def test_duplicate_joint_names_are_rejected(tmp_path):
    path = write_text(tmp_path, "t,a,b,a,c,b\n0,1,2,3,4,5\n1,1,2,3,4,5\n")
    with pytest.raises(ValueError, match=r"duplicate joint column name\(s\) \['a', 'b'\]"):
        read_joint_csv(path)


# --- row and value errors ---


def test_short_row_names_its_line(tmp_path):
    path = write_text(tmp_path, VALID_HEADER + "0.0,0.1,0.2\n0.25,0.11\n0.5,0.12,0.22\n")
    with pytest.raises(ValueError, match="line 3 has 2 value\\(s\\); the header has 3"):
        read_joint_csv(path)


def test_long_row_names_its_line(tmp_path):
    path = write_text(tmp_path, VALID_HEADER + VALID_ROWS + "0.75,0.1,0.2,0.3\n")
    with pytest.raises(ValueError, match="line 5 has 4 value\\(s\\); the header has 3"):
        read_joint_csv(path)


@pytest.mark.parametrize("cell", ["abc", "", "0.1.2", "1e"])
def test_non_number_cell_names_line_column_and_value(tmp_path, cell):
    path = write_text(tmp_path, VALID_HEADER + f"0.0,0.1,0.2\n0.25,0.11,{cell}\n")
    with pytest.raises(ValueError) as error:
        read_joint_csv(path)
    message = str(error.value)
    assert f"line 3, column 'elbow': {cell!r} is not a number" in message
    assert str(path) in message


def test_non_number_time_names_column_t(tmp_path):
    path = write_text(tmp_path, VALID_HEADER + "0.0,0.1,0.2\nlater,0.11,0.21\n")
    with pytest.raises(ValueError, match="line 3, column 't': 'later' is not a number"):
        read_joint_csv(path)


@pytest.mark.parametrize("cell", ["nan", "NaN", "inf", "-inf", "Infinity"])
def test_non_finite_cell_names_line_column_and_value(tmp_path, cell):
    path = write_text(tmp_path, VALID_HEADER + f"0.0,0.1,0.2\n0.25,0.11,0.21\n0.5,{cell},0.22\n")
    with pytest.raises(ValueError) as error:
        read_joint_csv(path)
    assert f"line 4, column 'shoulder': value {cell!r} is not finite" in str(error.value)


def test_non_finite_time_is_rejected(tmp_path):
    path = write_text(tmp_path, VALID_HEADER + "0.0,0.1,0.2\nnan,0.11,0.21\n")
    with pytest.raises(ValueError, match="line 3, column 't': value 'nan' is not finite"):
        read_joint_csv(path)


def test_line_number_counts_blank_lines(tmp_path):
    # Line 1 header, line 2 blank, line 3 good, line 4 bad.
    path = write_text(tmp_path, "t,a\n\n0.0,1.0\n0.25,oops\n")
    with pytest.raises(ValueError, match="line 4, column 'a': 'oops' is not a number"):
        read_joint_csv(path)


@pytest.mark.parametrize("rows", ["", "0.0,0.1,0.2\n"])
def test_fewer_than_two_rows_is_rejected(tmp_path, rows):
    path = write_text(tmp_path, VALID_HEADER + rows)
    count = rows.count("\n")
    with pytest.raises(ValueError, match=f"{count} data row\\(s\\); at least 2 are needed"):
        read_joint_csv(path)


# --- time column ---


@pytest.mark.parametrize(
    "times, bad_row", [((0.0, 0.25, 0.25, 0.5), 3), ((0.0, 0.25, 0.5, 0.4), 4)]
)
def test_non_increasing_time_names_the_row(tmp_path, times, bad_row):
    rows = "".join(f"{t},0.1,0.2\n" for t in times)
    path = write_text(tmp_path, VALID_HEADER + rows)
    with pytest.raises(ValueError) as error:
        read_joint_csv(path)
    message = str(error.value)
    assert "time must increase" in message
    assert f"at data row {bad_row} follows" in message


def test_non_uniform_time_names_the_rows(tmp_path):
    rows = "".join(f"{t},0.1,0.2\n" for t in (0.0, 0.25, 0.5, 0.8, 1.0))
    path = write_text(tmp_path, VALID_HEADER + rows)
    with pytest.raises(ValueError) as error:
        read_joint_csv(path)
    message = str(error.value)
    assert "the time step must be uniform" in message
    assert "between data rows 3 and 4" in message  # t = 0.5 → 0.8, the largest deviation
    assert "mean step 0.25 s" in message
    assert "resample first" in message


def test_time_jitter_below_tolerance_is_accepted(tmp_path):
    t = 0.25 * np.arange(10)
    t[5] += 1e-8  # 4e-8 relative to the step: well below TIME_STEP_RTOL = 1e-6
    rows = "".join(f"{float(v)!r},0.1,0.2\n" for v in t)
    dut = read_joint_csv(write_text(tmp_path, VALID_HEADER + rows))
    assert dut.dt_s == pytest.approx(0.25, rel=1e-12)


def test_time_error_messages_show_plain_numbers(tmp_path):
    rows = "".join(f"{t},0.1,0.2\n" for t in (0.0, 0.25, 0.5, 0.8, 1.0))
    path = write_text(tmp_path, VALID_HEADER + rows)
    with pytest.raises(ValueError) as error:
        read_joint_csv(path)
    assert "np.float64" not in str(error.value)


def test_expected_dt_matches(tmp_path):
    dut = read_joint_csv(write_text(tmp_path, VALID_HEADER + VALID_ROWS), expected_dt_s=0.25)
    assert dut.dt_s == pytest.approx(0.25, rel=1e-15)


def test_expected_dt_mismatch_is_rejected(tmp_path):
    path = write_text(tmp_path, VALID_HEADER + VALID_ROWS)
    with pytest.raises(ValueError, match=r"the time step is 0\.25 s but --dt 0\.01 s was given"):
        read_joint_csv(path, expected_dt_s=0.01)


# --- degrees warning ---


def test_degrees_warning_goes_to_the_caller_and_file_is_read(tmp_path, capsys):
    path = write_text(tmp_path, "t,shoulder,elbow\n0,0.1,10\n1,0.2,90\n2,0.3,180\n")

    said = []
    dut = read_joint_csv(path, warn=said.append)

    assert len(said) == 1  # only the elbow
    assert said[0].startswith("warning: ") and "joint 'elbow' reaches 180 rad" in said[0]
    assert "were degrees meant?" in said[0]
    # The numerical core prints nothing itself.
    read_joint_csv(path)
    assert capsys.readouterr() == ("", "")
    np.testing.assert_array_equal(dut.positions[:, 1], [10.0, 90.0, 180.0])


def test_no_warning_just_below_the_threshold(tmp_path, capsys):
    value = DEGREES_SUSPICION_RAD * (1 - 1e-9)
    path = write_text(tmp_path, f"t,a\n0,{value!r}\n1,{-value!r}\n")
    read_joint_csv(path)
    assert capsys.readouterr().err == ""
