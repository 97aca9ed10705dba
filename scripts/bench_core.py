"""Benchmark of the smoothing core and the simulation: prints a table and writes JSON
(``make bench``).

Measured side by side in one run (this machine is noisy; compare ratios, not absolutes).
Every row runs in a fresh process of its own, and its **peak memory** is that process's
peak resident set size (:data:`MEMORY_MEASURE`: Linux's ``VmHWM``, read at the end of the
row), given with the resident size before the measured work (Python, numpy, drake and
the row's input data: the "baseline"):

* Offline-CKS for 6 joints at N = 10² … 10⁶ in both constraint modes, the Drake
  MathematicalProgram and the banded interior point, against one RTS pass (filter + backward
  pass) on the same data: the floor any offline smoother pays, in time and in memory.
* The online step per 4 Hz tick for 6 joints at L = 3 and L = 75: the fixed-lag smoother
  (superstate filter and exact recursion), Online-CKS (recursion + reduced-Q), the hard
  limiter alone (``telesmooth.safety.limiter.limiter_step`` on Online-CKS's outputs) and
  online-hard (Online-CKS + the limiter), against Ruckig's update on the same stream (each
  sample a new target; the peer a user would reach for).
* Simulation: the real-time factor (simulated / wall time, and simulated / CPU time of the
  process, both over the simulator's advance alone; and simulated / wall time of the whole
  call, with the diagram's build and reading the logs back) of ``telesmooth simulate``'s chain
  on Defaults (planar arm) and OneOfEverything (6-DOF arm), the deployed chain (what
  ``simulate`` runs by default: the onboard receiver and link guard between the uplink and the
  robot) and the paper's chain (``--chain paper``: the uplink drives the robot) each a row of
  its own, beside the bare plant's (the flexible arm's MultibodyPlant alone, following a
  smooth set-point from a C++ source) at a 1 ms step, a 5 ms step and the default plant
  (continuous). Each chain row gives its real-time factor over the bare plant's of the same
  arm and plant step measured in the same run (:func:`over_bare_plant`, wall and CPU): the
  figure that carries from machine to machine, where the absolute factors do not. And the
  share of each stage of the
  chain: the CPU time spent inside each Python system's callbacks (timers around every
  callback a LeafSystem declares, nested calls counted once), and the rest, Drake's own work
  (plant, integrator, events, loggers).
* The experiment (``telesmooth experiment``): the time of each task (one demonstration, one
  method: smoothing and playback through the uplink and the plant) on a sample of
  demonstrations, with the default plant (the experiment's) and with a 5 ms plant step, and the
  whole grid extrapolated from it (see :func:`extrapolate_experiment`).

Usage: ``telesmooth bench [--out DIR] [--max-n 100000] [--repeat 3]`` (or
``python -m telesmooth.scripts.bench_core``, ``make bench``); ``--help`` lists the rest.
"""

from __future__ import annotations

import argparse
import json
import math
import multiprocessing
import os
import platform
import resource
import sys
import time
from collections import defaultdict
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from telesmooth.atomic_files import Outputs, write_text
from telesmooth.datasets.synthetic import synthetic_joint_motion
from telesmooth.smoothing.model import DEFAULT_DT_S, DEFAULT_R, DEFAULT_SIGMA, JerkModel

NUM_JOINTS = 6
MAX_ACCELERATION = 0.05
MAX_JERK = 0.1

CHAIN_SCENARIOS = ("Defaults", "OneOfEverything")
"""The scenarios whose chain ``telesmooth simulate`` runs in the simulation rows."""

CHAINS_TIMED = ("deployed", "paper")
"""The chains of the simulation rows, each scenario's: the deployed chain (``simulate``'s
default) and the paper's (``simulate --chain paper``)."""

BARE_PLANT_STEPS_S = (1e-3, 5e-3, 0.0)
"""Plant steps of the bare-plant rows: 1 ms and 5 ms discrete, and continuous (default)."""

EXPERIMENT_SAMPLE = ("Angle", "Sshape", "Snake")
"""Shapes (demonstration 0) of the experiment's sample: 30.5 s, 52.7 s and 84.4 s of
recording, around the mean of the 210 demonstrations (53.0 s; 19.1–93.2 s)."""


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


# -- one fresh process per row, with its peak memory ----------------------------------------


def resident_mb() -> float:
    """The resident set size of this process now, MB (Linux ``/proc/self/statm``)."""
    try:
        with open("/proc/self/statm") as statm:
            return int(statm.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20
    except OSError:        # not Linux: the peak so far is the best we know
        return peak_resident_mb()


MEMORY_MEASURE = ("peak resident set size of the row's own process (VmHWM of /proc/self/status; "
                  "getrusage's ru_maxrss where there is no /proc) and its resident size before "
                  "the measured work (baseline)")
"""What a row's memory figures are, as the JSON states it (:func:`peak_resident_mb`)."""


def peak_resident_mb() -> float:
    """The peak resident set size of this process's own memory so far, MB.

    On Linux the high-water mark of the process's address space (``VmHWM`` of
    ``/proc/self/status``), which starts afresh at ``exec``. Not ``ru_maxrss``: Linux carries
    it across fork and exec, so a row's process started from a parent holding 600 MB would read
    a peak of at least 600 MB whatever the row did (``tests/test_bench_memory.py``). Elsewhere
    ``ru_maxrss`` is the best there is.
    """
    try:
        with open("/proc/self/status") as status:
            for line in status:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) / 2**10              # kB
    except (OSError, ValueError, IndexError):
        pass
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return peak / 2**20 if sys.platform == "darwin" else peak / 2**10   # bytes / kB


