"""Benchmark of the smoothing core: prints a table and writes JSON (``make bench``).

Measured side by side in one run (this machine is noisy; compare ratios, not absolutes):

* Offline-CKS for 6 joints at N = 10² … 10⁵ in both constraint modes, against one RTS pass
  (filter + backward pass) on the same data: the floor any offline smoother pays.
* The online step per 4 Hz tick for 6 joints at L = 3 and L = 75: the fixed-lag smoother
  (superstate filter and exact recursion), Online-CKS (recursion + reduced-Q), the hard
  limiter alone (``telesmooth.safety.limiter.limiter_step`` on Online-CKS's outputs) and
  online-hard (Online-CKS + the limiter), against Ruckig's update on the same stream (each
  sample a new target; the peer a user would reach for). Issue 18's goal for online-hard is
  40 µs per tick at L = 3.
* Simulation speed of the whole chain as a real-time factor (simulated / wall time) for the
  planar arm (Defaults) and the 6-DOF arm, and of the experiment's playback (uplink + plant) at
  the plant's 1 ms and the experiment's 5 ms step.

Usage: ``telesmooth bench [--out DIR] [--max-n 100000] [--repeat 3]`` (or
``python -m telesmooth.scripts.bench_core``, ``make bench``).
"""

from __future__ import annotations

import argparse
import json
import math
import platform
import sys
import time
from pathlib import Path

import numpy as np

from telesmooth.atomic_files import Outputs, write_text
from telesmooth.datasets.synthetic import synthetic_joint_motion
from telesmooth.smoothing.fixed_lag import FixedLagSmoother
from telesmooth.smoothing.kalman import rest_prior, rts_smoother
from telesmooth.smoothing.model import DEFAULT_DT_S, DEFAULT_R, DEFAULT_SIGMA, JerkModel
from telesmooth.smoothing.offline import solve_offline_cks
from telesmooth.safety.limiter import limiter_params, limiter_rest_state, limiter_step
from telesmooth.smoothing.reduced_q import OnlineCks

NUM_JOINTS = 6
MAX_ACCELERATION = 0.05
MAX_JERK = 0.1


def synthetic_operator(num_samples: int, num_joints: int, *, dt_s=DEFAULT_DT_S, seed=0):
    """Minimum-jerk reaches of ±0.4 rad lasting 2–6 s with pauses, plus N(0, (1e-3 rad)²).

    Targets are clipped to ±1.5 rad; every joint starts at 0 (see ``synthetic_joint_motion``,
    O(N): 0.9 s at N = 10⁵, 6 joints).
    """
    return synthetic_joint_motion(num_samples, num_joints, dt_s=dt_s, noise_rad=1e-3, seed=seed,
                                  position_limit_rad=1.5)


def _best_time(function, repeat):
    best, value = np.inf, None
    for _ in range(repeat):
        start = time.perf_counter()
        value = function()
        best = min(best, time.perf_counter() - start)
    return best, value


def bench_offline(sizes, repeat, max_drake_n=10_000):
    rows = []
    for n in sizes:
        z = synthetic_operator(n, NUM_JOINTS, seed=n)
        model = JerkModel.make(DEFAULT_DT_S, DEFAULT_SIGMA, DEFAULT_R, num_joints=NUM_JOINTS)
        prior = rest_prior(z[0], model)
        reps = repeat if n <= 10_000 else 1
        rts_s, _ = _best_time(lambda: rts_smoother(z, model, prior), reps)
        row = {"num_samples": n, "num_joints": NUM_JOINTS, "rts_s": rts_s}
        for mode in ("state", "trajectory"):
            for solver in ("drake", "banded-ip"):
                if solver == "drake" and n > max_drake_n:
                    continue
                key = f"{mode}_{solver.replace('-', '_')}"
                seconds, result = _best_time(
                    lambda: solve_offline_cks(z, model, max_acceleration=MAX_ACCELERATION,
                                              max_jerk=MAX_JERK, constraint=mode,
                                              solver=solver), reps)
                row[f"{key}_s"] = seconds
                row[f"{key}_over_rts"] = seconds / rts_s
                row[f"{key}_us_per_sample"] = 1e6 * seconds / n   # linear growth: constant
                row[f"{key}_success"] = bool(result.is_success)
                row[f"{key}_solver"] = result.solver_name
                row[f"{key}_positions"] = result.states[:, :, 0]
            if f"{mode}_drake_s" in row:
                row[f"{mode}_drake_over_banded_ip"] = (row[f"{mode}_drake_s"]
                                                        / row[f"{mode}_banded_ip_s"])
                row[f"{mode}_max_position_difference_rad"] = float(np.max(np.abs(
                    row[f"{mode}_drake_positions"] - row[f"{mode}_banded_ip_positions"])))
            for solver in ("drake", "banded_ip"):
                row.pop(f"{mode}_{solver}_positions", None)
        rows.append(row)
        print(f"  offline N={n:>6}: RTS {rts_s:8.3f} s | " + " | ".join(
            f"{mode} {solver} {row[f'{mode}_{solver}_s']:8.3f} s "
            f"({row[f'{mode}_{solver}_over_rts']:5.1f}× RTS)"
            for mode in ("state", "trajectory") for solver in ("drake", "banded_ip")
            if f"{mode}_{solver}_s" in row), file=sys.stderr, flush=True)
    return rows


