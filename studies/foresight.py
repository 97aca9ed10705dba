"""How much of a method's deformation no rule could have avoided without knowing more of the
operator's motion (`telesmooth foresight`; the optimisation is
:mod:`telesmooth.smoothing.foresight`).

For the scenario's recording (through the ground station's IK at the uplink rate, as
`telesmooth compare` samples it) and one method, the best continuation of the method's
commands from every ``step``-th sample s: the commands closest to the operator within the FD
limits that could still follow the method's first s commands, knowing the whole future.
"""

from __future__ import annotations

import math
import time

import numpy as np

from telesmooth.diagrams.simulation import tool_positions
from telesmooth.smoothing.foresight import foresight_sweep
from telesmooth.smoothing.methods import METHOD_ALIASES, METHODS, method_name, smooth_recording
from telesmooth.smoothing.metrics import cartesian_deformation, finite_differences
from telesmooth.smoothing.offline import HISTORY_LENGTH, with_rest_history
from telesmooth.studies.comparison import method_settings, operator_samples

__all__ = ["SHARES", "foresight_study"]


SHARES = (0.5, 0.8)
"""The report names the first start whose bound reaches these shares of the method's E_def."""


def foresight_study(scenario, method: str = "online-hard", *, step: int = 4,
                    progress=None) -> dict:
    """The method's commands on the scenario's recording and their best continuations
    (``progress``: called with a line every 25 starts, if given).

    Returns:
        A JSON-ready dict: ``scenario``, ``method`` (E_def, delay), ``rows`` (one per start),
        ``commitment`` (per share in :data:`SHARES`, the first start whose continuation's
        E_def reaches that share of the method's; empty when the method breaks the limits).
        Each row's ``bound_share`` is the bound over the method's own remaining squared joint
        deviation (summed over joints): the part of it no method with the same first s
        commands could avoid.

    Raises:
        ValueError: an unknown method, a bad step, a scenario without a recording.
        RuntimeError: the method failed.
    """
    if not isinstance(method, str) or (method not in METHODS and method not in METHOD_ALIASES):
        raise ValueError(f"method = {method!r} must be one of {METHODS}")
    method = method_name(method)
    if isinstance(step, bool) or not isinstance(step, int) or step < 1:
        raise ValueError(f"step = {step!r} must be an integer >= 1")
    samples = operator_samples(scenario)
    z = samples.q
    period = scenario.uplink.period_s
    names = scenario.arm_description.joint_names
    base_method, settings = method_settings(scenario, method)
    smoothed = smooth_recording(z, period, base_method, settings, joint_names=names)
    commands = smoothed.positions
    limits = dict(max_acceleration=settings.max_acceleration, max_jerk=settings.max_jerk,
                  max_velocity=settings.max_velocity, rest=z[0], joint_names=names)

    def fk(q):
        return tool_positions(scenario, q)

    method_e_def = cartesian_deformation(commands, z, fk)["mean"]
    started = time.perf_counter()

    def report_progress(done, total):
        if progress is not None and (done % 25 == 0 or done == total):
            progress(f"  foresight: {done}/{total} starts "
                     f"({time.perf_counter() - started:.1f} s)")

    sweep = foresight_sweep(commands, z, period, step=step, progress=report_progress,
                            **limits)
    rows = []
    for start, method_error, result in zip(sweep.starts.tolist(), sweep.method_squared_error,
                                           sweep.continuations):
        ok = bool(result.is_success.all())
        method_sum = float(np.sum(method_error))
        rows.append({
            "start": start, "t_s": float(samples.t_s[start]),
            "method_squared_error_rad2": method_error.tolist(),
            "bound_squared_error_rad2": result.squared_error.tolist(),
            "e_def_m": cartesian_deformation(result.positions, z, fk)["mean"] if ok
            else math.nan,
            "bound_share": (float(np.sum(result.squared_error)) / method_sum
                            if ok and method_sum > 0 else math.nan),
            "is_success": result.is_success.tolist(), "status": list(result.status)})
    violation = _first_violation(commands, z[0], period, settings)
    commitment = {}
    for share in SHARES if violation is None else ():
        first = next((row for row in rows
                      if row["e_def_m"] >= share * method_e_def), None)
        commitment[f"{share:g}"] = None if first is None else {
            "start": first["start"], "t_s": first["t_s"], "e_def_m": first["e_def_m"],
            "bound_share": first["bound_share"]}
    a_max = np.broadcast_to(np.asarray(settings.max_acceleration, dtype=float), (z.shape[1],))
    operator_acc = np.zeros(z.shape)
    operator_acc[2:] = finite_differences(z, period, 2)
    return {
        "scenario": {"arm": scenario.arm, "haptic_source": scenario.haptic.source,
                     "period_s": period, "num_samples": int(z.shape[0]),
                     "joint_names": list(names), "step": step},
        "method": {"name": method, "e_def_m": method_e_def,
                   "sent_delay_s": smoothed.sent_delay_s,
                   "first_limit_violation_sample": violation},
        "rows": rows,
        "commitment": commitment,
        "operator_acc_over_limit": (np.abs(operator_acc) / a_max).max(axis=1).tolist(),
        "t_s": samples.t_s.tolist(),
    }


def _first_violation(commands, rest, period: float, settings) -> int | None:
    """The first sample whose command breaks an FD limit (after rest at ``rest``), or None.
    Relative slack 1e-9: the limiter's own rounding margin."""
    n = commands.shape[1]
    history = with_rest_history(commands, rest, hold_at_end=0)
    worst = np.zeros(commands.shape[0], dtype=bool)
    for order, limit in ((1, settings.max_velocity), (2, settings.max_acceleration),
                         (3, settings.max_jerk)):
        if limit is None:
            continue
        bound = np.broadcast_to(np.asarray(limit, dtype=float), (n,)) * (1 + 1e-9)
        values = np.abs(finite_differences(history, period, order)[HISTORY_LENGTH - order:])
        worst |= np.any(values > bound, axis=1)
    hits = np.flatnonzero(worst)
    return int(hits[0]) if hits.size else None
