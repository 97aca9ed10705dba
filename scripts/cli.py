"""The ``telesmooth`` command line.

Subcommands:
    smooth   smooth a joint trajectory CSV with one method (the contract in the README)
    demo     the main job: a real human demonstration (LASA) through every method, with a report

Errors in user input are printed as one clear line (exit status 2); nothing is written then.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path


from telesmooth.smoothing.kalman import START_PRIORS
from telesmooth.smoothing.methods import METHODS, SmoothingSettings, smooth_recording
from telesmooth.smoothing.metrics import smoothing_metrics
from telesmooth.smoothing.model import DEFAULT_LAG, DEFAULT_R, DEFAULT_SIGMA
from telesmooth.smoothing.offline import OFFLINE_CONSTRAINTS, OFFLINE_SOLVERS
from telesmooth.smoothing.reduced_q import (
    REDUCED_Q_VARIANTS,
    SIGMA_STEP_RULES,
    VIOLATION_TRIGGERS,
    ReducedQConfig,
    load_operator_sigma,
    save_operator_sigma,
    stored_operators,
)
from telesmooth.smoothing.trajectory_io import read_joint_csv, write_joint_csv
from telesmooth.smoothing.validation import as_per_joint


def parse_per_joint(text: str):
    """``"0.1"`` → 0.1; ``"0.1,0.2,0.3"`` → [0.1, 0.2, 0.3]; ``"a=0.1,b=0.2"`` → {a: 0.1, b: 0.2}."""
    parts = [part.strip() for part in text.split(",")]
    try:
        if any("=" in part for part in parts):
            pairs = [part.split("=", 1) for part in parts]
            return {name.strip(): float(value) for name, value in pairs}
        values = [float(part) for part in parts]
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"{text!r}: give a number, a comma list (one per joint) or name=value pairs"
        ) from None
    return values[0] if len(values) == 1 else values


def _add_smooth_parser(subparsers) -> None:
    p = subparsers.add_parser(
        "smooth",
        help="smooth a joint trajectory CSV (t,<joints…>; s, rad; uniform step)",
        description="Smooth an operator's joint trajectory so that acceleration and jerk stay "
        "within the robot's limits. Limits take one value for all joints, a comma list "
        "(one per joint, in column order) or name=value pairs.",
    )
    p.add_argument("input", type=Path, help="input CSV: header t,<joint names…>")
    p.add_argument("-o", "--output", type=Path, required=True, help="output CSV")
    p.add_argument("--method", choices=METHODS, default="online-cks")
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
    p.add_argument("--dt", type=float, default=None, metavar="S",
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
    p.add_argument("--rho", type=float, default=0.8, help="multiplicative σ factor (0.8)")
    p.add_argument("--sigma-min", type=float, default=None, help="σ_min (default 2.5e-4 σ_0)")
    p.add_argument("--trigger", choices=VIOLATION_TRIGGERS, default="state",
                   help="online-cks trigger: output block states or FD of sent positions")
    p.add_argument("--operator", default=None,
                   help="online-cks: operator name whose σ is loaded from/saved to --sigma-store")
    p.add_argument("--sigma-store", type=Path, default=None,
                   help="JSON file of per-operator σ (loaded as σ_0 if present, updated after)")
    p.add_argument("--link-lengths", type=parse_per_joint, default=None, metavar="L1,L2,…",
                   help="planar link lengths [m]: adds the Cartesian deformation to --metrics")
    p.add_argument("--metrics", type=Path, default=None, metavar="OUT.json",
                   help="write the SPEC §6 metrics as JSON")
    p.set_defaults(handler=run_smooth)


def _planar_fk(planar_forward_kinematics, link_lengths, q):
    return planar_forward_kinematics(q, link_lengths)


def run_smooth(args) -> int:
    trajectory = read_joint_csv(args.input, expected_dt_s=args.dt)
    names = list(trajectory.joint_names)
    settings = SmoothingSettings(
        max_acceleration=as_per_joint("--acc-max", args.acc_max, len(names), names),
        max_jerk=as_per_joint("--jerk-max", args.jerk_max, len(names), names),
        max_velocity=(None if args.vel_max is None
                      else as_per_joint("--vel-max", args.vel_max, len(names), names)),
        sigma=as_per_joint("--sigma", args.sigma, len(names), names),
        r=as_per_joint("--r", args.r, len(names), names),
        lag=args.lag,
        constraint=args.constraint,
        rest_at_end=args.rest_at_end,
        start_prior=args.start_prior,
        offline_solver=args.solver,
        reduced_q=ReducedQConfig(variant=args.variant, step_rule=args.sigma_step, rho=args.rho,
                                 sigma_min=args.sigma_min, trigger=args.trigger),
    )
    if (args.operator is None) != (args.sigma_store is None):
        raise ValueError("--operator and --sigma-store go together")
    if args.link_lengths is not None:
        link_lengths = as_per_joint("--link-lengths", args.link_lengths, len(names), names)
    sigma0 = None
    if args.operator is not None and args.operator in stored_operators(args.sigma_store):
        sigma0 = load_operator_sigma(args.sigma_store, args.operator, names)
        print(f"operator {args.operator!r}: σ_0 = {sigma0.tolist()} from {args.sigma_store}",
              file=sys.stderr)
    elif args.operator is not None:
        print(f"operator {args.operator!r}: new operator, σ_0 = --sigma", file=sys.stderr)
    result = smooth_recording(trajectory.positions, trajectory.dt_s, args.method, settings,
                              joint_names=names, sigma0=sigma0)
    write_joint_csv(args.output, trajectory.t_s, result.positions, names,
                    extra_columns={"sent_t": trajectory.t_s + result.sent_delay_s})
    print(f"wrote {args.output} ({len(trajectory.t_s)} samples, method {args.method})",
          file=sys.stderr)
    if args.metrics is not None:
        forward_kinematics = None
        if args.link_lengths is not None:
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
            joint_names=names,
        )
        metrics["method"] = args.method
        metrics["sent_delay_s"] = result.sent_delay_s
        metrics["details"] = result.details
        if result.final_sigma is not None:
            metrics["final_sigma"] = result.final_sigma.tolist()
        args.metrics.parent.mkdir(parents=True, exist_ok=True)
        args.metrics.write_text(json.dumps(metrics, indent=2) + "\n")
        print(f"wrote {args.metrics}", file=sys.stderr)
    if args.operator is not None and result.final_sigma is not None:
        save_operator_sigma(args.sigma_store, args.operator, names, result.final_sigma)
        print(f"operator {args.operator!r}: σ = {result.final_sigma.tolist()} saved to "
              f"{args.sigma_store}", file=sys.stderr)
    return 0


def _add_demo_parser(subparsers) -> None:
    p = subparsers.add_parser(
        "demo",
        help="smooth a real human demonstration (LASA) with every method and write a report",
    )
    p.add_argument("--out", type=Path, default=Path("out/demo"), help="report folder")
    p.add_argument("--shape", default="Angle", help="LASA shape (default Angle)")
    p.add_argument("--demo-index", type=int, default=0, help="demonstration 0–6 (default 0)")
    p.set_defaults(handler=run_demo)


def run_demo(args) -> int:
    from telesmooth.scripts.demo_report import write_demo_report

    report = write_demo_report(args.out, shape=args.shape, demo_index=args.demo_index)
    print(f"report: {report}")
    return 0


def _add_scenario_arguments(p) -> None:
    p.add_argument("--scenario", type=Path, default=None,
                   help="scenario YAML file (default: the built-in diagrams/scenarios.yaml)")
    p.add_argument("--scenario-name", default=None, help="entry of the file (default Defaults)")
    p.add_argument("--scenario-text", default=None,
                   help="YAML overrides, e.g. \"{arm: space_arm, smoother: {method: bmfls}}\"")
    p.add_argument("--on-collision", choices=("hold", "stop"), default=None,
                   help="what a pre-simulator collision does (the scenario's fifo.on_collision, "
                        "default hold): 'hold' re-sends the last command (the paper), 'stop' "
                        "brakes within the acceleration and jerk limits")


def _load_scenario(args):
    import dataclasses

    from telesmooth.diagrams.scenario import load_scenario

    scenario = load_scenario(filename=args.scenario, scenario_name=args.scenario_name,
                             scenario_text=args.scenario_text)
    if getattr(args, "on_collision", None) is not None:
        scenario = dataclasses.replace(scenario, fifo=dataclasses.replace(
            scenario.fifo, on_collision=args.on_collision))
    return scenario


def _add_simulate_parser(subparsers) -> None:
    p = subparsers.add_parser(
        "simulate",
        help="run a scenario headless through the whole chain and write a report",
    )
    _add_scenario_arguments(p)
    p.add_argument("--out", type=Path, default=Path("out/simulate"), help="report folder")
    p.add_argument("--duration", type=float, default=None,
                   help="simulated time in s (default: the recording + settle time)")
    p.add_argument("--meshcat", action="store_true",
                   help="also save a self-contained Meshcat replay, run.html")
    p.set_defaults(handler=run_simulate)


def run_simulate(args) -> int:
    from telesmooth.scripts.simulate_report import write_simulation_report

    scenario = _load_scenario(args)
    if args.duration is not None and not (args.duration > 0):
        raise ValueError(f"--duration = {args.duration!r} must be positive")
    report = write_simulation_report(args.out, scenario, duration_s=args.duration,
                                     meshcat_html=args.meshcat)
    print(f"report: {report}")
    return 0


def _add_compare_parser(subparsers) -> None:
    from telesmooth.diagrams.comparison import COMPARE_METHODS

    p = subparsers.add_parser(
        "compare",
        help="every smoothing method on one scenario through the same plant (paper Table 2)",
    )
    _add_scenario_arguments(p)
    p.add_argument("--out", type=Path, default=Path("out/compare"), help="report folder")
    p.add_argument("--methods", default=",".join(COMPARE_METHODS),
                   help="comma list of methods (default all: " + ",".join(COMPARE_METHODS)
                   + "); original is always run, it is the reference of P")
    _add_offline_solver_argument(p)
    p.set_defaults(handler=run_compare)


def _add_foresight_parser(subparsers) -> None:
    from telesmooth.diagrams.comparison import COMPARE_METHODS

    p = subparsers.add_parser(
        "foresight",
        help="how much of a method's deformation needed foresight: the best continuation of "
             "its commands from every step-th sample, the whole future known",
    )
    _add_scenario_arguments(p)
    p.add_argument("--out", type=Path, default=Path("out/foresight"), help="report folder")
    p.add_argument("--method", choices=COMPARE_METHODS, default="online-hard",
                   help="the method whose commands are continued (default online-hard)")
    p.add_argument("--step", type=int, default=4,
                   help="samples between two starts (default 4: every second at 4 Hz)")
    p.set_defaults(handler=run_foresight)


def run_foresight(args) -> int:
    from telesmooth.scripts.foresight_report import write_foresight_report

    report = write_foresight_report(args.out, _load_scenario(args), args.method,
                                    step=args.step)
    print(f"report: {report}")
    return 0


def _add_offline_solver_argument(p) -> None:
    p.add_argument("--solver", choices=OFFLINE_SOLVERS, default="drake",
                   help="solver of the Offline-CKS methods: 'drake' (the MathematicalProgram + "
                        "Clarabel, default) or 'banded-ip' (the banded interior point: the same "
                        "optimum to ~1e-6 rad, faster)")


def run_compare(args) -> int:
    from telesmooth.scripts.compare_report import write_comparison_report

    scenario = _load_scenario(args)
    methods = tuple(m.strip() for m in args.methods.split(",") if m.strip())
    if not methods:
        raise ValueError(f"--methods = {args.methods!r} names no method")
    report = write_comparison_report(args.out, scenario, methods=methods,
                                     offline_solver=args.solver)
    print(f"report: {report}")
    return 0


def _add_experiment_parser(subparsers) -> None:
    from telesmooth.diagrams.experiment import EXPERIMENT_METHODS, KF_FORMS, ExperimentConfig

    defaults = ExperimentConfig()
    p = subparsers.add_parser(
        "experiment",
        help="the paper's experiment on the LASA demonstrations: every method, the claims "
             "C1-C8, the Online-CKS sensitivity; on a Dask cluster",
    )
    _add_scenario_arguments(p)
    p.add_argument("--out", type=Path, default=Path("out/experiment"), help="report folder")
    p.add_argument("--shapes", default="all",
                   help="comma list of LASA shapes, or 'all' (default: all 30)")
    p.add_argument("--demos", default="0",
                   help="demonstrations of each shape: comma list of 0-6, or 'all' "
                        "(default 0; 'all' is the full grid of 210)")
    p.add_argument("--methods", default=",".join(EXPERIMENT_METHODS),
                   help="comma list of methods (default all: " + ",".join(EXPERIMENT_METHODS)
                   + ")")
    p.add_argument("--sensitivity-shapes", default=",".join(defaults.sensitivity_shapes),
                   help="shapes of the Online-CKS sensitivity study ('none' to skip)")
    p.add_argument("--c8-shapes", default="all",
                   help="shapes of the C8 study, each over its 7 demonstrations "
                        "('none' to skip; default all)")
    p.add_argument("--plant-step", type=float, default=defaults.plant_time_step_s,
                   help=f"plant time step in s (default {defaults.plant_time_step_s})")
    p.add_argument("--settle", type=float, default=defaults.settle_s,
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
                   help="run only every N-th task from the K-th (split a grid across runs or "
                        "machines; --merge joins the folders)")
    p.add_argument("--merge", default=None, metavar="DIR,DIR",
                   help="run nothing: join the records of these folders (the same grid, e.g. "
                        "its shards) into --out and write the report")
    _add_offline_solver_argument(p)
    p.set_defaults(handler=run_experiment_command)


def _shape_list(text: str, option: str) -> tuple:
    from telesmooth.datasets.lasa import LASA_SHAPES

    text = text.strip()
    if text == "all":
        return LASA_SHAPES
    if text in ("none", ""):
        return ()
    shapes = tuple(part.strip() for part in text.split(",") if part.strip())
    unknown = [s for s in shapes if s not in LASA_SHAPES]
    if unknown:
        raise ValueError(f"{option} = {text!r}: unknown shape(s) {unknown}; the shapes are "
                         f"{', '.join(LASA_SHAPES)}")
    return shapes


def _number_list(text: str, option: str) -> tuple[float, ...]:
    try:
        values = tuple(float(part) for part in text.split(",") if part.strip())
    except ValueError:
        raise ValueError(f"{option} = {text[:60]!r} must be a comma list of numbers") from None
    if not values:
        raise ValueError(f"{option} = {text[:60]!r} names no value")
    return values


def run_experiment_command(args) -> int:
    from telesmooth.diagrams.experiment import ExperimentConfig
    from telesmooth.scripts.experiment_report import (
        merge_experiment_reports,
        parse_demos,
        parse_shard,
        write_experiment_report,
    )

    base = _load_scenario(args)
    if args.quick:
        shapes, sensitivity, c8 = ("Angle", "CShape"), ("Angle",), ("Angle",)
    else:
        shapes = _shape_list(args.shapes, "--shapes")
        sensitivity = _shape_list(args.sensitivity_shapes, "--sensitivity-shapes")
        c8 = _shape_list(args.c8_shapes, "--c8-shapes")
    if not shapes:
        raise ValueError("--shapes names no shape")
    methods = tuple(m.strip() for m in args.methods.split(",") if m.strip())
    plants = tuple(p.strip() for p in args.plants.split(",") if p.strip())
    config = ExperimentConfig(shapes=shapes, demos=parse_demos(args.demos), methods=methods,
                              plant_time_step_s=args.plant_step, settle_s=args.settle,
                              sensitivity_shapes=sensitivity, c8_shapes=c8,
                              offline_solver=args.solver,
                              speeds=_number_list(args.speeds, "--speeds"), plants=plants,
                              kf_form=args.kf_form)
    if args.workers < 0:
        raise ValueError(f"--workers = {args.workers} must be >= 0")
    if args.merge is not None:
        sources = [part.strip() for part in args.merge.split(",") if part.strip()]
        if not sources:
            raise ValueError(f"--merge = {args.merge[:60]!r} names no folder")
        report = merge_experiment_reports(args.out, sources, base, config)
    else:
        report = write_experiment_report(args.out, base, config, workers=args.workers,
                                         scheduler=args.scheduler,
                                         shard=parse_shard(args.shard))
    print(f"report: {report}")
    return 0


def _add_bench_parser(subparsers) -> None:
    p = subparsers.add_parser(
        "bench", add_help=False,
        help="the performance benchmark (Offline-CKS solvers vs RTS, online step vs Ruckig, "
             "simulation real-time factors); --help lists its options")
    p.set_defaults(handler=None)  # main() hands `bench …` to bench_core before parsing


def _add_process_parsers(subparsers) -> None:
    from telesmooth.diagrams.channels import DEFAULT_LCM_URL

    for name, text in (("ground", "run the ground station process (publishes the 4 Hz uplink)"),
                       ("onboard", "run the onboard robot process (subscribes to the uplink)")):
        p = subparsers.add_parser(name, help=text)
        _add_scenario_arguments(p)
        p.add_argument("--lcm-url", default=None,
                       help=f"LCM URL (default: the scenario's, {DEFAULT_LCM_URL})")
        p.add_argument("--duration", type=float, default=None,
                       help="seconds to run (ground default: the recording + settle time)")
        p.add_argument("--realtime", type=float, default=1.0,
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
            p.add_argument("--resume-wait", type=float, default=2.0,
                           help="seconds to wait for the robot's telemetry at start; if it "
                                "comes, the ground starts from the robot's commanded pose "
                                "(a restart continues without a jump); 0 = do not wait")
        p.set_defaults(handler=run_process, process=name)
    p = subparsers.add_parser("keygen", help="write a fresh uplink HMAC key file (mode 0600)")
    p.add_argument("path", type=Path, help="the key file to create (never overwritten)")
    p.set_defaults(handler=run_keygen)
    p = subparsers.add_parser(
        "link-relay", add_help=False,
        help="relay the uplink between two LCM URLs through a fault model (delay, jitter, "
             "loss, duplication, reordering, outages); --help lists its options")
    p.set_defaults(handler=None)  # main() hands `link-relay …` to telesmooth.link.relay


def run_keygen(args) -> int:
    from telesmooth.link.auth import generate_key_file

    generate_key_file(args.path)
    print(f"uplink key written to {args.path} (mode 0600); give the same file to the ground "
          "and onboard processes with --uplink-key")
    return 0


def run_process(args) -> int:
    from telesmooth.scripts.processes import run_ground, run_onboard

    scenario = _load_scenario(args)
    url = args.lcm_url or scenario.lcm_url
    if args.duration is not None and not args.duration > 0:
        raise ValueError(f"--duration = {args.duration!r} must be positive")
    if not args.realtime >= 0:
        raise ValueError(f"--realtime = {args.realtime!r} must be >= 0")
    key = None
    if args.no_auth:
        print(f"telesmooth {args.process}: warning: --no-auth: uplink commands are not "
              "authenticated; anyone on the network can command the robot", file=sys.stderr)
    else:
        from telesmooth.link.auth import load_key
        key = load_key(args.uplink_key)
    if args.process == "ground":
        if not args.resume_wait >= 0:
            raise ValueError(f"--resume-wait = {args.resume_wait!r} must be >= 0")
        return run_ground(scenario, lcm_url=url, duration_s=args.duration,
                          realtime=args.realtime, out=args.out, uplink_key=key,
                          resume_wait_s=args.resume_wait)
    if args.duration is None:
        raise ValueError("onboard needs --duration (seconds to run)")
    return run_onboard(scenario, lcm_url=url, duration_s=args.duration,
                       realtime=args.realtime, out=args.out, uplink_key=key)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="telesmooth",
        description="Acceleration/jerk-limited Kalman smoothing for delayed teleoperation.",
    )
    subparsers = parser.add_subparsers(dest="command", required=True)
    _add_smooth_parser(subparsers)
    _add_demo_parser(subparsers)
    _add_simulate_parser(subparsers)
    _add_compare_parser(subparsers)
    _add_foresight_parser(subparsers)
    _add_experiment_parser(subparsers)
    _add_bench_parser(subparsers)
    _add_process_parsers(subparsers)
    return parser


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    if argv[:1] == ["bench"]:
        # The benchmark has its own parser (also `python -m telesmooth.scripts.bench_core`).
        from telesmooth.scripts.bench_core import main as bench_main

        return bench_main(argv[1:])
    if argv[:1] == ["link-relay"]:
        from telesmooth.link.relay import main as relay_main

        return relay_main(argv[1:])
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return args.handler(args)
    except (ValueError, RuntimeError) as error:
        print(f"telesmooth {args.command}: error: {error}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