def _with_memory(function, *args):
    """Runs in the row's own process: function(*args) → dict, with its peak memory."""
    baseline = resident_mb()
    row = function(*args)
    peak = peak_resident_mb()
    row["peak_rss_mb"] = peak
    row["baseline_rss_mb"] = baseline
    row["peak_above_baseline_mb"] = max(0.0, peak - baseline)
    return row


def in_fresh_process(function, *args) -> dict:
    """function(*args) (a dict) computed in a new process, with that process's peak memory
    (:func:`_with_memory`). ``function`` takes its input data as arguments or builds it
    before the work it measures; the baseline is read when it is called."""
    context = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(max_workers=1, mp_context=context) as pool:
        return pool.submit(_with_memory, function, *args).result()


# -- Offline-CKS against the RTS pass -------------------------------------------------------


def _offline_cell(num_samples: int, cell: str, repeat: int, keep_positions: bool) -> dict:
    """One solver on the benchmark's data: ``cell`` is "rts" or "<mode>_<solver>"."""
    from telesmooth.smoothing.kalman import rest_prior, rts_smoother
    from telesmooth.smoothing.offline import solve_offline_cks

    z = synthetic_operator(num_samples, NUM_JOINTS, seed=num_samples)
    model = JerkModel.make(DEFAULT_DT_S, DEFAULT_SIGMA, DEFAULT_R, num_joints=NUM_JOINTS)
    prior = rest_prior(z[0], model)
    reps = repeat if num_samples <= 10_000 else 1

    def work():
        if cell == "rts":
            return rts_smoother(z, model, prior)
        mode, solver = cell.split("_", 1)
        return solve_offline_cks(z, model, max_acceleration=MAX_ACCELERATION,
                                 max_jerk=MAX_JERK, constraint=mode,
                                 solver=solver.replace("_", "-"))

    # The memory is that of the first run (the process's peak); the time the best of reps.
    seconds, result = _best_time(work, reps)
    row = {"seconds": seconds}
    if cell != "rts":
        row.update(success=bool(result.is_success), solver=result.solver_name)
        if keep_positions:
            row["positions"] = result.states[:, :, 0]
    return row


def bench_offline(sizes, repeat, max_drake_n=10_000):
    rows = []
    for n in sizes:
        rts = in_fresh_process(_offline_cell, n, "rts", repeat, False)
        row = {"num_samples": n, "num_joints": NUM_JOINTS, "rts_s": rts["seconds"],
               "rts_peak_mb": rts["peak_rss_mb"],
               "rts_peak_above_baseline_mb": rts["peak_above_baseline_mb"]}
        for mode in ("state", "trajectory"):
            positions = {}
            for solver in ("drake", "banded_ip"):
                if solver == "drake" and n > max_drake_n:
                    continue
                key = f"{mode}_{solver}"
                cell = in_fresh_process(_offline_cell, n, key, repeat, n <= max_drake_n)
                seconds = cell["seconds"]
                row[f"{key}_s"] = seconds
                row[f"{key}_over_rts"] = seconds / row["rts_s"]
                row[f"{key}_us_per_sample"] = 1e6 * seconds / n   # linear growth: constant
                row[f"{key}_success"] = cell["success"]
                row[f"{key}_solver"] = cell["solver"]
                row[f"{key}_peak_mb"] = cell["peak_rss_mb"]
                row[f"{key}_peak_above_baseline_mb"] = cell["peak_above_baseline_mb"]
                # Memory against the RTS pass's, each above its own process's baseline.
                row[f"{key}_peak_over_rts"] = (cell["peak_above_baseline_mb"]
                                               / max(rts["peak_above_baseline_mb"], 1e-9))
                if "positions" in cell:
                    positions[solver] = cell["positions"]
            if f"{mode}_drake_s" in row:
                row[f"{mode}_drake_over_banded_ip"] = (row[f"{mode}_drake_s"]
                                                        / row[f"{mode}_banded_ip_s"])
                row[f"{mode}_max_position_difference_rad"] = float(np.max(np.abs(
                    positions["drake"] - positions["banded_ip"])))
        rows.append(row)
        print(f"  offline N={n:>7}: RTS {row['rts_s']:8.3f} s "
              f"{row['rts_peak_above_baseline_mb']:7.0f}"
              " MB | " + " | ".join(
                  f"{mode} {solver} {row[f'{mode}_{solver}_s']:8.3f} s "
                  f"({row[f'{mode}_{solver}_over_rts']:5.1f}× RTS, "
                  f"{row[f'{mode}_{solver}_peak_above_baseline_mb']:.0f} MB)"
                  for mode in ("state", "trajectory") for solver in ("drake", "banded_ip")
                  if f"{mode}_{solver}_s" in row), file=sys.stderr, flush=True)
    return rows


# -- the online step per tick ---------------------------------------------------------------


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