def _ruckig_stream_step(z, ticks):
    """Ruckig's update per tick on the stream z (6 joints), each sample the new target."""
    try:
        import ruckig
    except ImportError:
        return None
    n = z.shape[1]
    generator = ruckig.Ruckig(n, DEFAULT_DT_S)
    request, result = ruckig.InputParameter(n), ruckig.OutputParameter(n)
    request.max_velocity = [1e3] * n
    request.max_acceleration = [MAX_ACCELERATION] * n
    request.max_jerk = [MAX_JERK] * n
    request.synchronization = ruckig.Synchronization.No
    request.current_position = z[0].tolist()
    targets = [row.tolist() for row in z]
    for k in range(ticks):
        request.target_position = targets[k]
        generator.update(request, result)
        result.pass_to_input(request)
    return result


def bench_online(lags, ticks, repeat):
    rows = []
    z = synthetic_operator(ticks, NUM_JOINTS, seed=1)
    model = JerkModel.make(DEFAULT_DT_S, DEFAULT_SIGMA, DEFAULT_R, num_joints=NUM_JOINTS)
    ruckig_s, ruckig_result = _best_time(lambda: _ruckig_stream_step(z, ticks), repeat)
    ruckig_us = 1e6 * ruckig_s / ticks if ruckig_result is not None else None
    for lag in lags:
        row = {"lag": lag, "num_joints": NUM_JOINTS, "ticks": ticks}
        for method in ("superstate", "recursion"):
            smoother = FixedLagSmoother(model, lag=lag, method=method)

            def stream():
                state = smoother.initial_state(z[0])
                for k in range(ticks):
                    state = smoother.step(state, z[k])
                return state

            seconds, _ = _best_time(stream, repeat)
            row[f"{method}_us_per_tick"] = 1e6 * seconds / ticks
        online = OnlineCks(model, max_acceleration=MAX_ACCELERATION, max_jerk=MAX_JERK, lag=lag)

        def online_stream():
            state = online.initial_state(z[0])
            for k in range(ticks):
                state = online.step(state, z[k])[0]
            return state

        seconds, _ = _best_time(online_stream, repeat)
        row["online_cks_us_per_tick"] = 1e6 * seconds / ticks

        limits = limiter_params(dt_s=DEFAULT_DT_S, max_acceleration=MAX_ACCELERATION,
                                max_jerk=MAX_JERK, num_joints=NUM_JOINTS)

        def hard_stream():
            state = online.initial_state(z[0])
            limiter = limiter_rest_state(limits, z[0])
            for k in range(ticks):
                state, output, _ = online.step(state, z[k])
                limiter, _ = limiter_step(limits, limiter, output[:, 0])
            return limiter

        estimates = []
        state = online.initial_state(z[0])
        for k in range(ticks):
            state, output, _ = online.step(state, z[k])
            estimates.append(output[:, 0].copy())

        def limiter_alone():
            limiter = limiter_rest_state(limits, z[0])
            for estimate in estimates:
                limiter, _ = limiter_step(limits, limiter, estimate)
            return limiter

        seconds, _ = _best_time(limiter_alone, repeat)
        row["limiter_us_per_tick"] = 1e6 * seconds / ticks
        seconds, _ = _best_time(hard_stream, repeat)
        row["online_hard_us_per_tick"] = 1e6 * seconds / ticks
        row["superstate_over_recursion"] = (row["superstate_us_per_tick"]
                                            / row["recursion_us_per_tick"])
        if ruckig_us is not None:
            row["ruckig_us_per_tick"] = ruckig_us
            row["online_cks_over_ruckig"] = row["online_cks_us_per_tick"] / ruckig_us
            row["online_hard_over_ruckig"] = row["online_hard_us_per_tick"] / ruckig_us
        rows.append(row)
        print(f"  online L={lag:>3}: superstate {row['superstate_us_per_tick']:8.1f} µs/tick | "
              f"recursion {row['recursion_us_per_tick']:8.1f} µs/tick | Online-CKS "
              f"{row['online_cks_us_per_tick']:8.1f} µs/tick | limiter "
              f"{row['limiter_us_per_tick']:8.1f} µs/tick | online-hard "
              f"{row['online_hard_us_per_tick']:8.1f} µs/tick | Ruckig "
              f"{ruckig_us if ruckig_us is not None else float('nan'):8.1f} µs/tick",
              file=sys.stderr, flush=True)
    return rows


