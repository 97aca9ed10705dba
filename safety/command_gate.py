"""The robot's command gate as a pure step: which held command becomes the ramp the motors
follow, and which is refused.

At every poll the gate reads the held command q (and, if known, the instant it was issued):

* q equal to the current target: nothing to do (a rejected flag clears);
* q the same unsafe command already refused: nothing to do (it is counted once);
* q unsafe (not finite, or outside the joint limits, :func:`command_violation`): refused, the
  target held, the flag raised, the command counted;
* otherwise a new ramp towards q from where the set-point is now (the ``"linear"``
  interpolation: :func:`ramp_desired_state` at the start instant), or a step to q
  (``"zoh"``), starting at the issue instant when it lies between the last ramp's start and
  now, else now.

:class:`~telesmooth.systems.command_interpolator.CommandGate` is the thin Drake system around
:func:`gate_step`; it keeps the :class:`Ramp` as a state of its own, [t₀, q₀ (n), q₁ (n)],
which its ``ramp`` output is without a Python call.
"""

from __future__ import annotations

import dataclasses
import math
from typing import NamedTuple

import numpy as np

__all__ = ["GateParams", "GateState", "Ramp", "Refusals", "command_violation",
           "gate_initial_state", "gate_step", "ramp_desired_state"]


@dataclasses.dataclass(frozen=True)
class GateParams:
    """What the gate checks against and how it ramps."""

    joint_names: tuple[str, ...]
    lower_rad: np.ndarray
    upper_rad: np.ndarray
    interpolation: str          # "linear" or "zoh"
    ramp_duration_s: float


class Ramp(NamedTuple):
    """The ramp in progress, [t₀, q₀ (n), q₁ (n)] as a vector (the ``ramp`` port)."""

    start_s: float               # t₀
    start: np.ndarray            # q₀ (n,)
    target: np.ndarray           # q₁ (n,)


class Refusals(NamedTuple):
    """The commands refused."""

    rejected: bool               # the held command is refused
    count: int                   # distinct refused commands so far
    last: np.ndarray             # (n,) the last one refused (NaN before any)


class GateState(NamedTuple):
    """The gate between polls."""

    ramp: Ramp
    refusals: Refusals


def gate_initial_state(initial_position) -> GateState:
    """Holding ``initial_position`` from t = 0, nothing refused."""
    q0 = np.array(initial_position, dtype=float)
    return GateState(ramp=Ramp(start_s=0.0, start=q0.copy(), target=q0.copy()),
                     refusals=Refusals(rejected=False, count=0,
                                       last=np.full(q0.size, np.nan)))


def gate_step(params: GateParams, state: GateState, command, now: float,
              issued: float | None = None) -> tuple[GateState, str | None]:
    """The gate after a poll at ``now`` that reads ``command`` (issued at ``issued``, if
    known): the new state and, if the command was refused now, why (module docstring)."""
    ramp, refusals = state
    if np.array_equal(command, ramp.target):
        return (state._replace(refusals=refusals._replace(rejected=False))
                if refusals.rejected else state), None
    if refusals.rejected and np.array_equal(command, refusals.last, equal_nan=True):
        return state, None
    reason = command_violation(command, params.lower_rad, params.upper_rad, params.joint_names)
    if reason is not None:
        return state._replace(refusals=Refusals(
            rejected=True, count=refusals.count + 1,
            last=np.array(command, dtype=float))), reason
    start_time = now
    if issued is not None and math.isfinite(issued) and ramp.start_s <= issued <= now:
        start_time = issued
    if params.interpolation == "linear":
        start, _ = ramp_desired_state(ramp.start, ramp.target, ramp.start_s,
                                      params.ramp_duration_s, start_time)
    else:
        start = command
    return GateState(ramp=Ramp(start_s=float(start_time), start=np.array(start, dtype=float),
                               target=np.array(command, dtype=float)),
                     refusals=refusals._replace(rejected=False)), None


def ramp_desired_state(
    ramp_start_rad: np.ndarray,
    ramp_target_rad: np.ndarray,
    ramp_start_time_s: float,
    ramp_duration_s: float,
    time_s: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Desired position and velocity on a linear ramp at ``time_s``.

    With q₀ = ``ramp_start_rad``, q₁ = ``ramp_target_rad``, t₀ = ``ramp_start_time_s``,
    T = ``ramp_duration_s`` and s = clip((t − t₀)/T, 0, 1):

        q_d(t) = q₀ + s·(q₁ − q₀)
        v_d(t) = (q₁ − q₀)/T   if t₀ ≤ t < t₀ + T,   else 0.

    A step (``"zoh"``) is the degenerate ramp q₀ = q₁.

    Args:
        ramp_start_rad: q₀, rad; shape (n,).
        ramp_target_rad: q₁, rad; shape (n,).
        ramp_start_time_s: t₀, s.
        ramp_duration_s: T, s (> 0).
        time_s: t, s.

    Returns:
        (q_d, v_d): rad and rad/s, each shape (n,).
    """
    start = np.asarray(ramp_start_rad, dtype=float)
    target = np.asarray(ramp_target_rad, dtype=float)
    elapsed = time_s - ramp_start_time_s
    if elapsed < 0.0 or elapsed >= ramp_duration_s:
        velocity = np.zeros_like(target)
    else:
        velocity = (target - start) / ramp_duration_s
    fraction = min(max(elapsed / ramp_duration_s, 0.0), 1.0)
    # At s = 1 return the target itself, not q₀ + (q₁ − q₀), which can differ in the last bit.
    position = target.copy() if fraction >= 1.0 else start + fraction * (target - start)
    return position, velocity


def command_violation(
    q_rad: np.ndarray, lower_rad: np.ndarray, upper_rad: np.ndarray, joint_names
) -> str | None:
    """Why a joint command is unsafe, or None if it is finite and within the joint limits.

    Args:
        q_rad: The command, rad; shape (n,).
        lower_rad, upper_rad: Joint limits, rad; shape (n,). A command exactly on a limit
            is accepted.
        joint_names: Joint names, used in the message; length n.

    Returns:
        None, or a message naming the first offending joint and its value, e.g.
        ``"q_commanded[1] (elbow) = nan is not finite"``.
    """
    q = np.asarray(q_rad, dtype=float)
    if q.shape != np.shape(lower_rad):
        return f"q_commanded has shape {q.shape}, expected {np.shape(lower_rad)}"
    for index, (value, lower, upper) in enumerate(zip(q, lower_rad, upper_rad)):
        label = f"q_commanded[{index}] ({joint_names[index]}) = {float(value)!r}"
        if not math.isfinite(value):
            return f"{label} is not finite"
        if not lower <= value <= upper:
            return f"{label} is outside the joint limits [{float(lower)!r}, {float(upper)!r}]"
    return None