def _online_rows(lags, ticks, repeat) -> dict:
    from telesmooth.safety.limiter import limiter_params, limiter_rest_state, limiter_step
    from telesmooth.smoothing.fixed_lag import FixedLagSmoother
    from telesmooth.smoothing.reduced_q import OnlineCks

    rows = []
    z = synthetic_operator(ticks, NUM_JOINTS, seed=1)
    model = JerkModel.make(DEFAULT_DT_S, DEFAULT_SIGMA, DEFAULT_R, num_joints=NUM_JOINTS)
    ruckig_s, ruckig_result = _best_time(lambda: _ruckig_stream_step(z, ticks), repeat)
    ruckig_us = 1e6 * ruckig_s / ticks if ruckig_result is not None else None
    for lag in lags:
        row = {"lag": lag, "num_joints": NUM_JOINTS, "ticks": ticks}
        for method in ("superstate", "recursion"):
            smoother = FixedLagSmoother(model, lag=lag, method=method)

            def stream(smoother=smoother):
                state = smoother.initial_state(z[0])
                for k in range(ticks):
                    state = smoother.step(state, z[k])
                return state

            seconds, _ = _best_time(stream, repeat)
            row[f"{method}_us_per_tick"] = 1e6 * seconds / ticks
        online = OnlineCks(model, max_acceleration=MAX_ACCELERATION, max_jerk=MAX_JERK, lag=lag)

        def online_stream(online=online):
            state = online.initial_state(z[0])
            for k in range(ticks):
                state = online.step(state, z[k])[0]
            return state

        seconds, _ = _best_time(online_stream, repeat)
        row["online_cks_us_per_tick"] = 1e6 * seconds / ticks

        limits = limiter_params(dt_s=DEFAULT_DT_S, max_acceleration=MAX_ACCELERATION,
                                max_jerk=MAX_JERK, num_joints=NUM_JOINTS)

        def hard_stream(online=online, limits=limits):
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

        def limiter_alone(limits=limits, estimates=estimates):
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
    return {"rows": rows}


def bench_online(lags, ticks, repeat):
    measured = in_fresh_process(_online_rows, tuple(lags), ticks, repeat)
    rows = measured["rows"]
    for row in rows:
        row["peak_rss_mb"] = measured["peak_rss_mb"]      # the one process of all the rows
        print(f"  online L={row['lag']:>3}: superstate {row['superstate_us_per_tick']:8.1f} "
              f"µs/tick | recursion {row['recursion_us_per_tick']:8.1f} µs/tick | Online-CKS "
              f"{row['online_cks_us_per_tick']:8.1f} µs/tick | limiter "
              f"{row['limiter_us_per_tick']:8.1f} µs/tick | online-hard "
              f"{row['online_hard_us_per_tick']:8.1f} µs/tick | Ruckig "
              f"{row.get('ruckig_us_per_tick', float('nan')):8.1f} µs/tick",
              file=sys.stderr, flush=True)
    return rows


# -- simulation: the chain, its stages, the bare plant --------------------------------------


class CallbackTimers:
    """CPU time spent inside the Python callbacks of every LeafSystem built while active.

    While the context is entered, every ``Declare…Event`` and ``Declare…OutputPort`` of
    ``pydrake.systems.framework.LeafSystem`` wraps the callback it is given in a timer keyed
    by the declaring system's class name; leaving the context restores the methods (the
    timers stay in the systems built meanwhile). Time is exclusive: a callback that makes
    Drake evaluate another system's Python output does not count that output's time (a
    stack of running timers). ``time.process_time`` (CPU time of this process), so another
    process on the machine does not inflate it; each call costs ~1 µs of overhead.

    Attributes:
        seconds: class name → CPU seconds inside its callbacks.
        calls: class name → number of callback calls.
    """

    _CALLBACK_ARGUMENTS = {
        "DeclarePeriodicDiscreteUpdateEvent": ("update", 2),
        "DeclarePeriodicUnrestrictedUpdateEvent": ("update", 2),
        "DeclarePeriodicPublishEvent": ("publish", 2),
        "DeclareInitializationDiscreteUpdateEvent": ("update", 0),
        "DeclareInitializationUnrestrictedUpdateEvent": ("update", 0),
        "DeclareInitializationPublishEvent": ("publish", 0),
        "DeclareForcedDiscreteUpdateEvent": ("update", 0),
        "DeclareForcedUnrestrictedUpdateEvent": ("update", 0),
        "DeclareForcedPublishEvent": ("publish", 0),
        "DeclarePerStepDiscreteUpdateEvent": ("update", 0),
        "DeclarePerStepUnrestrictedUpdateEvent": ("update", 0),
        "DeclarePerStepPublishEvent": ("publish", 0),
        "DeclareVectorOutputPort": ("calc", 2),
        "DeclareAbstractOutputPort": ("calc", 2),
    }

    def __init__(self):
        self.seconds = defaultdict(float)
        self.calls = defaultdict(int)
        self._running = []     # CPU time of the nested callbacks of each running callback
        self._originals = {}

    def _timed(self, owner: str, callback):
        seconds, calls, running = self.seconds, self.calls, self._running
        clock = time.process_time

        def timed(*args, **kwargs):
            start = clock()
            running.append(0.0)
            try:
                return callback(*args, **kwargs)
            finally:
                elapsed = clock() - start
                nested = running.pop()
                seconds[owner] += elapsed - nested
                calls[owner] += 1
                if running:
                    running[-1] += elapsed
        return timed

    def __enter__(self):
        from pydrake.systems.framework import LeafSystem

        for name, (keyword, position) in self._CALLBACK_ARGUMENTS.items():
            original = getattr(LeafSystem, name)
            self._originals[name] = original

            def declare(system, *args, _original=original, _keyword=keyword,
                        _position=position, **kwargs):
                owner = type(system).__name__
                args = list(args)
                if _keyword in kwargs and callable(kwargs[_keyword]):
                    kwargs[_keyword] = self._timed(owner, kwargs[_keyword])
                elif len(args) > _position and callable(args[_position]):
                    args[_position] = self._timed(owner, args[_position])
                return _original(system, *args, **kwargs)

            setattr(LeafSystem, name, declare)
        return self

    def __exit__(self, *exc):
        from pydrake.systems.framework import LeafSystem

        for name, original in self._originals.items():
            setattr(LeafSystem, name, original)
        self._originals.clear()
        return False