def bench_simulation(duration_s: float):
    """Real-time factors of the whole chain and of the experiment's playback."""
    import dataclasses

    from telesmooth.diagrams.comparison import prepare_comparison, run_method
    from telesmooth.diagrams.scenario import load_scenario
    from telesmooth.diagrams.simulation import simulate

    rows = []
    cases = (("planar arm (Defaults)", load_scenario(scenario_name="Defaults")),
             ("6-DOF arm (space_arm, LASA)", load_scenario(scenario_text="{arm: space_arm}")))
    for name, scenario in cases:
        record = simulate(scenario, duration_s=duration_s)
        wall = record.wall_time_s  # the simulation alone (not the diagram's construction)
        rows.append({"what": f"whole chain, {name}", "simulated_s": record.duration_s,
                     "wall_s": wall, "real_time_factor": record.duration_s / wall})
        print(f"  simulate {name}: {duration_s:.0f} s in {wall:.1f} s "
              f"(×{duration_s / wall:.1f} real time)", file=sys.stderr, flush=True)
    base = load_scenario(scenario_name="Defaults")
    for step in (1e-3, 5e-3):
        scenario = dataclasses.replace(base, onboard=dataclasses.replace(base.onboard,
                                                                         time_step_s=step))
        setup = prepare_comparison(scenario)
        started = time.perf_counter()
        run = run_method(setup, "online-cks")
        wall = time.perf_counter() - started
        rows.append({"what": f"experiment playback (online-cks), plant step {step * 1e3:g} ms",
                     "simulated_s": setup.duration_s, "wall_s": wall,
                     "real_time_factor": setup.duration_s / wall,
                     "e_mean_m": run.metrics["response_error_m"]["mean"]})
        print(f"  playback, plant step {step * 1e3:g} ms: {setup.duration_s:.0f} s in "
              f"{wall:.1f} s (×{setup.duration_s / wall:.1f} real time)", file=sys.stderr,
              flush=True)
    return rows


