"""`telesmooth foresight`: how much of a method's deformation no rule could have avoided
without knowing more of the operator's motion (the study: :mod:`telesmooth.studies.foresight`).

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
from pathlib import Path

from telesmooth.atomic_files import write_text
from telesmooth.scripts.figures import FigureWriter
from telesmooth.scripts.formatting import log as _log
from telesmooth.studies.foresight import foresight_study

__all__ = ["write_foresight_report"]

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
