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
from telesmooth.safety.finite_differences import finite_differences
from telesmooth.safety.guard import GuardMode

__all__ = ["StatusInputs", "fd_ratios", "status_lines"]


class StatusInputs(NamedTuple):
    """What the status panel says (s, m, rad; NaN or inf where unknown; ``ik_failure``: why
    the inverse kinematics holds its target, "" when it does not; ``distance_horizon_m``: the
    pre-simulator's horizon, beyond which it reports the horizon itself as the distance)."""

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
    distance_horizon_m: float = math.inf


def fd_ratios(sent, period_s: float, max_acceleration, max_jerk):
    """max |FD acceleration| / limit and max |FD jerk| / limit per joint over the last sent
    commands ``sent`` (K, J) (K ≥ 4 for the jerk; fewer: zeros)."""
    sent = np.asarray(sent, dtype=float)
    joints = sent.shape[1] if sent.ndim == 2 else 0
    acc, jerk = np.zeros(joints), np.zeros(joints)
    if sent.ndim == 2 and sent.shape[0] >= 3:
        acc = np.max(np.abs(finite_differences(sent, period_s, 2)), axis=0) / max_acceleration
    if sent.ndim == 2 and sent.shape[0] >= 4:
        jerk = np.max(np.abs(finite_differences(sent, period_s, 3)), axis=0) / max_jerk
    return acc, jerk


def _numbers(values, fmt: str) -> str:
    return " ".join(format(float(v), fmt) for v in values)


_RELEASED = {ConsoleNotice.NO_BROWSER: "clutch released: no browser",
             ConsoleNotice.GAMEPAD_LOST: "clutch released: gamepad lost"}


def _largest(values) -> tuple[float, int]:
    """The largest of ``values`` and its joint (1-based); NaN and 0 when there are none."""
    values = np.asarray(values, dtype=float)
    if values.size == 0:
        return math.nan, 0
    j = int(np.argmax(values))
    return float(values[j]), j + 1


def _ratio(value: float) -> str:
    """A ratio in at most five characters (0.50, 12.35, 123, 1e+04)."""
    return (f"{value:.2f}" if abs(value) < 99.995 else f"{value:.0f}" if abs(value) < 999.5
            else f"{value:.0e}")


def status_lines(s: StatusInputs) -> list[str]:
    """The panel, one short line per subject (the control panel is 240 px wide; see the
    module docstring and docs/operator.md for what each line means)."""
    if s.stop:
        clutch = "STOPPED: Space to go on"
    elif s.enabled:
        clutch = "clutch ENGAGED: " + ("hand at REACH EDGE" if s.saturated else "you drive")
    else:
        clutch = _RELEASED.get(ConsoleNotice(int(s.notice)), "clutch released: Space to drive")
    lines = [clutch]
    # Without telemetry the robot's guard and the prediction's check are only as last heard.
    silent = not (s.telemetry_silence_s <= s.link_timeout_s)
    if not math.isfinite(s.telemetry_silence_s):
        lines.append("link: NO TELEMETRY yet")
    elif s.telemetry_silence_s > s.link_timeout_s:
        lines.append(f"link: NO TELEMETRY FOR {s.telemetry_silence_s:.1f} s")
    else:
        lines.append(f"link up: telemetry {1000 * s.telemetry_age_s:.0f} ms old")
    if s.robot_guard_mode >= 0:
        mode = GuardMode(int(s.robot_guard_mode)).label
        lines.append(f"robot guard: {mode} when last heard" if silent else
                     f"robot guard: {mode}, {1000 * s.stream_distance_rad:.1f} mrad off")
    fifo = "FIFO HOLD" if s.holding else "FIFO moving"
    if s.collision:
        presim = "COLLISION"
    elif math.isfinite(s.min_distance_m):
        at_least = "≥ " if s.min_distance_m >= s.distance_horizon_m else ""
        presim = at_least + (f"{1000 * s.min_distance_m:.0f} mm clear"
                             if s.min_distance_m < 0.9995 else f"{s.min_distance_m:.1f} m clear")
    else:
        presim = "clearance —"
    lines.append(f"{fifo}; {presim}")
    if s.ik_failure:
        lines.append(f"IK HOLDS: {s.ik_failure.upper()}")
    sigma, joint = _largest(s.sigma)
    if math.isfinite(sigma):
        lines.append(f"σ max {sigma:.1e} rad²/s⁷ (joint {joint})")
    else:
        lines.append("σ: not on the bus (see the report)")
    acc, jerk = _largest(s.acceleration_ratio)[0], _largest(s.jerk_ratio)[0]
    over = " OVER" if acc > 1.0 or jerk > 1.0 else ""
    lines.append(f"sent/limit{over}: acc {_ratio(acc)}, jerk {_ratio(jerk)}")
    if not math.isfinite(s.residual_m):
        lines.append("prediction: not measured yet")
    elif silent:
        lines.append("prediction: unchecked (no telemetry)")
    elif s.residual_m > s.residual_warning_m:
        lines.append(f"PREDICTION OFF by {1000 * s.residual_m:.2f} mm")
    else:
        lines.append(f"prediction: {1000 * s.residual_m:.3f} mm off")
    if math.isfinite(s.realtime_rate):
        lines.append(f"real time {s.realtime_rate:.2f}×, late ticks {int(s.late_ticks)}")
    return lines