def _load_chain_scenario(name: str, chain: str = "deployed"):
    import dataclasses

    from telesmooth.diagrams.scenario import LoadScenario

    return dataclasses.replace(LoadScenario(scenario_name=name), chain=chain)


def _chain_cell(name: str, duration_s: float | None, chain: str = "deployed") -> dict:
    """``simulate`` of the scenario through ``chain``: real-time factors of the run (wall and
    this process's CPU over the simulator's advance alone, the window the bare plant's rows
    measure) and of the whole call (build, run and reading the logs back)."""
    from telesmooth.diagrams.simulation import simulate

    scenario = _load_chain_scenario(name, chain)
    call_wall, call_cpu = time.perf_counter(), time.process_time()
    record = simulate(scenario, duration_s=duration_s)
    call_wall, call_cpu = time.perf_counter() - call_wall, time.process_time() - call_cpu
    return {"scenario": name, "chain": scenario.chain,
            "time_step_s": scenario.onboard.time_step_s, "arm": scenario.arm,
            **chain_speed(record.duration_s, record.wall_time_s, record.cpu_time_s,
                          call_wall, call_cpu)}


def over_bare_plant(chain: dict, bare: dict) -> dict:
    """A chain row's real-time factors over the bare plant's (same arm, same plant step,
    measured in the same run): chain / bare, from the wall and from the CPU time. The ratio
    is what the chain's Python stages and events cost on top of the plant, and carries from
    one machine to another where the absolute factors do not."""
    return {"over_bare_plant_wall": chain["real_time_factor"] / bare["real_time_factor"],
            "over_bare_plant_cpu": (chain["real_time_factor_cpu"]
                                    / bare["real_time_factor_cpu"])}


def chain_speed(simulated_s: float, wall_s: float, cpu_s: float, call_wall_s: float,
                call_cpu_s: float) -> dict:
    """The figures of one chain row: the run's real-time factors (simulated / wall and / CPU
    time of the simulator's advance) and the whole ``simulate`` call's (build + run + logs)."""
    return {**_run_speed(simulated_s, wall_s, cpu_s), "call_wall_s": call_wall_s,
            "call_cpu_s": call_cpu_s, "call_real_time_factor": simulated_s / call_wall_s}


def _run_speed(simulated_s: float, wall_s: float, cpu_s: float) -> dict:
    """A run's real-time factors over one window: simulated / wall and simulated / CPU time."""
    return {"simulated_s": simulated_s, "wall_s": wall_s, "cpu_s": cpu_s,
            "real_time_factor": simulated_s / wall_s, "real_time_factor_cpu": simulated_s / cpu_s}


def _chain_shares_cell(name: str, duration_s: float | None, chain: str = "deployed") -> dict:
    """The chain run again with a timer around every Python callback: CPU time per stage."""
    from telesmooth.diagrams.simulation import run_duration_s
    from telesmooth.diagrams.teleoperation import MakeTeleoperationDiagram
    from telesmooth.systems.flexible_arm import MakeSimulator

    scenario = _load_chain_scenario(name, chain)
    with CallbackTimers() as timers:
        handles = MakeTeleoperationDiagram(scenario)
    duration = run_duration_s(scenario, handles.ground.recording, duration_s)
    simulator = MakeSimulator(handles.diagram, scenario.onboard)
    simulator.Initialize()
    timers.seconds.clear()
    timers.calls.clear()
    cpu = time.process_time()
    simulator.AdvanceTo(duration + 1e-9)
    cpu = time.process_time() - cpu
    python = dict(sorted(timers.seconds.items(), key=lambda item: -item[1]))
    return {"scenario": name, "simulated_s": duration, "cpu_s": cpu,
            "python_s": python, "calls": dict(timers.calls),
            "drake_s": cpu - sum(python.values())}


def _bare_plant_cell(arm: str, time_step_s: float, duration_s: float) -> dict:
    """The flexible arm's plant alone, every motor following 0.2 sin(π t) rad (a C++ source)
    with its PD servo: the floor of any simulation of the chain at this plant step."""
    from pydrake.multibody.plant import AddMultibodyPlant, MultibodyPlantConfig
    from pydrake.systems.framework import DiagramBuilder
    from pydrake.systems.primitives import Multiplexer, Sine

    from telesmooth.arms.drake_models import add_arm
    from telesmooth.systems.flexible_arm import FlexibleArmConfig, MakeSimulator

    config = FlexibleArmConfig(arm=arm, time_step_s=time_step_s)
    description = config.arm_description
    n = description.num_joints
    builder = DiagramBuilder()
    plant, _ = AddMultibodyPlant(MultibodyPlantConfig(
        time_step=time_step_s,
        discrete_contact_approximation=config.discrete_contact_approximation,
        use_sampled_output_ports=False), builder)
    instance = add_arm(plant, description, flexible=True)
    plant.mutable_gravity_field().set_gravity_vector(np.array(config.gravity_m_per_s2))
    plant.Finalize()
    set_point = builder.AddSystem(Sine(0.2 * np.ones(n), np.full(n, math.pi), np.zeros(n),
                                       is_time_based=True))
    state = builder.AddSystem(Multiplexer([n, n]))
    builder.Connect(set_point.get_output_port(0), state.get_input_port(0))
    builder.Connect(set_point.get_output_port(1), state.get_input_port(1))
    builder.Connect(state.get_output_port(), plant.get_desired_state_input_port(instance))
    simulator = MakeSimulator(builder.Build(), config)
    simulator.Initialize()
    wall, cpu = time.perf_counter(), time.process_time()
    simulator.AdvanceTo(duration_s)
    wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
    return {"arm": arm, "time_step_s": time_step_s, **_run_speed(duration_s, wall, cpu)}


