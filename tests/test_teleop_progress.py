"""The live sessions' progress lines (scripts/teleop.py), from stand-in handles with known
state: what the operator reads on the terminal once a second."""

from __future__ import annotations

import math
from types import SimpleNamespace

from telesmooth.safety.guard import GuardMode
from telesmooth.scripts.teleop import _operator_progress, _progress_line
from telesmooth.systems.wall_clock_monitor import LatenessStatistics


class _Stub:
    def __init__(self, **fields):
        self.__dict__.update(fields)

    def GetMyContextFromRoot(self, context):  # noqa: N802 (Drake's name)
        return context


def handles(view, state):
    return SimpleNamespace(
        predictor=_Stub(view=lambda context: view),
        console=None if state is None else _Stub(console_state=lambda context: state))


CONTEXT = SimpleNamespace(get_time=lambda: 12.34)
MONITOR = SimpleNamespace(late_ticks=3, statistics=lambda last_s: LatenessStatistics(
    100, 1, 0.0421, 0.01, 0.98))


def test_the_teleop_line_names_the_link_guard_clutch_and_residual():
    view = SimpleNamespace(telemetry_silence_s=0.1, telemetry_age_s=0.2504,
                           guard_mode=float(GuardMode.TRACK), residual_m=0.00123)
    line = _progress_line(handles(view, SimpleNamespace(stop=False, enabled=True)), CONTEXT,
                          MONITOR)
    assert line == ("teleop: t =   12.3 s, real time 0.98×, late ticks 3 (worst 42 ms), "
                    "link: telemetry 250 ms old, robot guard track, clutch "
                    "engaged, prediction residual 1.23 mm")


def test_silence_no_console_and_no_residual_read_as_such():
    view = SimpleNamespace(telemetry_silence_s=2.5, telemetry_age_s=math.nan, guard_mode=-1.0,
                           residual_m=math.nan)
    line = _progress_line(handles(view, None), CONTEXT, MONITOR)
    assert "link: no telemetry for 2.5 s, robot guard —, clutch released" in line
    assert line.endswith("prediction residual —")
    view.telemetry_silence_s = math.inf
    line = _operator_progress(handles(view, SimpleNamespace(stop=True, enabled=True)),
                              CONTEXT, MONITOR)
    assert line == ("operator: t =   12.3 s, real time 0.98×, no telemetry yet, clutch "
                    "stopped, prediction residual —")
    view.telemetry_silence_s = 0.5
    assert ", telemetry arriving, " in _operator_progress(
        handles(view, SimpleNamespace(stop=False, enabled=False)), CONTEXT, MONITOR)
