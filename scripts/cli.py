"""The ``telesmooth`` command line.

Subcommands:
    smooth   smooth a joint trajectory CSV with one method (the contract in docs/commands.md)
    demo     the main job: a real human demonstration (LASA) through every method, with a report
    simulate, compare, foresight, experiment, bench   reports on scenarios (``--out`` folders)
    ground, onboard, keygen, link-relay                the two-process link

Errors, whatever the command (:func:`main`):

* Bad input (``ValueError``, an ``OSError`` on a file) is one line ``telesmooth <command>:
  error: …`` naming the option or key path as the user wrote it and the value (cut short),
  at most :data:`MAX_MESSAGE_CHARS` characters, exit status 2.
* Nothing is written then: every command declares its outputs up front in an
  :class:`~telesmooth.atomic_files.Outputs` (checked at once, never an input, staged beside
  their destinations) and they are put in place only when the command succeeds.
* Anything else is a bug: one line naming the exception, exit status 1, and ``--debug``
  (anywhere on the command line) shows the traceback.
"""

from __future__ import annotations

import argparse
import json
import math
import re
import sys
from pathlib import Path

from telesmooth.arms.joint_vectors import as_per_joint
from telesmooth.scripts.formatting import log as _log
from telesmooth.smoothing.kalman import START_PRIORS
from telesmooth.smoothing.methods import (
    METHOD_ALIASES,
    METHODS,
    SmoothingSettings,
    method_name,
    smooth_recording,
)
from telesmooth.smoothing.metrics import smoothing_metrics
from telesmooth.smoothing.model import DEFAULT_LAG, DEFAULT_R, DEFAULT_SIGMA
from telesmooth.smoothing.offline import OFFLINE_CONSTRAINTS, OFFLINE_SOLVERS
from telesmooth.smoothing.reduced_q import (
    REDUCED_Q_VARIANTS,
    SIGMA_STEP_RULES,
    VIOLATION_TRIGGERS,
    ReducedQConfig,
)
from telesmooth.smoothing.sigma_store import (
    load_operator_sigma,
    save_operator_sigma,
    stored_operators,
)
from telesmooth.smoothing.trajectory_io import read_joint_csv, write_joint_csv
from telesmooth.user_input import name_fields, parse_plain_number, quote, quote_path

METHOD_CHOICES = METHODS + tuple(METHOD_ALIASES)
"""What a ``--method`` option takes: every method of the registry and its aliases."""

MAX_MESSAGE_CHARS = 300
"""Longest error line printed (a backstop: messages quote values short at their source)."""

DEBUG_FLAG = "--debug"


def parse_per_joint(text: str):
    """``"0.1"`` → 0.1; ``"0.1,0.2,0.3"`` → [0.1, 0.2, 0.3]; ``"a=0.1,b=0.2"`` → {a: 0.1, b: 0.2}.

    Numbers are plain decimals (:func:`~telesmooth.user_input.parse_plain_number`); a joint
    named twice is an error, not the last value silently.
    """
    parts = [part.strip() for part in text.split(",")]
    try:
        if any("=" in part for part in parts):
            values = {}
            for part in parts:
                name, _, value = part.partition("=")
                name = name.strip()
                if not name:
                    raise ValueError
                if name in values:
                    raise argparse.ArgumentTypeError(
                        f"{quote(text)}: joint {quote(name)} is given twice")
                values[name] = parse_plain_number(value)
            return values
        values = [parse_plain_number(part) for part in parts]
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"{quote(text)}: give a number, a comma list (one per joint) or name=value pairs"
        ) from None
    return values[0] if len(values) == 1 else values