def bench_simulation(duration_s: float | None, bare_duration_s: float = 20.0):
    """The chain of each scenario (real-time factors and stage shares) beside the bare plant."""
    bare = []
    for arm in ("air_bearing_arm", "space_arm"):
        for step in BARE_PLANT_STEPS_S:
            row = in_fresh_process(_bare_plant_cell, arm, step, bare_duration_s)
            bare.append(row)
            print(f"  bare plant {arm}, {_step_text(step)}: ×{row['real_time_factor']:.1f} "
                  f"real time (×{row['real_time_factor_cpu']:.1f} CPU)", file=sys.stderr,
                  flush=True)
    chains = []
    for name in CHAIN_SCENARIOS:
        for chain in CHAINS_TIMED:
            row = in_fresh_process(_chain_cell, name, duration_s, chain)
            shares = in_fresh_process(_chain_shares_cell, name, duration_s, chain)
            add_bare_plant_ratios(row, bare)
            row["stage_cpu_s"] = shares["python_s"]
            row["stage_calls"] = shares["calls"]
            row["drake_cpu_s"] = shares["drake_s"]
            row["instrumented_cpu_s"] = shares["cpu_s"]
            row["stage_share"] = {stage: seconds / shares["cpu_s"]
                                  for stage, seconds in shares["python_s"].items()}
            row["stage_share"]["Drake (plant, integrator, events, loggers)"] = (
                shares["drake_s"] / shares["cpu_s"])
            chains.append(row)
            print(f"  simulate {name}, {chain} chain: {row['simulated_s']:.1f} s in "
                  f"{row['wall_s']:.2f} s (×{row['real_time_factor']:.1f} real time, "
                  f"×{row['real_time_factor_cpu']:.1f} CPU; "
                  f"{_ratio_text(row.get('over_bare_plant_wall'))} of the bare plant's wall "
                  f"factor, {_ratio_text(row.get('over_bare_plant_cpu'))} of its CPU factor; "
                  f"the whole call with build and logs {row['call_wall_s']:.2f} s, "
                  f"×{row['call_real_time_factor']:.1f}; {row['peak_rss_mb']:.0f} MB)",
                  file=sys.stderr, flush=True)
    return {"bare_plant": bare, "chain": chains}


def add_bare_plant_ratios(row: dict, bare: list[dict]) -> None:
    """Adds to a chain row its ratios over the bare plant of its arm: at its own plant step
    (``over_bare_plant_wall``/``_cpu``, :func:`over_bare_plant`) and, CPU, at each step
    measured (``over_bare_plant_<step>``)."""
    for reference in bare:
        if reference["arm"] != row["arm"]:
            continue
        key = f"over_bare_plant_{_step_key(reference['time_step_s'])}"
        row[key] = row["real_time_factor_cpu"] / reference["real_time_factor_cpu"]
        if reference["time_step_s"] == row["time_step_s"]:
            row.update(over_bare_plant(row, reference))


def _ratio_text(ratio) -> str:
    return "–" if ratio is None else f"{ratio:.3g}"


def _step_key(step: float) -> str:
    return "continuous" if step == 0.0 else f"{1e3 * step:g}ms"


def _step_text(step: float) -> str:
    return "continuous (default)" if step == 0.0 else f"{1e3 * step:g} ms step"


# -- the experiment: time per task and the whole grid ---------------------------------------


def _experiment_scenario(shape: str, demo: int, time_step_s: float | None):
    """The experiment's scenario of one demonstration (``studies.experiment``'s
    ``experiment_scenario``) with the plant step given (None: the default plant)."""
    import dataclasses
    import zlib

    from telesmooth.diagrams.scenario import LoadScenario
    from telesmooth.studies.experiment import ExperimentConfig

    base = LoadScenario(scenario_name="Defaults")
    seed = zlib.crc32(f"{shape}/{demo}".encode()) & 0x7FFFFFFF
    onboard = dataclasses.replace(base.onboard, tracker=dataclasses.replace(
        base.onboard.tracker, seed=seed))
    if time_step_s is not None:
        onboard = dataclasses.replace(onboard, time_step_s=time_step_s)
    return dataclasses.replace(
        base, haptic=dataclasses.replace(base.haptic, source="lasa", lasa_shape=shape,
                                         lasa_demo=demo),
        onboard=onboard, settle_s=ExperimentConfig().settle_s)


def _experiment_cell(shape: str, demo: int, time_step_s: float | None) -> dict:
    """Every method on one demonstration, as the experiment runs a demonstration's tasks
    (``run_task_group``): the IK pass and the setup once, a plant run shared by the methods
    that send the same packets."""
    from telesmooth.diagrams.scenario import make_haptic_recording
    from telesmooth.smoothing.methods import METHODS
    from telesmooth.studies.comparison import (
        operator_samples,
        prepare_comparison,
        run_method,
    )

    scenario = _experiment_scenario(shape, demo, time_step_s)
    recording = make_haptic_recording(scenario)
    started = time.process_time()
    samples = operator_samples(scenario)
    ik_cpu_s = time.process_time() - started
    methods = {}
    setup = prepare_comparison(scenario, samples)
    playbacks = {}
    for method in METHODS:
        wall, cpu = time.perf_counter(), time.process_time()
        run = run_method(setup, method, playbacks=playbacks)
        methods[method] = {"cpu_s": time.process_time() - cpu,
                           "wall_s": time.perf_counter() - wall,
                           "smooth_s": run.timings_s["smooth"],
                           "simulate_s": run.timings_s["simulate"],
                           "playback_reused": run.playback_reused,
                           "e_mean_m": run.metrics["response_error_m"]["mean"]}
    return {"shape": shape, "demo": demo, "time_step_s": time_step_s,
            "recording_s": float(recording.t_s[-1] - recording.t_s[0]),
            "simulated_s": setup.duration_s, "operator_samples_cpu_s": ik_cpu_s,
            "methods": methods}


