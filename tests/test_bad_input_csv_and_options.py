"""Bad input in CSV files and command-line options: classes 4 (ambiguity) and 5 (names).

The mechanisms: numbers are plain decimals (``user_input.parse_plain_number``: ASCII digits,
one '.', an exponent), so what ``float()`` also takes (``1_0e-3``, Arabic-Indic or full-width
digits, a no-break space) is an error, in CSV cells and in options alike; a joint may not be
named like a time column (``t``, ``sent_t``) nor twice in ``name=value`` limits; and messages
of the smoothing settings are renamed to the options that set them (``name_fields``).
"""

import pytest
from bad_input_helpers import assert_one_line_error, run, snapshot, write_trajectory
from hypothesis import given, settings
from hypothesis import strategies as st

from telesmooth.user_input import parse_plain_number

LIMITS = ["--acc-max", "0.05", "--jerk-max", "0.1"]


@pytest.fixture
def folder(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    write_trajectory(tmp_path)
    return tmp_path


CSV_CASES = {
    "underscore": ("t,a\n0,1_0e-3\n0.25,0\n0.5,0\n", "line 2, column 'a': '1_0e-3' is not a "
                                                     "number"),
    "arabic-indic digits": ("t,a\n0,\u0661\u0662\n0.25,0\n0.5,0\n", "'١٢' is not a number"),
    "full-width digit": ("t,a\n0,\uff11\n0.25,0\n0.5,0\n", "'１' is not a number"),
    "no-break space": ("t,a\n0,\u00a01\n0.25,0\n0.5,0\n", "'\\xa01' is not a number"),
    "underscore in time": ("t,a\n0,0\n0.2_5,0\n0.5,0\n", "line 3, column 't': '0.2_5'"),
    "joint named sent_t": ("t,sent_t,b\n0,0,0\n0.25,0,0\n", "joint column 1 is named 'sent_t', "
                                                            "a name reserved"),
    "joint named t": ("t,t,b\n0,0,0\n0.25,0,0\n", "joint column 1 is named 't'"),
    "joint named twice": ("t,a, a\n0,0,0\n0.25,0,0\n", "duplicate joint column name(s) ['a']"),
    "not an angle": ("t,a\n0,0\n0.25,2e6\n", "2000000.0 rad is beyond ±1e+06 rad"),
}


@pytest.mark.parametrize("case", CSV_CASES)
def test_ambiguous_csv_is_an_error_at_its_line(folder, capsys, case):
    text, words = CSV_CASES[case]
    (folder / "u.csv").write_text(text)
    before = snapshot(folder)
    status, stdout, stderr = run(capsys, "smooth", "u.csv", "-o", "o.csv", *LIMITS)
    assert_one_line_error(status, stdout, stderr, "smooth", "u.csv", words)
    assert snapshot(folder) == before


OPTION_CASES = {
    "joint named twice": (["--acc-max", "a=1,a=2,b=1", "--jerk-max", "1"],
                          "argument --acc-max: 'a=1,a=2,b=1': joint 'a' is given twice"),
    "unknown joint": (["--acc-max", "a=1,c=2", "--jerk-max", "1"],
                      "--acc-max: unknown joint name(s) ['c']"),
    "missing joint": (["--acc-max", "a=1", "--jerk-max", "1"],
                      "--acc-max: no value given for joint(s) ['b']"),
    "underscore": (["--acc-max", "1_0", "--jerk-max", "1"], "argument --acc-max: '1_0'"),
    "arabic-indic digit": (["--acc-max", "\u0661", "--jerk-max", "1"], "argument --acc-max"),
    "underscore --dt": ([*LIMITS, "--dt", "0.2_5"], "argument --dt: '0.2_5' is not a number"),
    "wrong count": (["--acc-max", "1,2,3", "--jerk-max", "1"],
                    "--acc-max has 3 value(s) [1.0, 2.0, 3.0] but there are 2 joints"),
    "negative sigma": ([*LIMITS, "--sigma", "-1"], "--sigma[0] = -1.0 for joint 0 ('a')"),
    "zero r": ([*LIMITS, "--r", "0"], "--r[0] = 0.0 for joint 0 ('a')"),
    "rho": ([*LIMITS, "--rho", "2"], "--rho = 2.0 must be in (0, 1)"),
    "sigma-min": ([*LIMITS, "--sigma-min", "-1"], "--sigma-min = -1.0 must be finite"),
    "lag": ([*LIMITS, "--lag", "-1"], "--lag = -1 must be an integer >= 0"),
    "vel-max": ([*LIMITS, "--method", "online-hard", "--vel-max", "-1"],
                "--vel-max[0] = -1.0 for joint 0 ('a')"),
}


@pytest.mark.parametrize("case", OPTION_CASES)
def test_options_are_named_as_written_and_ambiguity_is_refused(folder, capsys, case):
    argv, words = OPTION_CASES[case]
    before = snapshot(folder)
    status, stdout, stderr = run(capsys, "smooth", "in.csv", "-o", "o.csv", *argv)
    line = assert_one_line_error(status, stdout, stderr, "smooth", words)
    for internal in ("max_acceleration", "max_jerk", "max_velocity", "sigma_min", "dt_s"):
        assert internal not in line
    assert snapshot(folder) == before


@pytest.mark.parametrize("argv, words", [
    (["demo", "--shape", "Sshap", "--out", "out"], "--shape = 'Sshap' is not one of the 30 "
                                                   "LASA shapes; did you mean 'Sshape'"),
    (["demo", "--demo-index", "7", "--out", "out"], "--demo-index = 7 is out of range"),
    (["experiment", "--shapes", "Angle,Sshap", "--workers", "0", "--out", "out"],
     "--shapes = 'Sshap'"),
    (["experiment", "--quick", "--demos", "9", "--workers", "0", "--out", "out"],
     "--demos = [9] must be indices"),
    (["compare", "--methods", "online-cks,fast", "--out", "out"],
     "--methods = 'fast' is not one of the"),
])
def test_report_commands_name_their_options(tmp_path, monkeypatch, capsys, argv, words):
    monkeypatch.chdir(tmp_path)
    status, stdout, stderr = run(capsys, *argv)
    line = assert_one_line_error(status, stdout, stderr, argv[0], words)
    assert "shape = 'Sshap'" not in line.replace("--shape", "")
    assert list(tmp_path.iterdir()) == []


_PLAIN = st.from_regex(r"\A[ \t]*[+-]?([0-9]{1,8}\.?[0-9]{0,8}|\.[0-9]{1,8})([eE][+-]?[0-9]{1,3})?"
                       r"[ \t]*\Z")


@settings(derandomize=True, database=None, deadline=None, max_examples=100)
@given(text=st.one_of(_PLAIN, st.text(max_size=12)))
def test_plain_numbers_are_what_float_reads_from_ascii_digits_without_underscores(text):
    """Oracle: float() on text of only ASCII digits, signs, '.', 'e', ASCII spaces."""
    try:
        value = parse_plain_number(text)
    except ValueError:
        assert not set(text) <= set("0123456789+-.eE \t\r\n\v\f") or _float_fails(text)
    else:
        assert value == float(text) or (value != value and float(text) != float(text))
        if not set(text) <= set("0123456789+-.eE \t\r\n\v\f"):
            assert text.strip().lower().lstrip("+-") in ("nan", "inf", "infinity")


def _float_fails(text):
    try:
        float(text)
    except ValueError:
        return True
    return False
