"""Bad input, class 3: no input ends in a traceback or in a message that names nothing.

The mechanism: expected failures are ValueErrors raised where the user's names are known
(an ``OSError`` on a file becomes one naming the option; Ruckig's refusals name the sample and
joint; the run length is checked against the FIFO delay before simulating), and the command
line's one handler (``run_reporting_errors``) prints any ValueError, RuntimeError or OSError as
one line (exit 2) and anything else as one line with the hint to rerun with ``--debug`` (exit
1); ``--debug`` shows the traceback.
"""

import pytest
from bad_input_helpers import assert_one_line_error, run, snapshot, write_trajectory

from telesmooth.scripts import cli

LIMITS = ["--acc-max", "0.05", "--jerk-max", "0.1"]


@pytest.fixture
def folder(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    write_trajectory(tmp_path)
    write_trajectory(tmp_path, "far.csv", jump=9e5)    # a step far too large for tiny limits
    (tmp_path / "dir").mkdir()
    return tmp_path


CASES = {
    # OSErrors on inputs
    "missing input": (["smooth", "nope.csv", "-o", "o.csv", *LIMITS],
                      ("nope.csv: cannot read it (No such file or directory)",)),
    "input is a folder": (["smooth", "dir", "-o", "o.csv", *LIMITS], ("dir is a folder",)),
    "missing scenario": (["simulate", "--scenario", "nope.yaml", "--out", "out"],
                         ("--scenario = 'nope.yaml': cannot read it",)),
    # Ruckig (RuckigError; '-101 is not a valid Result' for a huge step)
    "ruckig tiny limits": (["smooth", "in.csv", "-o", "o.csv", "--method", "ruckig",
                            "--acc-max", "1e-300", "--jerk-max", "1e-300", "--vel-max",
                            "1e-300"], ("ruckig: sample 1", "for joint 0 ('a')")),
    "ruckig huge limits": (["smooth", "in.csv", "-o", "o.csv", "--method", "ruckig",
                            "--acc-max", "1e300", "--jerk-max", "1e300", "--vel-max",
                            "1e300"],
                           ("ruckig: sample 1", "for joint 0 ('a')")),
    "ruckig huge step": (["smooth", "far.csv", "-o", "o.csv", "--method", "ruckig",
                          "--acc-max", "1e-3", "--jerk-max", "1e-3"],
                         ("ruckig: sample 20 (t = 5 s)", "for joint 0 ('a')",
                          "would last longer than Ruckig allows")),
    # YAML mappings with non-string or mixed keys
    "int key": (["simulate", "--scenario-text", "{1: 2}", "--out", "out"],
                ("--scenario-text: line 1: the key '1' in the top level is an integer",)),
    "null key": (["simulate", "--scenario-text", "{~: 2}", "--out", "out"],
                 ("the key '~' in the top level is null",)),
    "mixed keys": (["simulate", "--scenario-text", "{arm: space_arm, 3: 4}", "--out", "out"],
                   ("the key '3' in the top level is an integer",)),
    # periods, durations, run lengths
    "zero period": (["simulate", "--scenario-text", "{haptic: {period_s: 0}}", "--out", "out"],
                    ("haptic.period_s = 0.0 must be positive",)),
    "negative 4 Hz period": (["simulate", "--scenario-text", "{fifo: {period_s: -1}, "
                              "smoother: {period_s: -1}, uplink: {period_s: -1}}", "--out",
                              "out"], ("fifo.period_s = -1.0",)),
    "infinite duration": (["simulate", "--duration", "inf", "--out", "out"],
                          ("--duration = inf must be finite",)),
    "infinite scenario duration": (["simulate", "--scenario-text",
                                    "{simulation_duration_s: .inf}", "--out", "out"],
                                   ("simulation_duration_s = inf",)),
    "infinite process duration": (["onboard", "--lcm-url", "memq://", "--no-auth",
                                   "--duration", "inf"], ("--duration = inf must be finite",)),
    "shorter than the FIFO delay": (["simulate", "--duration", "0.8", "--out", "out"],
                                    ("--duration = 0.8 s is shorter than the FIFO delay",
                                     "(1.01 s): no command's response would be measured")),
    "scenario shorter than the FIFO delay": (["simulate", "--scenario-text",
                                              "{simulation_duration_s: 0.5}", "--out", "out"],
                                             ("simulation_duration_s = 0.5 s is shorter",)),
    "settle far too long": (["simulate", "--scenario-text", "{settle_s: 1.0e+9}", "--out", "out"],
                            ("settle_s = 1000000000.0 s is longer than the limit",)),
    "experiment plant step": (["experiment", "--quick", "--plant-step", "1e-9", "--workers",
                               "0", "--out", "out"], ("--plant-step = 1e-09 s is below",)),
    "LCM URL": (["onboard", "--lcm-url", "udpm://300.1.2.3:7667?ttl=0", "--no-auth",
                 "--duration", "1"], ("--lcm-url = 'udpm://300.1.2.3:7667?ttl=0'",)),
    "LCM URL scheme": (["ground", "--lcm-url", "file:///tmp/log?mode=w", "--no-auth"],
                       ("--lcm-url = 'file:///tmp/log?mode=w' must be an LCM URL",)),
}


@pytest.mark.parametrize("case", CASES)
def test_expected_failures_are_one_line_naming_what_the_user_wrote(folder, capsys, case):
    argv, words = CASES[case]
    before = snapshot(folder)
    status, stdout, stderr = run(capsys, *argv)
    assert_one_line_error(status, stdout, stderr, argv[0], *words)
    assert snapshot(folder) == before


def test_an_unexpected_exception_is_one_line_with_the_debug_hint(folder, capsys, monkeypatch):
    def broken(args):
        raise KeyError("internal table")

    monkeypatch.setattr(cli, "run_smooth", broken)
    parser = cli.build_parser
    monkeypatch.setattr(cli, "build_parser", lambda: _with_handler(parser(), broken))
    status, _, stderr = run(capsys, "smooth", "in.csv", "-o", "o.csv", *LIMITS)
    assert status == 1
    lines = stderr.strip().splitlines()
    assert len(lines) == 1 and len(lines[0]) <= 300
    assert lines[0].startswith("telesmooth smooth: internal error: KeyError: 'internal table'")
    assert "rerun with --debug for the traceback" in lines[0]
    with pytest.raises(KeyError, match="internal table"):
        cli.main(["smooth", "in.csv", "-o", "o.csv", *LIMITS, "--debug"])


def _with_handler(parser, handler):
    parser._subparsers._group_actions[0].choices["smooth"].set_defaults(handler=handler)
    return parser


def test_debug_shows_the_traceback_of_an_expected_error_too(folder):
    with pytest.raises(ValueError, match="--dt = 0.0"):
        cli.main(["--debug", "smooth", "in.csv", "-o", "o.csv", *LIMITS, "--dt", "0"])


def test_recursion_and_memory_errors_are_bugs_not_bad_input(capsys):
    for error in (RecursionError("deep"), MemoryError("big")):
        def handler(error=error):
            raise error
        status = cli.run_reporting_errors("x", handler)
        line = capsys.readouterr().err.strip()
        assert status == 1 and f"internal error: {type(error).__name__}" in line


def test_one_line_collapses_and_cuts_any_message():
    text = cli.one_line("first\nsecond\t third " + "x" * 1000)
    assert "\n" not in text and len(text) == cli.MAX_MESSAGE_CHARS and text.endswith("…")
    assert text.startswith("first second third x")