def _experiment_c8_cell(shape: str) -> dict:
    """One C8 task (core only: Online-CKS over the shape's 7 demonstrations, twice)."""
    from telesmooth.diagrams.scenario import LoadScenario
    from telesmooth.studies.experiment import ExperimentConfig, ExperimentTask, run_task

    base = LoadScenario(scenario_name="Defaults")
    cpu = time.process_time()
    run_task(ExperimentTask(index=0, kind="c8", shape=shape, demo=-1, method="online-cks",
                            label="online-cks C8", study="c8"), base, ExperimentConfig())
    return {"shape": shape, "cpu_s": time.process_time() - cpu}


def _recording_lengths() -> dict:
    """Recording length of every LASA demonstration as the experiment maps it, s."""
    from telesmooth.datasets.lasa import LASA_DEMOS_PER_SHAPE, LASA_SHAPES
    from telesmooth.diagrams.scenario import make_haptic_recording

    lengths = {}
    for shape in LASA_SHAPES:
        for demo in range(LASA_DEMOS_PER_SHAPE):
            recording = make_haptic_recording(_experiment_scenario(shape, demo, None))
            lengths[f"{shape}/{demo}"] = float(recording.t_s[-1] - recording.t_s[0])
    return {"lengths": lengths}


def extrapolate_experiment(sample: list[dict], c8_cpu_s: dict, lengths: dict,
                           workers: int = 2) -> dict:
    """The whole grid's time from the sample, in CPU seconds and on ``workers`` cores.

    Model (stated, not fitted beyond it): a task's CPU time is proportional to the seconds
    it simulates, at each method's own rate measured on the sample (CPU seconds per
    simulated second, pooled over the sample's demonstrations; a method that reused another's
    plant run on the sample counts as cheap as it was there); a demonstration simulates its
    recording plus the same offset as the sample's (settling, the fixed-lag delay, the ramp);
    the IK pass runs once per demonstration (its tasks run together); C8 tasks scale with
    the shape's recordings. Tasks are spread evenly over the workers (Dask's scheduling
    overhead and idle ends are not counted): wall ≈ CPU / workers.
    """
    from telesmooth.studies.experiment import ExperimentConfig, make_tasks

    config = ExperimentConfig(demos=tuple(range(7)))
    tasks = make_tasks(config)
    offset = float(np.mean([cell["simulated_s"] - cell["recording_s"] for cell in sample]))
    methods = sample[0]["methods"].keys()
    rate = {m: sum(cell["methods"][m]["cpu_s"] for cell in sample)
            / sum(cell["simulated_s"] for cell in sample) for m in methods}
    ik_rate = (sum(cell["operator_samples_cpu_s"] for cell in sample)
               / sum(cell["recording_s"] for cell in sample))
    c8_rate = float(np.mean([seconds / sum(lengths[f"{shape}/{d}"] for d in range(7))
                             for shape, seconds in c8_cpu_s.items()]))
    total = 0.0
    by_kind = defaultdict(float)
    demos_seen = set()
    for task in tasks:
        if task.kind == "c8":
            seconds = c8_rate * sum(lengths[f"{task.shape}/{d}"] for d in range(7))
        else:
            simulated = lengths[f"{task.shape}/{task.demo}"] + offset
            seconds = rate[task.method] * simulated
            demos_seen.add((task.shape, task.demo))
        by_kind[task.study if task.kind == "run" else "c8"] += seconds
        total += seconds
    ik = ik_rate * sum(lengths[f"{s}/{d}"] for s, d in demos_seen)
    total += ik
    return {"num_tasks": len(tasks), "cpu_s": total, "workers": workers,
            "wall_s": total / workers, "cpu_s_by_study": dict(by_kind), "ik_cpu_s": ik,
            "cpu_s_per_simulated_s": rate, "simulated_offset_s": offset}


def bench_experiment(shapes, *, workers: int = 2) -> dict:
    """Per-task times on the sample with the default plant (the experiment's) and a 5 ms
    step, and the grid extrapolated from each."""
    lengths = in_fresh_process(_recording_lengths)["lengths"]
    c8 = {shape: in_fresh_process(_experiment_c8_cell, shape)["cpu_s"] for shape in shapes[:1]}
    report = {"sample": list(shapes), "c8_cpu_s": c8, "plants": {}}
    for label, step in (("default plant", None),
                        ("5 ms step", 0.005)):
        sample = [in_fresh_process(_experiment_cell, shape, 0, step) for shape in shapes]
        grid = extrapolate_experiment(sample, c8, lengths, workers)
        report["plants"][label] = {"sample": sample, "grid": grid}
        per_task = np.mean([m["cpu_s"] for cell in sample for m in cell["methods"].values()])
        print(f"  experiment, {label}: {per_task:.2f} CPU s per task on the sample; "
              f"{grid['num_tasks']} tasks ≈ {grid['cpu_s'] / 60:.0f} CPU min, "
              f"≈ {grid['wall_s'] / 60:.0f} min on {workers} cores", file=sys.stderr,
              flush=True)
    return report


# -- the table ------------------------------------------------------------------------------


