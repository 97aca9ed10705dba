"""`telesmooth foresight`: how much of a method's deformation no rule could have avoided
without knowing more of the operator's motion (:mod:`telesmooth.smoothing.foresight`).

For the scenario's recording (through the ground station's IK at the uplink rate, as
`telesmooth compare` samples it) and one method, the best continuation of the method's
commands from every ``step``-th sample s: the commands closest to the operator within the FD
limits that could still follow the method's first s commands, knowing the whole future.

Output folder:
    foresight.json  per start s: time, the method's and the continuation's remaining squared
                    joint deviation (the continuation's is a lower bound for every method within
                    the limits with the same first s commands), the continuation's Cartesian
                    deformation E_def, the solver status per joint
    foresight.png   E_def of the best continuation from s against s, the method's own E_def,
                    and the operator's FD acceleration against a_max
    report.md       the summary, the table and the figure
"""

from __future__ import annotations

import json
import math
import time
from pathlib import Path

import numpy as np

from telesmooth.atomic_files import write_text
from telesmooth.diagrams.simulation import tool_positions
from telesmooth.scripts.figures import FigureWriter
from telesmooth.scripts.formatting import log as _log
from telesmooth.smoothing.foresight import foresight_sweep
from telesmooth.smoothing.methods import METHOD_ALIASES, METHODS, method_name, smooth_recording
from telesmooth.smoothing.metrics import cartesian_deformation, finite_differences
from telesmooth.smoothing.offline import HISTORY_LENGTH, with_rest_history
from telesmooth.studies.comparison import method_settings, operator_samples

__all__ = ["foresight_study", "write_foresight_report"]

SHARES = (0.5, 0.8)
"""The report names the first start whose bound reaches these shares of the method's E_def."""


def foresight_study(scenario, method: str = "online-hard", *, step: int = 4,
                    progress=_log) -> dict:
    """The method's commands on the scenario's recording and their best continuations.

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


def _figure(out: Path, study: dict) -> list[tuple[str, str]]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    writer = FigureWriter(out)
    rows = study["rows"]
    fig, (top, bottom) = plt.subplots(2, 1, figsize=(8, 6), sharex=True)
    t = [row["t_s"] for row in rows]
    top.plot(t, [1e3 * row["e_def_m"] for row in rows], "o-", ms=3,
             label="best continuation from t (whole future known)")
    top.axhline(1e3 * study["method"]["e_def_m"], color="C3",
                label=f"{study['method']['name']} itself")
    top.set_ylabel("E_def [mm]")
    top.legend(loc="best", fontsize=8)
    top.grid(alpha=0.3)
    bottom.plot(study["t_s"], study["operator_acc_over_limit"], color="C2")
    bottom.axhline(1.0, color="k", lw=0.8, ls="--")
    bottom.set_ylabel("operator |FD acc| / a_max\n(worst joint)")
    bottom.set_xlabel("t [s] (start of the continuation / operator sample)")
    bottom.grid(alpha=0.3)
    writer.save(fig, "foresight.png", "Best continuation against its start, and the operator's "
                                      "acceleration")
    return writer.figures


def _report_text(study: dict, figures) -> str:
    method = study["method"]
    lines = [f"# Foresight: {method['name']}", "",
             f"{study['scenario']['num_samples']} operator samples at "
             f"{study['scenario']['period_s']:g} s, arm {study['scenario']['arm']}. "
             f"{method['name']} (commands sent {method['sent_delay_s']:g} s after their "
             f"sample) deforms the operator's path by E_def = "
             f"{1e3 * method['e_def_m']:.2f} mm.", "",
             "Row s: the commands closest to the operator within the limits that could "
             "still follow the method's first s commands, with the whole future known "
             "(`telesmooth.smoothing.foresight`). Their remaining squared joint deviation "
             "is a lower bound for every method within the limits that sent the same first s "
             "commands (*bound / method*: the share of the method's own that no such method "
             "could avoid). E_def is the Cartesian deformation of that whole sequence (the "
             "method's first s commands, then the continuation): the continuation minimises "
             "the joint deviation, so its E_def indicates, but does not bound, what full "
             "foresight could reach. Where both approach the method's own, the deformation "
             "was committed by then.", ""]
    violation = method["first_limit_violation_sample"]
    if violation is not None:
        lines.append(f"- {method['name']}'s commands break the FD limits (first at sample "
                     f"{violation}): the bound is for methods within the limits, and a "
                     f"continuation exists only from starts up to sample {violation}; row 0 is "
                     f"the least-squares optimum within the limits.")
    for share, first in study["commitment"].items():
        if first is None:
            lines.append(f"- No continuation reaches {float(share):.0%} of the method's E_def.")
        else:
            lines.append(f"- The first start whose continuation keeps {float(share):.0%} of "
                         f"the method's E_def: t = {first['t_s']:.2f} s (sample "
                         f"{first['start']}), E_def {1e3 * first['e_def_m']:.2f} mm; there the "
                         f"bound is {first['bound_share']:.0%} of the method's remaining "
                         f"squared joint deviation.")
    lines += ["", "| s | t [s] | remaining Σ(p−z)², method [rad²] | bound [rad²] | "
              "bound / method | E_def of the continuation [mm] |",
              "|---:|---:|---:|---:|---:|---:|"]
    for row in study["rows"]:
        lines.append(f"| {row['start']} | {row['t_s']:.2f} | "
                     f"{sum(row['method_squared_error_rad2']):.3e} | "
                     f"{sum(row['bound_squared_error_rad2']):.3e} | "
                     f"{row['bound_share']:.1%} | {1e3 * row['e_def_m']:.2f} |")
    lines.append("")
    for title, name in figures:
        lines += [f"![{title}]({name})", ""]
    return "\n".join(lines)


def write_foresight_report(out_dir, scenario, method: str = "online-hard", *, step: int = 4,
                           progress=_log) -> Path:
    """Runs :func:`foresight_study` and writes the report folder; returns report.md's path."""
    study = foresight_study(scenario, method, step=step, progress=progress)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    write_text(out / "foresight.json", json.dumps(study, indent=1, default=float) + "\n")
    figures = _figure(out, study)
    report = out / "report.md"
    write_text(report, _report_text(study, figures))
    return report
