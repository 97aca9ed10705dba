"""The operator's status panel as text: what the display shows beside the robots (pure).

:func:`status_lines` turns the chain's state (the clutch, the link, the robot's guard, the
FIFO, the pre-simulator, σ, the sent commands against the limits, the prediction) into a few
short lines, the alarms first-class: a released clutch, a stop, silence on the link, a
collision, a prediction that is off. The display puts them in the page's control panel.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from telesmooth.console.input import ConsoleNotice
from telesmooth.safety.guard import GuardMode

__all__ = ["StatusInputs", "fd_ratios", "status_lines"]


class StatusInputs(NamedTuple):
    """What the status panel says (s, m, rad; NaN or inf where unknown; ``ik_failure``: why
    the inverse kinematics holds its target, "" when it does not)."""

    enabled: bool
    stop: bool
    notice: int
    saturated: bool
    telemetry_age_s: float
    telemetry_silence_s: float
    robot_guard_mode: int
    stream_distance_rad: float
    holding: bool
    collision: bool
    min_distance_m: float
    ik_failure: str
    sigma: np.ndarray
    acceleration_ratio: np.ndarray
    jerk_ratio: np.ndarray
    residual_m: float
    residual_warning_m: float
    realtime_rate: float = math.nan
    late_ticks: int = 0
    link_timeout_s: float = 1.0


def fd_ratios(sent, period_s: float, max_acceleration, max_jerk):
    """max |FD acceleration| / limit and max |FD jerk| / limit per joint over the last sent
    commands ``sent`` (K, J) (K ≥ 4 for the jerk; fewer: zeros)."""
    sent = np.asarray(sent, dtype=float)
    joints = sent.shape[1] if sent.ndim == 2 else 0
    acc, jerk = np.zeros(joints), np.zeros(joints)
    if sent.ndim == 2 and sent.shape[0] >= 3:
        acc = np.max(np.abs(np.diff(sent, 2, axis=0)), axis=0) / period_s**2 / max_acceleration
    if sent.ndim == 2 and sent.shape[0] >= 4:
        jerk = np.max(np.abs(np.diff(sent, 3, axis=0)), axis=0) / period_s**3 / max_jerk
    return acc, jerk


def _numbers(values, fmt: str) -> str:
    return " ".join(format(float(v), fmt) for v in values)


def status_lines(s: StatusInputs) -> list[str]:
    """The panel, one line per subject (see the module docstring)."""
    if s.stop:
        clutch = "STOPPED: press Enable (Space) to go on"
    elif s.enabled:
        clutch = "clutch ENGAGED: you drive the robot"
    else:
        clutch = "clutch released: press Enable (Space) to drive"
    notice = ConsoleNotice(int(s.notice)).text
    if notice and not s.stop:
        clutch += f" ({notice})"
    if s.saturated:
        clutch += "; hand at the edge of the reach"
    lines = [clutch]
    if not math.isfinite(s.telemetry_silence_s):
        lines.append("link: NO TELEMETRY yet")
    elif s.telemetry_silence_s > s.link_timeout_s:
        lines.append(f"link: NO TELEMETRY FOR {s.telemetry_silence_s:.1f} s: the predicted "
                     "robot runs on the commands sent")
    else:
        lines.append(f"link up: telemetry {1000 * s.telemetry_age_s:.0f} ms old")
    if s.robot_guard_mode >= 0:
        mode = GuardMode(int(s.robot_guard_mode)).label
        lines.append(f"robot guard: {mode}, {1000 * s.stream_distance_rad:.1f} mrad from "
                     "the commands")
    fifo = "FIFO HOLDING the robot" if s.holding else "FIFO: moving"
    if s.collision:
        presim = "pre-simulator: COLLISION"
    elif math.isfinite(s.min_distance_m):
        presim = f"pre-simulator: {1000 * s.min_distance_m:.0f} mm clear"
    else:
        presim = "pre-simulator: —"
    if s.ik_failure:
        presim += f"; IK: {s.ik_failure.upper()} (target held)"
    lines.append(f"{fifo}; {presim}")
    if np.all(np.isfinite(s.sigma)):
        lines.append(f"σ [rad²/s⁷]: {_numbers(s.sigma, '.1e')}")
    else:
        lines.append("σ: not sent on the bus (the ground's report has it)")
    over = bool(np.any(s.acceleration_ratio > 1.0) or np.any(s.jerk_ratio > 1.0))
    lines.append(f"sent acc/limit {_numbers(s.acceleration_ratio, '.2f')}, jerk/limit "
                 f"{_numbers(s.jerk_ratio, '.2f')}" + (" (OVER: the robot's guard cuts)"
                                                       if over else ""))
    if not math.isfinite(s.residual_m):
        lines.append("prediction: not measured yet")
    elif s.residual_m > s.residual_warning_m:
        lines.append(f"PREDICTION OFF: {1000 * s.residual_m:.2f} mm from the measured robot "
                     "(the model or the link differs)")
    else:
        lines.append(f"prediction: {1000 * s.residual_m:.3f} mm from the measured robot")
    if math.isfinite(s.realtime_rate):
        lines.append(f"real time {s.realtime_rate:.2f}×, late ticks {int(s.late_ticks)}")
    return lines