def number(text: str) -> float:
    """An option's number: a plain decimal, or inf/nan (which each command refuses by name
    where they make no sense); not the other spellings ``float()`` takes (``1_0``, ``١``)."""
    try:
        return parse_plain_number(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{quote(text)} is not a number") from None


def _check_finite(option: str, value: float, *, minimum: float = 0.0,
                  allow_zero: bool = False) -> float:
    """``value`` if finite and > ``minimum`` (>= with ``allow_zero``), else a ValueError."""
    ok = math.isfinite(value) and (value >= minimum if allow_zero else value > minimum)
    if not ok:
        rule = f">= {minimum:g}" if allow_zero else f"> {minimum:g}"
        raise ValueError(f"{option} = {value!r} must be finite and {rule}")
    return value


# Settings fields and the options that set them, for messages of the smoothing core.
_SMOOTH_OPTIONS = {
    "max_acceleration": "--acc-max", "max_jerk": "--jerk-max", "max_velocity": "--vel-max",
    "sigma": "--sigma", "r": "--r", "lag": "--lag", "rho": "--rho", "sigma_min": "--sigma-min",
    "sigma0": "--sigma-store", "variant": "--variant", "step_rule": "--sigma-step",
    "trigger": "--trigger", "constraint": "--constraint", "method": "--method",
    "link_lengths": "--link-lengths",
}


def _add_smooth_parser(subparsers) -> None:
    p = subparsers.add_parser(
        "smooth",
        help="smooth a joint trajectory CSV (t,<joints…>; s, rad; uniform step)",
        description="Smooth an operator's joint trajectory so that acceleration and jerk stay "
        "within the robot's limits. Limits take one value for all joints, a comma list "
        "(one per joint, in column order) or name=value pairs. Prints a summary to stderr: "
        "per joint the FD acceleration and jerk max/limit and share of samples over (velocity "
        "too with --vel-max), whether the limits are met, the deformation |Δq| (mean / max, "
        "mrad) and the worst ratios.",
    )
    p.add_argument("input", type=Path, help="input CSV: header t,<joint names…>")
    p.add_argument("-o", "--output", type=Path, required=True, help="output CSV")
    p.add_argument("--method", choices=METHOD_CHOICES, default="online-cks", metavar="METHOD",
                   help="the smoothing method (default online-cks): " + ", ".join(METHODS)
                   + "; pass-through is original; offline-cks-trajectory is offline-cks with "
                   "--constraint trajectory --rest-at-end, as `compare` runs it")
    p.add_argument("--acc-max", type=parse_per_joint, required=True, metavar="A",
                   help="acceleration limit a_max [rad/s²]")
    p.add_argument("--jerk-max", type=parse_per_joint, required=True, metavar="J",
                   help="jerk limit j_max [rad/s³]")
    p.add_argument("--vel-max", type=parse_per_joint, default=None, metavar="V",
                   help="velocity limit v_max [rad/s] (offline-cks trajectory mode, online-hard, "
                   "ruckig)")
    p.add_argument("--constraint", choices=OFFLINE_CONSTRAINTS[:2], default="state",
                   help="offline-cks: 'state' (the paper's state box, soft) or 'trajectory' "
                   "(hard limits on the finite differences of the sent positions)")
    p.add_argument("--rest-at-end", action="store_true", help="offline-cks: end at rest")
    p.add_argument("--start-prior", choices=START_PRIORS, default="rest",
                   help="offline-ks, offline-cks: 'rest' (default: the robot at rest at the "
                   "first sample's pose one tick before it, as the online smoothers start) or "
                   "'loose' (the paper's prior; the estimate may start moving: a jerk step)")
    p.add_argument("--solver", choices=OFFLINE_SOLVERS, default="drake",
                   help="offline-cks: 'drake' (Drake MathematicalProgram + Clarabel; the banded "
                   "interior point takes over for a joint Clarabel cannot solve) or 'banded-ip' "
                   "(the banded interior point alone: faster, and robust at 100 Hz)")
    p.add_argument("--dt", type=number, default=None, metavar="S",
                   help="expected sample period [s]; the file's time step must match it")
    p.add_argument("--lag", type=int, default=DEFAULT_LAG, metavar="L",
                   help=f"fixed lag in samples for bmfls/online-cks (default {DEFAULT_LAG})")
    p.add_argument("--sigma", type=parse_per_joint, default=DEFAULT_SIGMA, metavar="S",
                   help=f"jounce intensity σ_0 [rad²/s⁷] (default {DEFAULT_SIGMA:g})")
    p.add_argument("--r", type=parse_per_joint, default=DEFAULT_R, metavar="R",
                   help=f"position measurement variance [rad²] (default {DEFAULT_R:g})")
    p.add_argument("--variant", choices=REDUCED_Q_VARIANTS, default="A",
                   help="online-cks reduced-Q variant (default A)")
    p.add_argument("--sigma-step", choices=SIGMA_STEP_RULES, default="multiplicative",
                   help="online-cks σ step rule (default multiplicative)")
    p.add_argument("--rho", type=number, default=0.8, help="multiplicative σ factor (0.8)")
    p.add_argument("--sigma-min", type=number, default=None, help="σ_min (default 2.5e-4 σ_0)")
    p.add_argument("--trigger", choices=VIOLATION_TRIGGERS, default="state",
                   help="online-cks trigger: output block states or FD of sent positions")
    p.add_argument("--operator", default=None,
                   help="online-cks: operator name whose σ is loaded from/saved to --sigma-store")
    p.add_argument("--sigma-store", type=Path, default=None,
                   help="JSON file of per-operator σ (loaded as σ_0 if present, updated after)")
    p.add_argument("--link-lengths", type=parse_per_joint, default=None, metavar="L1,L2,…",
                   help="planar link lengths [m]: adds the Cartesian deformation to --metrics")
    p.add_argument("--metrics", type=Path, default=None, metavar="OUT.json",
                   help="write the docs/method.md §6 metrics as JSON")
    p.set_defaults(handler=run_smooth)


def _planar_fk(planar_forward_kinematics, link_lengths, q):
    return planar_forward_kinematics(q, link_lengths)


def _refuse_a_haptic_recording(path, columns) -> None:
    """``smooth`` reads joint angles: a file whose columns are a hand's pose (a haptic
    recording: metres) is one line, not metres smoothed as radians."""
    from telesmooth.datasets.haptic_recording import PLANAR_POSE_NAMES, SPATIAL_POSE_NAMES

    pose = {name for name in columns if name in PLANAR_POSE_NAMES + SPATIAL_POSE_NAMES}
    if pose:
        raise ValueError(
            f"file = {quote_path(str(path))}: columns {quote(sorted(pose))} are a hand's pose "
            "(a haptic recording), not joint angles in radians; run `telesmooth simulate` on it")


def run_smooth(args) -> int:
    from telesmooth.atomic_files import Outputs

    args.method = method_name(args.method, "--method")
    if (args.operator is None) != (args.sigma_store is None):
        raise ValueError("--operator and --sigma-store go together")
    if args.operator is not None and not args.operator.strip():
        raise ValueError(f"--operator = {quote(args.operator)} must be a non-empty name")
    if args.dt is not None:
        _check_finite("--dt", args.dt)
    with Outputs(inputs={"file": args.input}) as outputs:
        output = outputs.file("-o", args.output)
        metrics_path = None if args.metrics is None else outputs.file("--metrics", args.metrics)
        store_path = (None if args.sigma_store is None
                      else outputs.file("--sigma-store", args.sigma_store))
        trajectory = read_joint_csv(args.input, expected_dt_s=args.dt, warn=_log)
        _refuse_a_haptic_recording(args.input, trajectory.joint_names)
        try:
            result, settings, extra = _smooth(args, trajectory)
        except ValueError as error:
            raise ValueError(name_fields(str(error), _SMOOTH_OPTIONS)) from None
        names = list(trajectory.joint_names)
        write_joint_csv(output, trajectory.t_s, result.positions, names,
                        extra_columns={"sent_t": trajectory.t_s + result.sent_delay_s})
        metrics = _smooth_metrics(args, trajectory, result, settings, extra)
        summary = smooth_summary(metrics)
        if metrics_path is not None:
            from telesmooth.atomic_files import write_text

            write_text(metrics_path, json.dumps(metrics, indent=2) + "\n")
        if store_path is not None and result.final_sigma is not None:
            save_operator_sigma(args.sigma_store, args.operator, names, result.final_sigma,
                                destination=store_path)
        elif store_path is not None:     # nothing to store: keep the file as it is
            outputs.drop(store_path)
    for line in summary:
        print(line, file=sys.stderr)
    print(f"wrote {args.output} ({len(trajectory.t_s)} samples, method {args.method})",
          file=sys.stderr)
    if args.metrics is not None:
        print(f"wrote {args.metrics}", file=sys.stderr)
    if store_path is not None and result.final_sigma is not None:
        print(f"operator {args.operator!r}: σ = {result.final_sigma.tolist()} saved to "
              f"{args.sigma_store}", file=sys.stderr)
    return 0


def _smooth(args, trajectory):
    """Runs the smoothing of ``smooth``; errors name the settings' fields (renamed by the
    caller to the options)."""
    names = list(trajectory.joint_names)
    settings = SmoothingSettings(
        max_acceleration=as_per_joint("max_acceleration", args.acc_max, len(names), names),
        max_jerk=as_per_joint("max_jerk", args.jerk_max, len(names), names),
        max_velocity=(None if args.vel_max is None
                      else as_per_joint("max_velocity", args.vel_max, len(names), names)),
        sigma=as_per_joint("sigma", args.sigma, len(names), names),
        r=as_per_joint("r", args.r, len(names), names),
        lag=args.lag,
        constraint=args.constraint,
        rest_at_end=args.rest_at_end,
        start_prior=args.start_prior,
        offline_solver=args.solver,
        reduced_q=ReducedQConfig(variant=args.variant, step_rule=args.sigma_step, rho=args.rho,
                                 sigma_min=args.sigma_min, trigger=args.trigger),
    )
    link_lengths = None
    if args.link_lengths is not None:
        link_lengths = as_per_joint("link_lengths", args.link_lengths, len(names), names)
    sigma0 = None
    try:
        stored = [] if args.operator is None else stored_operators(args.sigma_store)
        if args.operator in stored:
            sigma0 = load_operator_sigma(args.sigma_store, args.operator, names)
    except ValueError as error:
        raise ValueError(f"--sigma-store: {error}") from None
    if sigma0 is not None:
        print(f"operator {args.operator!r}: σ_0 = {sigma0.tolist()} from {args.sigma_store}",
              file=sys.stderr)
    elif args.operator is not None:
        print(f"operator {args.operator!r}: new operator, σ_0 = --sigma", file=sys.stderr)
    result = smooth_recording(trajectory.positions, trajectory.dt_s, args.method, settings,
                              joint_names=names, sigma0=sigma0)
    return result, settings, link_lengths


def _smooth_metrics(args, trajectory, result, settings, link_lengths) -> dict:
    forward_kinematics = None
    if link_lengths is not None:
        from functools import partial

        from telesmooth.arms.planar import planar_forward_kinematics

        forward_kinematics = partial(_planar_fk, planar_forward_kinematics,
                                     tuple(link_lengths))
    metrics = smoothing_metrics(
        smoothed_positions=result.positions,
        original_positions=trajectory.positions,
        dt_s=trajectory.dt_s,
        max_acceleration=settings.max_acceleration,
        max_jerk=settings.max_jerk,
        max_velocity=settings.max_velocity,
        smoothed_states=result.states,
        forward_kinematics=forward_kinematics,
        joint_names=list(trajectory.joint_names),
    )
    metrics["method"] = args.method
    metrics["sent_delay_s"] = result.sent_delay_s
    metrics["details"] = result.details
    if result.final_sigma is not None:
        metrics["final_sigma"] = result.final_sigma.tolist()
    return metrics


_SUMMARY_LIMITS = (("acc", "fd_acceleration", "FD acceleration"),
                   ("jerk", "fd_jerk", "FD jerk"),
                   ("vel", "fd_velocity", "FD velocity"))
"""The limits the ``smooth`` summary reports: (column word, metrics key, name); velocity only
when ``--vel-max`` is given."""


def _share(fraction: float) -> str:
    """A share of samples in %, never rounded to 0.0 % when some sample is over."""
    percent = 100.0 * fraction
    if 0.0 < percent < 0.05:
        return "<0.1 %"
    return f"{percent:.1f} %"


def smooth_summary(metrics: dict) -> list[str]:
    """What ``smooth`` prints before its "wrote" lines: per joint whether the FD limits are met
    (max/limit with :func:`~telesmooth.scripts.formatting.limit_ratio`, the share of samples
    over), the deformation |Δq| (mean and max, mrad), and the worst ratio of each limit.

    Args:
        metrics: :func:`~telesmooth.smoothing.metrics.smoothing_metrics` of the run.

    Returns:
        A few lines: a headline, a small aligned table (one row per joint) and the worst
        ratios. A limit with no finite difference to measure (too few samples) reads n/a.
    """
    from telesmooth.scripts.formatting import limit_ratio
    from telesmooth.smoothing.metrics import VIOLATION_RTOL

    names = metrics["joint_names"]
    limits = [entry for entry in _SUMMARY_LIMITS if entry[1] in metrics]
    header = ["joint"]
    for word, _, _ in limits:
        header += [f"{word} max/limit", f"{word} over"]
    header += ["|Δq| mean / max [mrad]", "limits"]
    rows = []
    met = 0
    for j, name in enumerate(names):
        row, over = [name], []
        for word, key, _ in limits:
            stats = metrics[key]
            if stats["num_samples"] == 0:
                row += ["n/a", "n/a"]
                continue
            ratio = stats["max_over_limit"][j]
            row += [limit_ratio(ratio), _share(stats["fraction_over_limit"][j])]
            if ratio > 1.0 + VIOLATION_RTOL:
                over.append(word)
        deformation = metrics["position_deformation_rad"]
        row.append(f"{1e3 * deformation['mean'][j]:.2f} / {1e3 * deformation['max'][j]:.2f}")
        row.append("over: " + ", ".join(over) if over else "met")
        met += not over
        rows.append(row)
    widths = [max(len(line[c]) for line in [header, *rows]) for c in range(len(header))]

    def aligned(cells):
        text = [cells[0].ljust(widths[0])]
        text += [cell.rjust(width) for cell, width in zip(cells[1:-1], widths[1:-1])]
        return "  ".join(text + [cells[-1]]).rstrip()

    worst = []
    for _, key, label in limits:
        stats = metrics[key]
        if stats["num_samples"]:
            j = max(range(len(names)), key=lambda i: stats["max_over_limit"][i])
            worst.append(f"{label} {limit_ratio(stats['max_over_limit'][j])} ({names[j]})")
    return [f"{metrics['method']}: {metrics['num_samples']} samples at Δt = "
            f"{metrics['dt_s']:g} s; the FD limits are met on {met} of {len(names)} joint(s)",
            aligned(header), *(aligned(row) for row in rows),
            "worst max/limit: " + (", ".join(worst) if worst else "n/a")]


def _add_demo_parser(subparsers) -> None:
    p = subparsers.add_parser(
        "demo",
        help="smooth a real human demonstration (LASA) with every method and write a report",
        description="The main job, without the plant: one LASA handwriting demonstration (a "
        "real person's hand motion) mapped onto the air-bearing arm, converted to joint "
        "targets and sampled at the 4 Hz uplink rate, then smoothed by every method of the "
        "registry; writes the CSVs, metrics.json, the figures and report.md into --out.",
    )
    p.add_argument("--out", type=Path, default=Path("out/demo"), help="report folder")
    p.add_argument("--shape", default="Angle", help="LASA shape (default Angle)")
    p.add_argument("--demo-index", type=int, default=0, help="demonstration 0–6 (default 0)")
    p.set_defaults(handler=run_demo)


def run_demo(args) -> int:
    from telesmooth.atomic_files import Outputs
    from telesmooth.datasets.lasa import validate_demo_index, validate_shape
    from telesmooth.scripts.demo_report import write_demo_report

    validate_shape(args.shape, field="--shape")
    validate_demo_index(args.demo_index, args.shape, field="--demo-index")
    with Outputs() as outputs:
        report = write_demo_report(outputs.folder("--out", args.out), shape=args.shape,
                                   demo_index=args.demo_index)
    print(f"report: {args.out / report.name}")
    return 0


def _add_scenario_arguments(p, *, on_collision_default=None) -> None:
    p.add_argument("--scenario", type=Path, default=None,
                   help="scenario YAML file (default: the built-in diagrams/scenarios.yaml)")
    p.add_argument("--scenario-name", default=None, help="entry of the file (default Defaults)")
    p.add_argument("--scenario-text", default=None,
                   help="YAML overrides, e.g. \"{arm: space_arm, smoother: {method: bmfls}}\"")
    p.add_argument("--on-collision", choices=("hold", "stop"), default=on_collision_default,
                   help="what a pre-simulator collision (and the operator's Stop) does ("
                        + ("default stop" if on_collision_default == "stop" else
                           "the scenario's fifo.on_collision, default hold")
                        + "): 'hold' re-sends the last command (the paper), 'stop' "
                        "brakes within the acceleration and jerk limits")


_SCENARIO_OPTIONS = {"filename": "--scenario", "scenario_name": "--scenario-name",
                     "scenario_text": "--scenario-text"}


def _scenario_outputs(args, scenario, *extra_inputs):
    """An :class:`~telesmooth.atomic_files.Outputs` whose inputs are the scenario's files."""
    from telesmooth.atomic_files import Outputs

    outputs = Outputs(inputs={"--scenario": args.scenario})
    if scenario.haptic.source == "file":
        outputs.add_input("haptic.file", scenario.haptic.file)
    for name, path in extra_inputs:
        outputs.add_input(name, path)
    return outputs


MAX_SIMULATED_S = 3600.0
"""Longest simulated run of simulate/compare/foresight/experiment, s (the cost grows with it;
the LASA demonstrations last 3-20 s)."""
MAX_PROCESS_RUN_S = 7 * 24 * 3600.0
"""Longest ``--duration`` of the ground and onboard processes, s (a week; they log in
memory as they run)."""
MIN_PLANT_STEP_S = 1e-5
"""Shortest plant step of the experiment, s."""
MAX_WORKERS = 64
"""Most worker processes of the experiment's local Dask cluster."""


def _check_at_most(option: str, value: float, limit: float) -> None:
    if value > limit:
        raise ValueError(f"{option} = {value!r} s is longer than the limit of {limit:g} s")


def _check_run_length(scenario, duration_s, *, uses_duration: bool = True) -> None:
    """Refuses a simulated run too short for one command to reach the robot and be measured
    (the metrics compare commands with the operator's targets from the FIFO delay on, and the
    robot's response a ramp later) or too long."""
    interpolator = scenario.onboard.interpolator
    ramp = (interpolator.ramp_duration_s if interpolator.interpolation == "linear" else 0.0)
    # ... and the tracker samples the response after the ramp, one tracker period later.
    shortest = (scenario.fifo.delay_s + max(scenario.uplink.period_s, ramp)
                + scenario.onboard.tracker.period_s)
    for label, value in (("--duration", duration_s),
                         ("simulation_duration_s", scenario.simulation_duration_s)):
        if value is None or not uses_duration:
            continue
        if value < shortest - 1e-9:
            raise ValueError(
                f"{label} = {value!r} s is shorter than the FIFO delay, an uplink period or "
                f"the onboard ramp, and a tracker sample ({shortest:g} s): no command's "
                "response would be measured")
        _check_at_most(label, value, MAX_SIMULATED_S)
        return
    _check_at_most("settle_s", scenario.settle_s, MAX_SIMULATED_S)


def _load_scenario(args, overrides=None):
    """The scenario of the scenario options; ``--on-collision`` and ``--chain`` (and the
    caller's ``overrides``) are merged into it before it is built and checked, so a key they
    make unread is refused like any other."""
    from telesmooth.diagrams.scenario import LoadScenario
    from telesmooth.typed_yaml import merge_data

    options = {}
    if getattr(args, "on_collision", None) is not None:
        options["fifo"] = {"on_collision": args.on_collision}
    chain = getattr(args, "chain", None)
    if chain is not None:
        options["chain"] = chain
    options = merge_data(options, overrides or {})
    try:
        return LoadScenario(filename=args.scenario, scenario_name=args.scenario_name,
                             scenario_text=args.scenario_text, option_names=_SCENARIO_OPTIONS,
                             overrides=options or None)
    except ValueError as error:
        if chain is not None and "link.faults need chain" in str(error):
            raise ValueError(f"--chain {chain}: {error}") from None
        raise


def _add_simulate_parser(subparsers) -> None:
    p = subparsers.add_parser(
        "simulate",
        help="run a scenario headless through the whole chain and write a report",
        description="Run a scenario in one process through the whole chain (operator, IK, "
        "FIFO, smoother, uplink, link, onboard robot and tracker) and write a report of what "
        "happened (commands, limits, tracking errors, figures) into --out.",
    )
    _add_scenario_arguments(p)
    p.add_argument("--out", type=Path, default=Path("out/simulate"), help="report folder")
    p.add_argument("--duration", type=number, default=None,
                   help="simulated time in s (default: the recording + settle time)")
    p.add_argument("--meshcat", action="store_true",
                   help="also save a self-contained Meshcat replay, run.html")
    p.add_argument("--chain", choices=("deployed", "paper"), default=None,
                   help="'deployed' (the scenario's default): every packet through the "
                        "onboard receiver and link guard, as `telesmooth onboard` runs them; "
                        "'paper': the uplink drives the robot directly (the paper's chain, "
                        "no guard)")
    p.set_defaults(handler=run_simulate)


def run_simulate(args) -> int:
    from telesmooth.scripts.simulate_report import write_simulation_report

    scenario = _load_scenario(args)
    if args.duration is not None:
        _check_finite("--duration", args.duration)
    _check_run_length(scenario, args.duration)
    with _scenario_outputs(args, scenario) as outputs:
        report = write_simulation_report(outputs.folder("--out", args.out), scenario,
                                         duration_s=args.duration, meshcat_html=args.meshcat)
    print(f"report: {args.out / report.name}")
    return 0


def _add_teleop_parser(subparsers) -> None:
    p = subparsers.add_parser(
        "teleop",
        help="drive the robot live from a browser (the whole chain in one process, at real "
             "time, with the pre-simulator display and the predicted robot)",
        description="The operator's seat: the whole deployed chain in one process against the "
        "wall clock, driven from a browser page on Drake's Meshcat. Keys: Space = Enable "
        "(the clutch: nothing moves until you engage it), Esc = Stop (brakes the robot "
        "within the limits and holds it), A/D = -x/+x, S/W = -y/+y, J/L = the tool angle "
        "(6-DOF arm: yaw; K/I = -z/+z, U/O = roll, Q/E = pitch); on-screen sliders and a "
        "gamepad (left stick x/y, right stick angle and z; button A = Enable, B = Stop) do "
        "the same. The page shows the planning position (solid), the position received "
        "from the robot (wire frame), the predicted robot (green) and a status panel (open "
        "the page's controls). With --out the session is written: the operator's hand as "
        "a haptic recording, the logs, predicted.csv and report.md.",
    )
    _add_scenario_arguments(p, on_collision_default="stop")
    _add_live_arguments(p, out_help="folder for the session: operator.npz/.csv (your hand, "
                        "replayable with simulate), logs, predicted.csv, report.md")
    p.add_argument("--realtime", type=number, default=1.0,
                   help="target real-time rate (default 1)")
    p.set_defaults(handler=run_teleop_command)


def run_teleop_command(args) -> int:
    from telesmooth.scripts.teleop import run_teleop

    scenario = _live_scenario(args)
    _check_live_options(args)
    _check_finite("--realtime", args.realtime)
    with _scenario_outputs(args, scenario) as outputs:
        out = None if args.out is None else outputs.folder("--out", args.out)
        status = run_teleop(scenario, host=args.host, port=args.port,
                            duration_s=args.duration, realtime=args.realtime, out=out)
    if args.out is not None:
        print(f"report: {args.out / 'report.md'}")
    return status


def _add_operator_parser(subparsers) -> None:
    from telesmooth.lcm_types.channels import DEFAULT_LCM_URL

    p = subparsers.add_parser(
        "operator",
        help="the operator's console alone, on the LCM bus (with `telesmooth ground` and "
             "`telesmooth onboard`: three processes)",
        description="The browser console of `teleop` as its own process: it publishes the "
        "operator's hand on TELEOP_HAPTIC_COMMAND at 100 Hz (what `telesmooth ground "
        "--scenario-text \"{haptic: {source: lcm}}\"` reads) and shows the planning position, "
        "the robot's telemetry (ONBOARD_JOINT_STATUS), the predicted robot and the ground's "
        "collision events. Keys as `teleop`. See docs/operator.md.",
    )
    _add_scenario_arguments(p)
    p.add_argument("--lcm-url", default=None,
                   help=f"LCM URL (default: the scenario's, {DEFAULT_LCM_URL})")
    _add_live_arguments(p, out_help="folder for the session: operator.npz/.csv, console.csv, "
                        "predicted.csv, report.md")
    p.set_defaults(handler=run_operator_command)


def _add_live_arguments(p, *, out_help: str) -> None:
    """The options every live console (``teleop``, ``operator``) takes."""
    p.add_argument("--port", type=int, default=None,
                   help="port of the page (default: the first free from 7000)")
    p.add_argument("--host", default="127.0.0.1",
                   help="interface the page listens on (default 127.0.0.1: this machine "
                        "only; anything else is reachable from other machines, and says so)")
    p.add_argument("--duration", type=number, default=None,
                   help="seconds to run (default: until Ctrl-C)")
    p.add_argument("--out", type=Path, default=None, help=out_help)


def _live_scenario(args):
    """The scenario of a live console (``teleop``, ``operator``): the browser console is the
    operator (``haptic.live_initial_pose`` is where the hand starts), the deployed chain."""
    return _load_scenario(args, overrides={"haptic": {"source": "console"},
                                           "chain": "deployed"})


def _check_live_options(args) -> None:
    if args.duration is not None:
        _check_finite("--duration", args.duration)
        _check_at_most("--duration", args.duration, MAX_PROCESS_RUN_S)
    if args.port is not None and not 1 <= args.port <= 65535:
        raise ValueError(f"--port = {args.port} must be a port number within 1 and 65535")


def run_operator_command(args) -> int:
    from telesmooth.lcm_types.channels import check_lcm_url
    from telesmooth.scripts.teleop import run_operator

    scenario = _live_scenario(args)
    url = check_lcm_url("--lcm-url" if args.lcm_url else "lcm_url (scenario)",
                        args.lcm_url or scenario.lcm_url)
    _check_live_options(args)
    with _scenario_outputs(args, scenario) as outputs:
        out = None if args.out is None else outputs.folder("--out", args.out)
        status = run_operator(scenario, lcm_url=url, host=args.host, port=args.port,
                              duration_s=args.duration, out=out)
    if args.out is not None:
        print(f"report: {args.out / 'report.md'}")
    return status


def _add_compare_parser(subparsers) -> None:
    p = subparsers.add_parser(
        "compare",
        help="every smoothing method on one scenario through the same plant (paper Table 2)",
        description="Run every smoothing method (or those of --methods) on the scenario's "
        "recorded session and play each method's commands through the same plant; write the "
        "paper's Table 2 (limits, deformation, response error, P, latency) into --out.",
    )
    _add_scenario_arguments(p)
    p.add_argument("--out", type=Path, default=Path("out/compare"), help="report folder")
    p.add_argument("--methods", default=",".join(METHODS),
                   help="comma list of methods (default all: " + ",".join(METHODS)
                   + "); original is always run, it is the reference of P")
    _add_offline_solver_argument(p)
    _add_playback_chain_argument(p)
    p.set_defaults(handler=run_compare)


def _add_playback_chain_argument(p) -> None:
    p.add_argument("--chain", choices=("paper", "deployed"), default="paper",
                   help="'paper' (default; the paper's set-up): each method's commands drive "
                        "the robot directly; 'deployed': through the onboard receiver and "
                        "link guard, as `telesmooth onboard` runs them (the guard keeps what "
                        "the robot receives within the limits; the report says what it cut)")


def _add_foresight_parser(subparsers) -> None:
    p = subparsers.add_parser(
        "foresight",
        help="how much of a method's deformation needed foresight: the best continuation of "
             "its commands from every step-th sample, the whole future known",
        description="For one method on the scenario's recording, the best continuation within "
        "the limits of its first s commands for every --step-th s, knowing the whole future: "
        "the part of the method's deformation that no rule could have avoided. Writes "
        "foresight.json, the figure and report.md into --out.",
    )
    _add_scenario_arguments(p)
    p.add_argument("--out", type=Path, default=Path("out/foresight"), help="report folder")
    p.add_argument("--method", choices=METHOD_CHOICES, default="online-hard", metavar="METHOD",
                   help="the method whose commands are continued (default online-hard): "
                   + ", ".join(METHODS))
    p.add_argument("--step", type=int, default=4,
                   help="samples between two starts (default 4: every second at 4 Hz)")
    p.set_defaults(handler=run_foresight)


def run_foresight(args) -> int:
    from telesmooth.scripts.foresight_report import write_foresight_report

    scenario = _load_scenario(args)
    _check_run_length(scenario, None, uses_duration=False)
    if args.step < 1:
        raise ValueError(f"--step = {args.step} must be an integer >= 1")
    with _scenario_outputs(args, scenario) as outputs:
        report = write_foresight_report(outputs.folder("--out", args.out), scenario,
                                        args.method, step=args.step)
    print(f"report: {args.out / report.name}")
    return 0


def _add_offline_solver_argument(p) -> None:
    p.add_argument("--solver", choices=OFFLINE_SOLVERS, default="drake",
                   help="solver of the Offline-CKS methods: 'drake' (the MathematicalProgram + "
                        "Clarabel, default) or 'banded-ip' (the banded interior point: the same "
                        "optimum to ~1e-6 rad, faster)")


def run_compare(args) -> int:
    from telesmooth.scripts.compare_report import write_comparison_report

    scenario = _load_scenario(args)
    _check_run_length(scenario, None, uses_duration=False)
    methods = _method_list(args.methods, METHODS)
    with _scenario_outputs(args, scenario) as outputs:
        report = write_comparison_report(outputs.folder("--out", args.out), scenario,
                                         methods=methods, offline_solver=args.solver,
                                         chain=args.chain)
    print(f"report: {args.out / report.name}")
    return 0


def _method_list(text: str, known) -> tuple:
    """``--methods``: a comma list of known methods (or their aliases), at least one; the
    registry's names."""
    methods = tuple(m.strip() for m in text.split(",") if m.strip())
    if not methods:
        raise ValueError(f"--methods = {quote(text)} names no method")
    return tuple(method_name(method, "--methods", known) for method in methods)


def _add_experiment_parser(subparsers) -> None:
    from telesmooth.studies.experiment import KF_FORMS, ExperimentConfig

    defaults = ExperimentConfig()
    p = subparsers.add_parser(
        "experiment",
        help="the paper's experiment on the LASA demonstrations: every method, the claims "
             "C1-C8, the Online-CKS sensitivity; on a Dask cluster",
        description="The paper's experiment at scale: every method on LASA demonstrations "
        "through the whole chain, the Online-CKS sensitivity study and claim C8, run as tasks "
        "on a Dask cluster; records.jsonl in --out is a journal (a rerun continues it) and "
        "the report judges the claims C1-C8 per plant and operator speed.",
    )
    _add_scenario_arguments(p)
    p.add_argument("--out", type=Path, default=Path("out/experiment"), help="report folder")
    p.add_argument("--shapes", default="all",
                   help="comma list of LASA shapes, or 'all' (default: all 30)")
    p.add_argument("--demos", default="0",
                   help="demonstrations of each shape: comma list of 0-6, or 'all' "
                        "(default 0; 'all' is the full grid of 210)")
    p.add_argument("--methods", default=",".join(METHODS),
                   help="comma list of methods (default all: " + ",".join(METHODS)
                   + ")")
    p.add_argument("--sensitivity-shapes", default=",".join(defaults.sensitivity_shapes),
                   help="shapes of the Online-CKS sensitivity study ('none' to skip)")
    p.add_argument("--kf-sigma0-factors",
                   default=",".join(f"{v:g}" for v in defaults.kf_sigma0_factors),
                   help="σ_0 multipliers of the KF's sensitivity study, run with both KF forms "
                        "on the sensitivity shapes (comma list, or 'none'; default "
                        + ",".join(f"{v:g}" for v in defaults.kf_sigma0_factors) + ")")
    p.add_argument("--c8-shapes", default="all",
                   help="shapes of the C8 study, each over its 7 demonstrations "
                        "('none' to skip; default all)")
    p.add_argument("--plant-step", type=number, default=defaults.plant_time_step_s,
                   help="plant time step in s, 0 = continuous (default: the scenario's plant, "
                        "continuous unless onboard.time_step_s says otherwise)")
    p.add_argument("--settle", type=number, default=defaults.settle_s,
                   help=f"simulated seconds after the operator stops (default "
                        f"{defaults.settle_s})")
    p.add_argument("--workers", type=int, default=2,
                   help="worker processes of the local Dask cluster (default 2; 0 = run in "
                        "this process without Dask)")
    p.add_argument("--scheduler", default=None,
                   help="address of an existing Dask scheduler (tcp://host:port) instead of "
                        "a local cluster")
    p.add_argument("--quick", action="store_true",
                   help="a small grid (shapes Angle,CShape; sensitivity and C8 on Angle) to "
                        "check the set-up in a few minutes")
    p.add_argument("--speeds", default="1",
                   help="operator speeds, multiples of the demonstrator's hand speed (the LASA "
                        "time scale is divided by each), comma list (default 1)")
    p.add_argument("--plants", default="lab",
                   help="plant drive presets, comma list of lab, lightweight (default lab)")
    p.add_argument("--kf-form", choices=KF_FORMS, default=defaults.kf_form,
                   help="the KF form every claim uses; the other is reported beside it "
                        f"(default {defaults.kf_form}: the a-posteriori filter)")
    p.add_argument("--shard", default=None, metavar="K/N",
                   help="run only every N-th demonstration's tasks from the K-th (split a "
                        "grid across runs or machines; --merge joins the folders)")
    p.add_argument("--merge", default=None, metavar="DIR,DIR",
                   help="run nothing: join the records of these folders (the same grid, e.g. "
                        "its shards) into --out and write the report")
    _add_offline_solver_argument(p)
    _add_playback_chain_argument(p)
    p.set_defaults(handler=run_experiment_command)


def _shape_list(text: str, option: str) -> tuple:
    from telesmooth.datasets.lasa import LASA_SHAPES

    text = text.strip()
    if text == "all":
        return LASA_SHAPES
    if text in ("none", ""):
        return ()
    from telesmooth.datasets.lasa import validate_shape

    shapes = tuple(part.strip() for part in text.split(",") if part.strip())
    for shape in shapes:
        validate_shape(shape, field=option)
    return shapes


_EXPERIMENT_OPTIONS = {"shapes": "--shapes", "demos": "--demos", "methods": "--methods",
                       "plant_time_step_s": "--plant-step", "settle_s": "--settle",
                       "sensitivity_shapes": "--sensitivity-shapes",
                       "c8_shapes": "--c8-shapes", "offline_solver": "--solver",
                       "speeds": "--speeds", "plants": "--plants", "kf_form": "--kf-form",
                       "chain": "--chain", "kf_sigma0_factors": "--kf-sigma0-factors"}


def _number_list(text: str, option: str) -> tuple[float, ...]:
    try:
        values = tuple(parse_plain_number(part) for part in text.split(",") if part.strip())
    except ValueError:
        raise ValueError(f"{option} = {quote(text)} must be a comma list of numbers") from None
    if not values:
        raise ValueError(f"{option} = {quote(text)} names no value")
    return values


def run_experiment_command(args) -> int:
    from telesmooth.scripts.experiment_report import (
        merge_experiment_reports,
        parse_demos,
        parse_shard,
        write_experiment_report,
    )
    from telesmooth.studies.experiment import ExperimentConfig

    base = _load_scenario(args)
    _check_run_length(base, None, uses_duration=False)
    _check_finite("--settle", args.settle)
    _check_at_most("--settle", args.settle, MAX_SIMULATED_S)
    if args.plant_step is not None:
        _check_finite("--plant-step", args.plant_step, allow_zero=True)
        if args.plant_step != 0 and args.plant_step < MIN_PLANT_STEP_S:
            raise ValueError(f"--plant-step = {args.plant_step!r} s is below "
                             f"{MIN_PLANT_STEP_S} s (each simulated second would take hours; "
                             "0 is the continuous plant)")
    if args.quick:
        shapes, sensitivity, c8 = ("Angle", "CShape"), ("Angle",), ("Angle",)
    else:
        shapes = _shape_list(args.shapes, "--shapes")
        sensitivity = _shape_list(args.sensitivity_shapes, "--sensitivity-shapes")
        c8 = _shape_list(args.c8_shapes, "--c8-shapes")
    if not shapes:
        raise ValueError("--shapes names no shape")
    methods = _method_list(args.methods, METHODS)
    plants = tuple(p.strip() for p in args.plants.split(",") if p.strip())
    try:
        config = ExperimentConfig(shapes=shapes, demos=parse_demos(args.demos), methods=methods,
                                  plant_time_step_s=args.plant_step, settle_s=args.settle,
                                  sensitivity_shapes=sensitivity, c8_shapes=c8,
                                  offline_solver=args.solver,
                                  speeds=_number_list(args.speeds, "--speeds"), plants=plants,
                                  kf_form=args.kf_form, chain=args.chain,
                                  kf_sigma0_factors=(
                                      () if args.kf_sigma0_factors.strip() == "none" else
                                      _number_list(args.kf_sigma0_factors,
                                                   "--kf-sigma0-factors")))
    except ValueError as error:
        raise ValueError(name_fields(str(error), _EXPERIMENT_OPTIONS)) from None
    if not 0 <= args.workers <= MAX_WORKERS:
        raise ValueError(f"--workers = {args.workers} must be within 0 and {MAX_WORKERS}")
    shard = parse_shard(args.shard)
    sources = None
    if args.merge is not None:
        sources = [part.strip() for part in args.merge.split(",") if part.strip()]
        if not sources:
            raise ValueError(f"--merge = {quote(args.merge)} names no folder")
    # The experiment's --out is its journal (records.jsonl grows as tasks finish, and a rerun
    # continues it), so it is a work folder: checked, made, and removed again only if the
    # command fails before anything is in it; its report files are written atomically.
    with _scenario_outputs(args, base) as outputs:
        out = outputs.work_folder("--out", args.out)
        if sources is not None:
            report = merge_experiment_reports(out, sources, base, config)
        else:
            report = write_experiment_report(out, base, config, workers=args.workers,
                                             scheduler=args.scheduler, shard=shard)
    print(f"report: {report}")
    return 0


def _add_bench_parser(subparsers) -> None:
    p = subparsers.add_parser(
        "bench", add_help=False,
        help="the performance benchmark (Offline-CKS solvers vs RTS, online step vs Ruckig, "
             "simulation real-time factors); --help lists its options",
        description="The performance benchmark (its own options: telesmooth bench --help).")
    p.set_defaults(handler=None)  # main() hands `bench …` to bench_core before parsing


_PROCESS_DESCRIPTIONS = {
    "ground": "The ground station as its own process: the operator source, IK, FIFO, smoother "
              "and the signed 4 Hz uplink published on LCM, the robot's telemetry received.",
    "onboard": "The onboard robot as its own process: receives and checks the uplink "
               "commands on LCM (signature, session, freshness), drives the flexible-joint "
               "plant and publishes its telemetry.",
}


def _add_process_parsers(subparsers) -> None:
    from telesmooth.lcm_types.channels import DEFAULT_LCM_URL

    for name, text in (("ground", "run the ground station process (publishes the 4 Hz uplink)"),
                       ("onboard", "run the onboard robot process (subscribes to the uplink)")):
        p = subparsers.add_parser(name, help=text, description=_PROCESS_DESCRIPTIONS[name])
        _add_scenario_arguments(p)
        p.add_argument("--lcm-url", default=None,
                       help=f"LCM URL (default: the scenario's, {DEFAULT_LCM_URL})")
        p.add_argument("--duration", type=number, default=None,
                       help="seconds to run (ground default: the recording + settle time)")
        p.add_argument("--realtime", type=number, default=1.0,
                       help="target real-time rate (default 1; 0 = as fast as possible)")
        p.add_argument("--out", type=Path, default=None,
                       help="folder for the sent/received commands (CSV)")
        p.add_argument("--uplink-key", type=Path, default=None,
                       help="file with the shared HMAC key of the uplink (hex; make one with "
                            "`telesmooth keygen FILE`); default: the environment variable "
                            "TELESMOOTH_UPLINK_KEY")
        p.add_argument("--no-auth", action="store_true",
                       help="send/accept unsigned commands (anyone on the network can then "
                            "command the robot; for a bench without a key only)")
        if name == "ground":
            p.add_argument("--resume-wait", type=number, default=2.0,
                           help="seconds to wait for the robot's telemetry at start; if it "
                                "comes, the ground starts from the robot's commanded pose "
                                "(a restart continues without a jump); 0 = do not wait")
        p.set_defaults(handler=run_process, process=name)
    p = subparsers.add_parser(
        "keygen", help="write a fresh uplink HMAC key file (mode 0600)",
        description="Write a fresh random HMAC key for the uplink to a new file (mode 0600; "
        "never overwrites one). Give the same file to the ground and onboard processes with "
        "--uplink-key.")
    p.add_argument("path", help="the key file to create (never overwritten; missing folders "
                                "are made with mode 0700)")
    p.set_defaults(handler=run_keygen)
    p = subparsers.add_parser(
        "link-relay", add_help=False,
        help="relay the uplink between two LCM URLs through a fault model (delay, jitter, "
             "loss, duplication, reordering, outages); --help lists its options",
        description="The LCM relay with link faults (its own options: telesmooth link-relay "
        "--help).")
    p.set_defaults(handler=None)  # main() hands `link-relay …` to telesmooth.link.relay


def run_keygen(args) -> int:
    from telesmooth.link.auth import generate_key_file

    generate_key_file(args.path)   # refuses an existing path; makes missing folders 0700
    print(f"uplink key written to {args.path} (mode 0600); give the same file to the ground "
          "and onboard processes with --uplink-key")
    return 0


def run_process(args) -> int:
    from telesmooth.lcm_types.channels import check_lcm_url
    from telesmooth.scripts.processes import run_ground, run_onboard

    scenario = _load_scenario(args)
    url = check_lcm_url("--lcm-url" if args.lcm_url else "lcm_url (scenario)",
                        args.lcm_url or scenario.lcm_url)
    _check_at_most("settle_s", scenario.settle_s, MAX_SIMULATED_S)
    if args.duration is not None:
        _check_finite("--duration", args.duration)
        _check_at_most("--duration", args.duration, MAX_PROCESS_RUN_S)
    _check_finite("--realtime", args.realtime, allow_zero=True)
    if args.process == "ground":
        _check_finite("--resume-wait", args.resume_wait, allow_zero=True)
    elif args.duration is None:
        raise ValueError("onboard needs --duration (seconds to run)")
    key = None
    if args.no_auth:
        print(f"telesmooth {args.process}: warning: --no-auth: uplink commands are not "
              "authenticated; anyone on the network can command the robot", file=sys.stderr)
    else:
        from telesmooth.link.auth import load_key

        try:
            key = load_key(args.uplink_key)
        except ValueError as error:   # names the file or the variable, never the key
            raise ValueError(f"--uplink-key: {error}" if args.uplink_key is not None
                             else str(error)) from None
    with _scenario_outputs(args, scenario, ("--uplink-key", args.uplink_key)) as outputs:
        out = None if args.out is None else outputs.folder("--out", args.out)
        if args.process == "ground":
            status = run_ground(scenario, lcm_url=url, duration_s=args.duration,
                                realtime=args.realtime, out=out, uplink_key=key,
                                resume_wait_s=args.resume_wait)
        else:
            status = run_onboard(scenario, lcm_url=url, duration_s=args.duration,
                                 realtime=args.realtime, out=out, uplink_key=key)
    if args.out is not None:
        print(f"report: {args.out / 'report.md'}")
    return status


def package_version() -> str:
    """The installed package's version (``importlib.metadata``); from a source tree that is
    not installed, the version in its ``pyproject.toml``."""
    from importlib import metadata

    try:
        return metadata.version("telesmooth")
    except metadata.PackageNotFoundError:
        import tomllib

        pyproject = Path(__file__).resolve().parents[1] / "pyproject.toml"
        return tomllib.loads(pyproject.read_text(encoding="utf-8"))["project"]["version"]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="telesmooth",
        description="Acceleration/jerk-limited Kalman smoothing for delayed teleoperation.",
        epilog=f"{DEBUG_FLAG} (anywhere on the command line): on an unexpected error, print "
               "the full traceback instead of one line.",
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {package_version()}",
                        help="print the package version and exit")
    parser.add_argument(DEBUG_FLAG, action="store_true",
                        help="print the traceback of an unexpected error")
    subparsers = parser.add_subparsers(dest="command", required=True)
    _add_smooth_parser(subparsers)
    _add_demo_parser(subparsers)
    _add_simulate_parser(subparsers)
    _add_teleop_parser(subparsers)
    _add_operator_parser(subparsers)
    _add_compare_parser(subparsers)
    _add_foresight_parser(subparsers)
    _add_experiment_parser(subparsers)
    _add_bench_parser(subparsers)
    _add_process_parsers(subparsers)
    return parser