def _table(offline, online, simulation=()) -> str:
    lines = ["Offline-CKS, 6 joints (wall time incl. build; best of repeats); drake = "
             "MathematicalProgram + Clarabel, banded-ip = the banded interior point", "",
             "| N | RTS pass [s] | mode | drake [s] | drake / RTS | banded-ip [s] | "
             "banded-ip / RTS | drake / banded-ip | banded-ip [µs/sample] | max |Δq| [rad] |",
             "|---:|---:|---|---:|---:|---:|---:|---:|---:|---:|"]

    def cell(row, key, fmt):
        return fmt.format(row[key]) if key in row else "–"

    for r in offline:
        for mode in ("state", "trajectory"):
            lines.append(
                f"| {r['num_samples']} | {r['rts_s']:.4f} | {mode} | "
                f"{cell(r, f'{mode}_drake_s', '{:.3f}')} | "
                f"{cell(r, f'{mode}_drake_over_rts', '{:.1f}')} | "
                f"{cell(r, f'{mode}_banded_ip_s', '{:.3f}')} | "
                f"{cell(r, f'{mode}_banded_ip_over_rts', '{:.1f}')} | "
                f"{cell(r, f'{mode}_drake_over_banded_ip', '{:.1f}')} | "
                f"{cell(r, f'{mode}_banded_ip_us_per_sample', '{:.1f}')} | "
                f"{cell(r, f'{mode}_max_position_difference_rad', '{:.1e}')} |")
    lines += ["", "Online step per 4 Hz tick, 6 joints", "",
              "| L | superstate [µs/tick] | recursion [µs/tick] | superstate / recursion | "
              "Online-CKS [µs/tick] | limiter alone [µs/tick] | "
              "online-hard (Online-CKS + limiter) [µs/tick] | "
              "Ruckig update [µs/tick] | Online-CKS / Ruckig | online-hard / Ruckig |",
              "|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for r in online:
        lines.append(f"| {r['lag']} | {r['superstate_us_per_tick']:.1f} | "
                     f"{r['recursion_us_per_tick']:.1f} | {r['superstate_over_recursion']:.2f} | "
                     f"{r['online_cks_us_per_tick']:.1f} | {r['limiter_us_per_tick']:.1f} | "
                     f"{r['online_hard_us_per_tick']:.1f} | "
                     f"{cell(r, 'ruckig_us_per_tick', '{:.1f}')} | "
                     f"{cell(r, 'online_cks_over_ruckig', '{:.1f}')} | "
                     f"{cell(r, 'online_hard_over_ruckig', '{:.1f}')} |")
    if simulation:
        lines += ["", "Simulation speed", "",
                  "| what | simulated [s] | wall [s] | real-time factor |", "|---|---:|---:|---:|"]
        for r in simulation:
            lines.append(f"| {r['what']} | {r['simulated_s']:.1f} | {r['wall_s']:.1f} | "
                         f"{r['real_time_factor']:.1f} |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="telesmooth bench",
                                     description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("out/bench"))
    parser.add_argument("--max-n", type=int, default=100_000,
                        help="largest N of the Offline-CKS rows (10² … 10⁶; default 10⁵)")
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--ticks", type=int, default=2000)
    parser.add_argument("--max-drake-n", type=int, default=10_000,
                        help="largest N solved with the Drake MathematicalProgram too")
    parser.add_argument("--sim-duration", type=_number, default=30.0,
                        help="simulated seconds of the whole-chain real-time factor (0 = skip)")
    args = parser.parse_args(argv)
    for option, value in (("--max-n", args.max_n), ("--repeat", args.repeat),
                          ("--ticks", args.ticks), ("--max-drake-n", args.max_drake_n)):
        if value < 1:
            raise ValueError(f"{option} = {value} must be >= 1")
    if not (math.isfinite(args.sim_duration) and 0 <= args.sim_duration <= MAX_SIM_DURATION_S):
        raise ValueError(f"--sim-duration = {args.sim_duration!r} must be within 0 and "
                         f"{MAX_SIM_DURATION_S:g} s")
    with Outputs() as outputs:
        staged = outputs.folder("--out", args.out)
        table = _run(args, staged)
    print(table)
    print(f"wrote {args.out / 'bench_core.json'}", file=sys.stderr)
    return 0


MAX_SIM_DURATION_S = 3600.0
"""Longest --sim-duration, simulated s (two simulations of it are run)."""


def _number(text: str) -> float:
    from telesmooth.user_input import parse_plain_number

    try:
        return parse_plain_number(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text[:60]!r} is not a number") from None


def _run(args, out: Path) -> str:
    sizes = [n for n in (100, 1_000, 10_000, 100_000, 1_000_000) if n <= args.max_n]
    print("telesmooth core benchmark", file=sys.stderr)
    offline = bench_offline(sizes, args.repeat, args.max_drake_n)
    online = bench_online((3, 75), args.ticks, args.repeat)
    simulation = bench_simulation(args.sim_duration) if args.sim_duration > 0 else []
    report = {"machine": {"python": platform.python_version(), "processor": platform.machine()},
              "offline_cks": offline, "online_step": online, "simulation": simulation}
    write_text(out / "bench_core.json", json.dumps(report, indent=2) + "\n")
    table = _table(offline, online, simulation)
    write_text(out / "bench_core.md", table)
    return table


if __name__ == "__main__":
    sys.exit(main())