def _table(offline, online, simulation=None, experiment=None) -> str:
    lines = ["Offline-CKS, 6 joints (wall time incl. build; best of repeats); drake = "
             "MathematicalProgram + Clarabel, banded-ip = the banded interior point. Memory: "
             "peak RSS of the row's own process above its baseline (imports and input data), "
             "MB", "",
             "| N | RTS pass [s] | RTS [MB] | mode | drake [s] | drake / RTS | drake [MB] | "
             "banded-ip [s] | banded-ip / RTS | banded-ip [MB] | banded-ip / RTS memory | "
             "drake / banded-ip | banded-ip [µs/sample] | max |Δq| [rad] |",
             "|---:|---:|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    if not offline:         # --online-only
        lines = []

    def cell(row, key, fmt):
        return fmt.format(row[key]) if key in row else "–"

    for r in offline:
        for mode in ("state", "trajectory"):
            lines.append(
                f"| {r['num_samples']} | {r['rts_s']:.4f} | "
                f"{cell(r, 'rts_peak_above_baseline_mb', '{:.0f}')} | {mode} | "
                f"{cell(r, f'{mode}_drake_s', '{:.3f}')} | "
                f"{cell(r, f'{mode}_drake_over_rts', '{:.1f}')} | "
                f"{cell(r, f'{mode}_drake_peak_above_baseline_mb', '{:.0f}')} | "
                f"{cell(r, f'{mode}_banded_ip_s', '{:.3f}')} | "
                f"{cell(r, f'{mode}_banded_ip_over_rts', '{:.1f}')} | "
                f"{cell(r, f'{mode}_banded_ip_peak_above_baseline_mb', '{:.0f}')} | "
                f"{cell(r, f'{mode}_banded_ip_peak_over_rts', '{:.2f}')} | "
                f"{cell(r, f'{mode}_drake_over_banded_ip', '{:.1f}')} | "
                f"{cell(r, f'{mode}_banded_ip_us_per_sample', '{:.1f}')} | "
                f"{cell(r, f'{mode}_max_position_difference_rad', '{:.1e}')} |")
    lines += [""] if offline else []
    lines += ["Online step per 4 Hz tick, 6 joints", "",
              "| L | superstate [µs/tick] | recursion [µs/tick] | superstate / recursion | "
              "Online-CKS [µs/tick] | limiter alone [µs/tick] | "
              "online-hard (Online-CKS + limiter) [µs/tick] | "
              "Ruckig update [µs/tick] | Online-CKS / Ruckig | online-hard / Ruckig | "
              "peak [MB] |",
              "|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for r in online:
        lines.append(f"| {r['lag']} | {r['superstate_us_per_tick']:.1f} | "
                     f"{r['recursion_us_per_tick']:.1f} | {r['superstate_over_recursion']:.2f} | "
                     f"{r['online_cks_us_per_tick']:.1f} | {r['limiter_us_per_tick']:.1f} | "
                     f"{r['online_hard_us_per_tick']:.1f} | "
                     f"{cell(r, 'ruckig_us_per_tick', '{:.1f}')} | "
                     f"{cell(r, 'online_cks_over_ruckig', '{:.1f}')} | "
                     f"{cell(r, 'online_hard_over_ruckig', '{:.1f}')} | "
                     f"{cell(r, 'peak_rss_mb', '{:.0f}')} |")
    if simulation:
        lines += ["", "Simulation speed: real-time factor = simulated / wall time (and / CPU "
                  "time of the row's process) of the simulator's advance; the whole call adds "
                  "the diagram's build and reading the logs back; *chain / bare plant*: the "
                  "chain's real-time factor over the bare plant's of the same arm and plant "
                  "step in this run (from the wall and from the CPU time: the ratio carries "
                  "from machine to machine, the factors do not); peak RSS of the row's process",
                  "", "| what | chain | plant | simulated [s] | wall [s] | ×real time | "
                  "×real time (CPU) | chain / bare plant | chain / bare plant (CPU) | "
                  "whole call [s] | ×real time (whole call) | peak [MB] |",
                  "|---|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
        for r in simulation["bare_plant"]:
            lines.append(f"| bare plant, {r['arm']} | – | {_step_text(r['time_step_s'])} | "
                         f"{r['simulated_s']:.1f} | {r['wall_s']:.2f} | "
                         f"{r['real_time_factor']:.1f} | {r['real_time_factor_cpu']:.1f} | – | – "
                         f"| – | – | {r['peak_rss_mb']:.0f} |")
        for r in simulation["chain"]:
            lines.append(f"| `telesmooth simulate`, {r['scenario']} ({r['arm']}) | "
                         f"{r.get('chain', 'deployed')} | "
                         f"{_step_text(r['time_step_s'])} | {r['simulated_s']:.1f} | "
                         f"{r['wall_s']:.2f} | {r['real_time_factor']:.1f} | "
                         f"{r['real_time_factor_cpu']:.1f} | "
                         f"{cell(r, 'over_bare_plant_wall', '{:.3g}')} | "
                         f"{cell(r, 'over_bare_plant_cpu', '{:.3g}')} | "
                         f"{r['call_wall_s']:.2f} | {r['call_real_time_factor']:.1f} | "
                         f"{r['peak_rss_mb']:.0f} |")
        for r in simulation["chain"]:
            lines += ["", f"Stages of the {r['scenario']} chain ({r.get('chain', 'deployed')}): "
                      f"share of the CPU time of an "
                      f"instrumented run ({r['instrumented_cpu_s']:.2f} s for "
                      f"{r['simulated_s']:.1f} s simulated)", "",
                      "| stage | CPU [s] | share | calls |", "|---|---:|---:|---:|"]
            for stage, share in r["stage_share"].items():
                seconds = r["stage_cpu_s"].get(stage, r["drake_cpu_s"])
                lines.append(f"| {stage} | {seconds:.3f} | {100 * share:.1f} % | "
                             f"{r['stage_calls'].get(stage, '–')} |")
    if experiment:
        lines += ["", f"Experiment: CPU time per task on {', '.join(experiment['sample'])} "
                  "(demonstration 0; every method), and the whole grid extrapolated "
                  "(`--demos all`: main table, sensitivity study, C8)", "",
                  "| plant | CPU per task [s] | CPU per simulated s | tasks | grid CPU [min] | "
                  "grid on 2 cores [min] |", "|---|---:|---:|---:|---:|---:|"]
        for label, plant in experiment["plants"].items():
            sample, grid = plant["sample"], plant["grid"]
            per_task = np.mean([m["cpu_s"] for c in sample for m in c["methods"].values()])
            rate = (sum(m["cpu_s"] for c in sample for m in c["methods"].values())
                    / sum(c["simulated_s"] * len(c["methods"]) for c in sample))
            lines.append(f"| {label} | {per_task:.2f} | {rate:.3f} | {grid['num_tasks']} | "
                         f"{grid['cpu_s'] / 60:.1f} | {grid['wall_s'] / 60:.1f} |")
    return "\n".join(lines) + "\n"


def build_parser() -> argparse.ArgumentParser:
    """The options of ``telesmooth bench``."""
    parser = argparse.ArgumentParser(prog="telesmooth bench",
                                     description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("out/bench"),
                        help="report folder (default out/bench)")
    parser.add_argument("--max-n", type=int, default=100_000,
                        help="largest N of the Offline-CKS rows (10² … 10⁶; default 10⁵)")
    parser.add_argument("--repeat", type=int, default=3,
                        help="timed repetitions of each row; the best is kept (default 3)")
    parser.add_argument("--ticks", type=int, default=2000,
                        help="online steps timed per row of the online smoothers (default 2000)")
    parser.add_argument("--max-drake-n", type=int, default=10_000,
                        help="largest N solved with the Drake MathematicalProgram too")
    parser.add_argument("--sim-duration", type=_number, default=None,
                        help="simulated seconds of each chain (default: the scenario's own "
                             "run, 33.5 s on Defaults; 0 = skip the simulation rows)")
    parser.add_argument("--bare-plant-duration", type=_number, default=20.0,
                        help="simulated seconds of each bare-plant row (default 20)")
    parser.add_argument("--online-only", action="store_true",
                        help="only the online step per tick (Online-CKS, limiter, online-hard, "
                             "Ruckig at L = 3 and 75): no offline, simulation or experiment "
                             "rows")
    parser.add_argument("--experiment-shapes", default=",".join(EXPERIMENT_SAMPLE),
                        help="LASA shapes (demonstration 0) of the experiment's sample "
                             f"(default {','.join(EXPERIMENT_SAMPLE)}; 'none' = skip; skipped "
                             "with --sim-duration 0 too)")
    return parser


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    for option, value in (("--max-n", args.max_n), ("--repeat", args.repeat),
                          ("--ticks", args.ticks), ("--max-drake-n", args.max_drake_n)):
        if value < 1:
            raise ValueError(f"{option} = {value} must be >= 1")
    for option, value in (("--sim-duration", args.sim_duration),
                          ("--bare-plant-duration", args.bare_plant_duration)):
        if value is not None and not (math.isfinite(value) and 0 <= value <= MAX_SIM_DURATION_S):
            raise ValueError(f"{option} = {value!r} must be within 0 and "
                             f"{MAX_SIM_DURATION_S:g} s")
    with Outputs() as outputs:
        staged = outputs.folder("--out", args.out)
        table = _run(args, staged)
    print(table)
    print(f"wrote {args.out / 'bench_core.json'}", file=sys.stderr)
    return 0


MAX_SIM_DURATION_S = 3600.0
"""Longest --sim-duration or --bare-plant-duration, simulated s."""


def _number(text: str) -> float:
    from telesmooth.user_input import parse_plain_number

    try:
        return parse_plain_number(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text[:60]!r} is not a number") from None


def _run(args, out: Path) -> str:
    sizes = [n for n in (100, 1_000, 10_000, 100_000, 1_000_000) if n <= args.max_n]
    print("telesmooth core benchmark (one process per row)", file=sys.stderr)
    offline = [] if args.online_only else bench_offline(sizes, args.repeat, args.max_drake_n)
    online = bench_online((3, 75), args.ticks, args.repeat)
    simulation = None
    if not args.online_only and (args.sim_duration is None or args.sim_duration > 0):
        simulation = bench_simulation(args.sim_duration, args.bare_plant_duration)
    experiment = None
    shapes = [s for s in args.experiment_shapes.split(",") if s and s != "none"]
    if shapes and simulation is not None:
        experiment = bench_experiment(shapes)
    report = {"machine": {"python": platform.python_version(), "processor": platform.machine(),
                          "cpus": os.cpu_count(),
                          "load_average": list(os.getloadavg()) if hasattr(
                              os, "getloadavg") else None},
              "memory_measure": MEMORY_MEASURE,
              "offline_cks": offline, "online_step": online,
              "simulation": simulation or {}, "experiment": experiment or {}}
    write_text(out / "bench_core.json", json.dumps(report, indent=2) + "\n")
    table = _table(offline, online, simulation, experiment)
    write_text(out / "bench_core.md", table)
    return table


if __name__ == "__main__":
    sys.exit(main())