def one_line(message: str, limit: int = MAX_MESSAGE_CHARS) -> str:
    """``message`` on one line (runs of white space become one space), cut to ``limit``."""
    text = re.sub(r"\s+", " ", str(message)).strip()
    return text if len(text) <= limit else text[:limit - 1] + "…"


def _describe(error: BaseException) -> str:
    """An expected error as its message; an ``OSError`` as "<file>: <reason>"."""
    if isinstance(error, OSError) and error.strerror:
        where = error.filename if error.filename is not None else ""
        return f"{quote(str(where))}: {error.strerror}" if where else error.strerror
    return str(error)


_UNEXPECTED = (RecursionError, NotImplementedError, MemoryError)
"""Subclasses of the expected types that mean a bug or a missing bound, not bad input."""


def run_reporting_errors(command: str, handler, *, debug: bool = False) -> int:
    """Runs ``handler()``; returns its status, or prints one line for an error (see the
    module docstring): 2 for bad input, 1 for a bug (with the hint to rerun with
    ``--debug``), 130 for Ctrl-C. With ``debug`` every error raises, traceback and all."""
    prefix = f"telesmooth {command}:"
    try:
        return handler()
    except KeyboardInterrupt:
        if debug:
            raise
        print(f"{prefix} interrupted", file=sys.stderr)
        return 130
    except _UNEXPECTED as error:
        if debug:
            raise
        _report_bug(prefix, error)
        return 1
    except (ValueError, RuntimeError, OSError) as error:
        if debug:
            raise
        head = f"{prefix} error: "
        print(head + one_line(_describe(error), MAX_MESSAGE_CHARS - len(head)), file=sys.stderr)
        return 2
    except Exception as error:  # noqa: BLE001 - anything else is a bug, said in one line
        if debug:
            raise
        _report_bug(prefix, error)
        return 1


def _report_bug(prefix: str, error: BaseException) -> None:
    hint = f"; this is a bug: rerun with {DEBUG_FLAG} for the traceback and report it"
    head = f"{prefix} internal error: {type(error).__name__}: "
    print(head + one_line(str(error), MAX_MESSAGE_CHARS - len(head) - len(hint)) + hint,
          file=sys.stderr)


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    debug = DEBUG_FLAG in argv
    argv = [arg for arg in argv if arg != DEBUG_FLAG]
    if argv[:1] == ["bench"]:
        # The benchmark has its own parser (also `python -m telesmooth.scripts.bench_core`).
        from telesmooth.scripts.bench_core import main as bench_main

        return run_reporting_errors("bench", lambda: bench_main(argv[1:]), debug=debug)
    if argv[:1] == ["link-relay"]:
        from telesmooth.link.relay import main as relay_main

        return run_reporting_errors("link-relay", lambda: relay_main(argv[1:]), debug=debug)
    parser = build_parser()
    args = parser.parse_args(argv)
    return run_reporting_errors(args.command, lambda: args.handler(args), debug=debug)


if __name__ == "__main__":
    sys.exit(main())
