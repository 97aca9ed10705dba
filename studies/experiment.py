"""The paper's experiment on real human demonstrations, at scale (``telesmooth experiment``).

Grid (every task is one simulation of the whole chain, see
:func:`~telesmooth.studies.comparison.run_method`), for every *cell* (plant drive preset ×
operator speed):

    LASA shape × demonstration × method      (the main table; every method of
                                              :data:`~telesmooth.smoothing.methods.METHODS`)
    LASA shape × demonstration × Online-CKS with σ carried over (study ``carried``: each
                                              demonstration starts from the σ the shape's
                                              earlier ones, in order, ended with)
    sensitivity shapes × Online-CKS variant  (σ_0, σ_min and the reduced-Q step ρ, one at a time)
    sensitivity shapes × KF form × σ_0 factor (studies ``kf_sigma0``, ``kf-predictor_sigma0``)

plus one core-only task per shape for claim C8 (Online-CKS over the shape's demonstrations in
order, each operation starting from the σ the previous one ended with, against each starting
from σ_0). Each cell is summarised and judged on its own
(:func:`telesmooth.studies.claims.summarize_cells`).

Operator speed is a multiple of the demonstrator's own hand speed: the LASA clock is stretched by
the default ``lasa_mapping.time_scale`` (10, the hand's own speed) divided by the speed (speed 2.5
is time_scale 4), whatever time scale the base scenario has. At hand speed the raw commands break
the acceleration limit on a few per cent of the samples only, so the limits hardly bind; faster,
they do.

Every demonstration is mapped into the air-bearing arm's workspace at that speed
(:class:`~telesmooth.datasets.lasa.WorkspaceMapping`: 10:1 in space), run
through the ground station's IK, sampled at 4 Hz, smoothed, and played through the same 4 Hz
uplink and flexible-joint plant. The limits are those of the base scenario (Defaults:
a_max = 0.05 rad/s², j_max = 0.1 rad/s³ on every joint), which the raw operator data violate on
almost every demonstration (the report gives the fraction).

The chain (:attr:`ExperimentConfig.chain`): ``"paper"`` (default) plays every method's
commands as the paper does, the uplink driving the robot directly; ``"deployed"`` plays them
through the onboard receiver and link guard
(:func:`~telesmooth.studies.comparison.prepare_comparison`). It is part of the grid (a folder
holds the records of one chain) and every record says which it ran.

Tasks are independent and deterministic: the same task gives the same figures on any worker, and
:func:`run_experiment` orders the results by task, so the output does not depend on the number
of workers (``tests/test_experiment.py``). The tasks of one demonstration run together
(:func:`run_task_group`): one IK pass, and one plant run for the methods that send the same
packets to the bit (the playback is deterministic, so each record is the one its task gives
alone). Groups run on Dask (``dask.distributed``): a local
cluster of worker processes by default (bound to 127.0.0.1, no dashboard: only the scheduler's
health/metrics HTTP endpoint, on 127.0.0.1), an existing cluster
given its scheduler address, or in this process (``workers=0``).

Each task's record is JSON-ready; :mod:`telesmooth.studies.claims` aggregates the records
and judges the claims, without running anything.
"""

from __future__ import annotations

import dataclasses
import math
import time
import zlib
from collections.abc import Callable, Iterator, Sequence

import numpy as np

from telesmooth.arms.modes import plant_modes
from telesmooth.datasets.lasa import LASA_DEMOS_PER_SHAPE, LASA_SHAPES, WorkspaceMapping
from telesmooth.diagrams.scenario import Scenario
from telesmooth.smoothing.methods import METHOD_ALIASES, METHODS, method_name, smooth_recording
from telesmooth.smoothing.metrics import finite_differences
from telesmooth.smoothing.offline import OFFLINE_SOLVERS, with_rest_history
from telesmooth.smoothing.reduced_q import DEFAULT_SIGMA_MIN_RATIO
from telesmooth.studies.comparison import (
    OperatorSamples,
    method_settings,
    operator_samples,
    prepare_comparison,
    run_method,
    run_summary,
)

__all__ = [
    "CARRIED_LABEL",
    "KF_FORMS",
    "KF_SIGMA_STUDIES",
    "ExperimentConfig",
    "ExperimentTask",
    "carried_sigma0",
    "cell_name",
    "experiment_scenario",
    "make_tasks",
    "run_experiment",
    "run_task",
    "iter_task_group",
    "run_task_group",
    "task_groups",
]

KF_FORMS = ("kf", "kf-predictor")
"""The paper's "KF" comparator read as the a-posteriori filter x̂_{k|k} or its one-step
predictor x̂_{k|k−1}; :attr:`ExperimentConfig.kf_form` declares which one every claim uses."""

@dataclasses.dataclass(frozen=True)
class ExperimentConfig:
    """What the experiment runs.

    Attributes:
        shapes: LASA shapes of the main table.
        demos: Demonstration indices (0–6) of each shape.
        methods: Methods of the main table (``original`` is always added: it is P's reference).
        plant_time_step_s: The flexible-joint plant's step for every run, s; None (default):
            the scenario's plant (continuous, as ``simulate`` and ``compare`` run it), 0: the
            continuous plant. A discrete step is not free: a 5 ms step triples e on Defaults
            (online-cks 0.058 → 0.167 mm, P 13.4 → 4.3 %), and the continuous plant costs
            about as much per run (``make bench``).
        settle_s: Simulated time after the operator's last sample, s (long enough for the
            methods that trail the operator, e.g. Ruckig, to arrive).
        sensitivity_shapes: Shapes (demonstration 0) of the Online-CKS sensitivity study.
        sigma0_factors: σ_0 multipliers of the study (1 = the scenario's σ_0).
        sigma_min_ratios: σ_min / σ_0 values of the study (the default is 2.5e-4).
        rhos: Multiplicative reduced-Q steps ρ of the study (the default is 0.8).
        c8_shapes: Shapes of the C8 study (all seven demonstrations of each, in order).
        kf_sigma0_factors: σ_0 multipliers of the KF's sensitivity study, run with both KF
            forms (:data:`KF_FORMS`) on the sensitivity shapes.
        carried_sigma: Also run Online-CKS on every demonstration of the main table with σ
            carried over from the shape's earlier demonstrations (study ``carried``), as the
            paper keeps σ per operator; the main table's Online-CKS starts from σ_0.
        offline_solver: Solver of the Offline-CKS methods, "drake" (the MathematicalProgram)
            or "banded-ip" (the banded interior point).
        speeds: Operator speeds, multiples of the demonstrator's hand speed (> 0): the
            demonstration's time scale is 10 (the hand's speed) divided by each.
        plants: Drive presets of the plant (:data:`~telesmooth.arms.description.PLANT_PRESETS`;
            the base scenario's other drive fields are kept).
        kf_form: The KF form every claim uses (:data:`KF_FORMS`); the other is reported
            beside it where both ran.
        chain: The chain every method's commands are played through
            (:data:`~telesmooth.diagrams.scenario.CHAINS`): ``"paper"`` (default: the uplink
            drives the robot directly, the paper's set-up) or ``"deployed"`` (through the
            onboard receiver and link guard); the base scenario's own ``chain`` is not read.
    """

    shapes: tuple[str, ...] = LASA_SHAPES
    demos: tuple[int, ...] = (0,)
    methods: tuple[str, ...] = METHODS
    plant_time_step_s: float | None = None
    settle_s: float = 5.0
    sensitivity_shapes: tuple[str, ...] = ("Angle", "CShape", "GShape", "Sshape", "Worm")
    sigma0_factors: tuple[float, ...] = (0.01, 0.1, 10.0, 100.0)
    sigma_min_ratios: tuple[float, ...] = (2.5e-6, 2.5e-2, 0.25)
    rhos: tuple[float, ...] = (0.5, 0.95)
    c8_shapes: tuple[str, ...] = LASA_SHAPES
    kf_sigma0_factors: tuple[float, ...] = (0.01, 0.1, 10.0, 100.0)
    carried_sigma: bool = True
    offline_solver: str = "drake"
    speeds: tuple[float, ...] = (1.0,)
    plants: tuple[str, ...] = ("lab",)
    kf_form: str = "kf"
    chain: str = "paper"

    def __post_init__(self) -> None:
        from telesmooth.arms.description import PLANT_PRESETS
        from telesmooth.diagrams.scenario import CHAINS

        if self.chain not in CHAINS:
            raise ValueError(f"chain = {self.chain!r} must be one of {CHAINS}")

        if not self.speeds or len(set(self.speeds)) != len(self.speeds) or not all(
                isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
                and v > 0 for v in self.speeds):
            raise ValueError(f"speeds = {list(self.speeds)!r} must be distinct positive "
                             "multiples of the demonstrator's speed")
        unknown = [p for p in self.plants if p not in PLANT_PRESETS]
        if unknown or not self.plants or len(set(self.plants)) != len(self.plants):
            raise ValueError(f"plants = {list(self.plants)!r} must be distinct drive presets "
                             f"of {PLANT_PRESETS}")
        if self.kf_form not in KF_FORMS:
            raise ValueError(f"kf_form = {self.kf_form!r} must be one of {KF_FORMS}")
        for field in ("shapes", "sensitivity_shapes", "c8_shapes"):
            unknown = [s for s in getattr(self, field) if s not in LASA_SHAPES]
            if unknown:
                raise ValueError(f"{field}: unknown LASA shape(s) {unknown}; the shapes are "
                                 f"{list(LASA_SHAPES)}")
        bad = [d for d in self.demos if not (isinstance(d, int) and 0 <= d < LASA_DEMOS_PER_SHAPE)]
        if bad or not self.demos:
            raise ValueError(f"demos = {list(self.demos)!r} must be indices 0–"
                             f"{LASA_DEMOS_PER_SHAPE - 1}")
        if self.offline_solver not in OFFLINE_SOLVERS:
            raise ValueError(f"offline_solver = {self.offline_solver!r} must be one of "
                             f"{OFFLINE_SOLVERS}")
        unknown = [m for m in self.methods if not isinstance(m, str)
                   or (m not in METHODS and m not in METHOD_ALIASES)]
        if unknown:
            raise ValueError(f"methods {unknown!r} are not among {METHODS}")
        # The registry's names (an alias such as pass-through is its method, original).
        if any(m in METHOD_ALIASES for m in self.methods):
            object.__setattr__(self, "methods", tuple(method_name(m) for m in self.methods))
        step = self.plant_time_step_s
        if step is not None and not (math.isfinite(step) and step >= 0):
            raise ValueError(f"plant_time_step_s = {step!r} must be None, 0 (continuous) or "
                             "a positive, finite step")
        if not (math.isfinite(self.settle_s) and self.settle_s > 0):
            raise ValueError(f"settle_s = {self.settle_s!r} must be positive and finite")
        for field, lo, hi in (("sigma0_factors", 0, math.inf),
                              ("kf_sigma0_factors", 0, math.inf), ("sigma_min_ratios", 0, 1),
                              ("rhos", 0, 1)):
            for value in getattr(self, field):
                if not (lo < value < hi or (field == "sigma_min_ratios" and value == 1)):
                    raise ValueError(f"{field}: {value!r} must be in ({lo}, {hi})")


@dataclasses.dataclass(frozen=True)
class ExperimentTask:
    """One cell of the grid.

    Attributes:
        index: Position in the grid (results are returned in this order).
        kind: ``"run"`` (one simulation) or ``"c8"`` (core only, one shape's demonstrations).
        shape, demo: The LASA demonstration (``demo`` unused for ``c8``).
        method: A method of :data:`~telesmooth.smoothing.methods.METHODS`.
        label: The run's name in the tables (the method, or e.g. ``online-cks σ0×10``).
        study: ``"main"`` or the sensitivity parameter (``"sigma0"``, ``"sigma_min"``, ``"rho"``).
        value: The parameter's value (NaN for ``main``).
        seed: Seed of the laser tracker's noise (a function of shape and demonstration).
        plant: The plant's drive preset.
        speed: The operator's speed, a multiple of the demonstrator's.
    """

    index: int
    kind: str
    shape: str
    demo: int
    method: str
    label: str
    study: str = "main"
    value: float = math.nan
    seed: int = 0
    plant: str = "lab"
    speed: float = 1.0

    @property
    def key(self) -> str:
        """What the task computes, stable across runs of the same grid (resuming, merging)."""
        return f"{self.plant}|{self.speed!r}|{self.kind}|{self.shape}|{self.demo}|{self.label}"


def cell_name(plant: str, speed: float) -> str:
    """The name of a (plant, speed) cell in summaries and reports, e.g. ``"lab, 2.5×"``."""
    return f"{plant}, {speed:g}×"


def _seed(shape: str, demo: int) -> int:
    return zlib.crc32(f"{shape}/{demo}".encode()) & 0x7FFFFFFF


def experiment_scenario(base: Scenario, config: ExperimentConfig, shape: str, demo: int,
                        seed: int = 0, *, plant: str = "lab", speed: float = 1.0) -> Scenario:
    """The base scenario replaying one LASA demonstration at ``speed`` × the demonstrator's
    hand speed (whatever time scale the base has: the default time scale, 10, is the hand's
    speed), on the ``plant`` drive preset, with the experiment's plant step and chain."""
    mapping = dataclasses.replace(base.haptic.lasa_mapping,
                                  time_scale=WorkspaceMapping().time_scale / speed)
    haptic = dataclasses.replace(base.haptic, source="lasa", lasa_shape=shape, lasa_demo=demo,
                                 lasa_mapping=mapping)
    step = (base.onboard.time_step_s if config.plant_time_step_s is None
            else config.plant_time_step_s)
    onboard = dataclasses.replace(
        base.onboard, time_step_s=step,
        tracker=dataclasses.replace(base.onboard.tracker, seed=seed),
        drive=dataclasses.replace(base.onboard.drive, preset=plant))
    return dataclasses.replace(base, haptic=haptic, onboard=onboard, settle_s=config.settle_s,
                               chain=config.chain)


def make_tasks(config: ExperimentConfig) -> list[ExperimentTask]:
    """The grid, in report order: per cell (plant × speed), the main table, the sensitivity
    study and the C8 study."""
    tasks = []

    def add(**fields):
        tasks.append(ExperimentTask(index=len(tasks), **fields))

    methods = ("original",) + tuple(m for m in config.methods if m != "original")
    studies = ([("sigma0", f) for f in config.sigma0_factors]
               + [("sigma_min", r) for r in config.sigma_min_ratios]
               + [("rho", r) for r in config.rhos])
    for plant in config.plants:
        for speed in config.speeds:
            cell = dict(plant=plant, speed=float(speed))
            for shape in config.shapes:
                for demo in config.demos:
                    for method in methods:
                        add(kind="run", shape=shape, demo=demo, method=method, label=method,
                            seed=_seed(shape, demo), **cell)
                    if config.carried_sigma and "online-cks" in methods:
                        add(kind="run", shape=shape, demo=demo, method="online-cks",
                            label=CARRIED_LABEL, study="carried", seed=_seed(shape, demo),
                            **cell)
            main_cells = {(t.shape, t.demo, t.method) for t in tasks
                          if t.study == "main" and (t.plant, t.speed) == (plant, speed)}
            for shape in config.sensitivity_shapes:
                # The original (P's reference) and Online-CKS with the scenario's settings
                # (the study's default point), unless the main table already has them.
                for method in ("original", "online-cks"):
                    if (shape, 0, method) not in main_cells:
                        add(kind="run", shape=shape, demo=0, method=method, label=method,
                            study="reference", seed=_seed(shape, 0), **cell)
                for study, value in studies:
                    add(kind="run", shape=shape, demo=0, method="online-cks",
                        label=f"online-cks {study}={value:g}", study=study,
                        value=float(value), seed=_seed(shape, 0), **cell)
                for form in KF_FORMS if config.kf_sigma0_factors else ():
                    if (shape, 0, form) not in main_cells:
                        add(kind="run", shape=shape, demo=0, method=form, label=form,
                            study="reference", seed=_seed(shape, 0), **cell)
                    for value in config.kf_sigma0_factors:
                        add(kind="run", shape=shape, demo=0, method=form,
                            label=f"{form} sigma0={value:g}", study=f"{form}_sigma0",
                            value=float(value), seed=_seed(shape, 0), **cell)
            for shape in config.c8_shapes:
                add(kind="c8", shape=shape, demo=-1, method="online-cks",
                    label="online-cks C8", study="c8", seed=0, **cell)
    return tasks


def _settings(setup, task: ExperimentTask, offline_solver: str = "drake"):
    base_method, settings = method_settings(setup.scenario, task.method, offline_solver)
    if task.study in ("main", "reference", "carried"):
        return base_method, settings
    config = settings.reduced_q
    sigma0 = np.asarray(settings.sigma, dtype=float)
    if task.study == "sigma0" or task.study in KF_SIGMA_STUDIES:
        return base_method, dataclasses.replace(settings, sigma=sigma0 * task.value)
    if task.study == "sigma_min":
        # σ_min as a ratio of σ_0 (one value for all joints: the smallest σ_0 sets it).
        return base_method, dataclasses.replace(settings, reduced_q=dataclasses.replace(
            config, sigma_min=float(np.min(sigma0)) * task.value))
    if task.study == "rho":
        return base_method, dataclasses.replace(settings, reduced_q=dataclasses.replace(
            config, step_rule="multiplicative", rho=task.value))
    raise ValueError(f"unknown study {task.study!r}")


CARRIED_LABEL = "online-cks carried"
"""The label of Online-CKS with σ carried over (study ``carried``)."""

KF_SIGMA_STUDIES = tuple(f"{form}_sigma0" for form in KF_FORMS)
"""The KF's σ_0 sensitivity studies, one per form."""

_SAMPLES_CACHE: dict = {}
_CARRIED_CACHE: dict = {}


def _samples(scenario: Scenario) -> OperatorSamples:
    """One IK pass per demonstration and worker process (a run needs only the arrays)."""
    key = repr(scenario)
    if key not in _SAMPLES_CACHE:
        if len(_SAMPLES_CACHE) > 8:
            _SAMPLES_CACHE.clear()
        _SAMPLES_CACHE[key] = operator_samples(scenario)
    return _SAMPLES_CACHE[key]


def carried_sigma0(base: Scenario, config: ExperimentConfig, task: ExperimentTask):
    """The σ Online-CKS starts ``task``'s demonstration with when σ is carried over: the σ
    the shape's previous demonstration ended with, itself started from the σ carried to it,
    from σ_0 at demonstration 0 (None: start from the settings' σ_0). Only the smoother's
    core runs for the earlier demonstrations (kept per worker process)."""
    sigma = None
    for demo in range(task.demo):
        scenario = experiment_scenario(base, config, task.shape, demo, plant=task.plant,
                                       speed=task.speed)
        key = repr(scenario)
        if key not in _CARRIED_CACHE:
            samples = _samples(scenario)
            base_method, settings = method_settings(scenario, "online-cks")
            result = smooth_recording(samples.q, scenario.uplink.period_s, base_method,
                                      settings, joint_names=scenario.arm_description.joint_names,
                                      sigma0=sigma)
            if len(_CARRIED_CACHE) > 64:
                _CARRIED_CACHE.clear()
            _CARRIED_CACHE[key] = result.final_sigma
        sigma = _CARRIED_CACHE[key]
    return sigma


def _c8_record(base: Scenario, config: ExperimentConfig, task: ExperimentTask) -> dict:
    """Online-CKS over the shape's seven demonstrations, σ carried over vs. fresh σ_0."""
    carried = None
    rows = []
    for demo in range(LASA_DEMOS_PER_SHAPE):
        scenario = experiment_scenario(base, config, task.shape, demo, plant=task.plant,
                                       speed=task.speed)
        samples = _samples(scenario)
        base_method, settings = method_settings(scenario, "online-cks")
        period = scenario.uplink.period_s
        names = scenario.arm_description.joint_names
        row = {"demo": demo}
        for mode, sigma0 in (("fresh", None), ("carried", carried)):
            result = smooth_recording(samples.q, period, base_method, settings,
                                      joint_names=names, sigma0=sigma0)
            sent = with_rest_history(result.positions, samples.q_start)
            jerk = np.abs(finite_differences(sent, period, 3)) / np.asarray(
                settings.max_jerk, dtype=float)
            acc = np.abs(finite_differences(sent, period, 2)) / np.asarray(
                settings.max_acceleration, dtype=float)
            sigma = np.vstack([np.broadcast_to(
                np.asarray(sigma0 if sigma0 is not None else settings.sigma, dtype=float),
                (1, len(names))), result.sigma])
            row[mode] = {
                "fd_jerk_max_over_limit": float(jerk.max()),
                "fd_jerk_mean_over_limit": float(jerk.mean()),
                "fd_acc_max_over_limit": float(acc.max()),
                "sigma_start": np.atleast_1d(sigma[0]).tolist(),
                "sigma_end": result.final_sigma.tolist(),
                "sigma_monotone": bool(np.diff(sigma, axis=0).max() <= 0.0),
                "cycles_triggered": int(np.sum(result.details["cycles_triggered"])),
            }
            if mode == "carried":
                carried = result.final_sigma
        rows.append(row)
    return {"demos": rows}


def run_task(task: ExperimentTask, base: Scenario, config: ExperimentConfig) -> dict:
    """Runs one cell; the record is JSON-ready and its figures depend only on the task (not
    the worker, nor the tasks run beside it); ``wall_s`` and ``playback_reused`` say how it
    was computed."""
    return run_task_group([task], base, config)[0]


def _group_key(task: ExperimentTask) -> tuple:
    """Tasks with the same key play the same demonstration in the same scenario."""
    return (task.kind, task.plant, task.speed, task.shape, task.demo, task.seed)


def task_groups(tasks: Sequence[ExperimentTask]) -> list[list[ExperimentTask]]:
    """The tasks grouped by demonstration (plant, speed, shape, demonstration, seed), in the
    order of each group's first task; a C8 task is a group of its own. The tasks of a group
    share one IK pass, one setup and the plant runs of identical packets
    (:func:`run_task_group`)."""
    groups: dict[tuple, list] = {}
    for task in tasks:
        key = (task.index,) if task.kind == "c8" else _group_key(task)
        groups.setdefault(key, []).append(task)
    return list(groups.values())


def run_task_group(tasks: Sequence[ExperimentTask], base: Scenario,
                   config: ExperimentConfig) -> list[dict]:
    """Runs tasks of one demonstration (one group of :func:`task_groups`), returning their
    records in order (:func:`iter_task_group`)."""
    return list(iter_task_group(tasks, base, config))


def iter_task_group(tasks: Sequence[ExperimentTask], base: Scenario,
                    config: ExperimentConfig) -> Iterator[dict]:
    """Runs tasks of one demonstration (one group of :func:`task_groups`), yielding each
    record as soon as its task is done.

    The operator's samples and the comparison setup are computed once, and a method whose
    packets equal an earlier method's to the bit reuses its plant run (``playbacks`` of
    :func:`~telesmooth.studies.comparison.run_method`): every record is the one
    :func:`run_task` gives for its task alone.

    Raises:
        ValueError: If the tasks are not of one demonstration.
    """
    tasks = list(tasks)
    if len(task_groups(tasks)) > 1:
        raise ValueError("run_task_group: the tasks must be of one demonstration "
                         f"({sorted({t.key for t in tasks})[:3]} ...)")
    setup = None
    playbacks: dict = {}
    for task in tasks:
        started = time.perf_counter()
        if task.kind == "run" and setup is None:
            scenario = experiment_scenario(base, config, task.shape, task.demo, task.seed,
                                           plant=task.plant, speed=task.speed)
            setup = prepare_comparison(scenario, _samples(scenario), chain=config.chain)
        yield _task_record(task, base, config, setup, playbacks, started)


def _task_record(task: ExperimentTask, base: Scenario, config: ExperimentConfig, setup,
                 playbacks: dict, started: float) -> dict:
    record = {"index": task.index, "key": task.key, "kind": task.kind, "shape": task.shape,
              "demo": task.demo, "method": task.method, "label": task.label,
              "study": task.study, "value": None if math.isnan(task.value) else task.value,
              "seed": task.seed, "plant": task.plant, "speed": task.speed,
              "chain": config.chain}
    if task.kind == "c8":
        record["c8"] = _c8_record(base, config, task)
    else:
        scenario = setup.scenario
        base_method, settings = _settings(setup, task, config.offline_solver)
        carried = carried_sigma0(base, config, task) if task.study == "carried" else None
        try:
            run = run_method(setup, task.method, settings=settings, base_method=base_method,
                             label=task.label, playbacks=playbacks, sigma0=carried)
        except (RuntimeError, ValueError, ArithmeticError) as error:
            # A method that fails on one demonstration is a finding, reported with the
            # others; it does not end the grid.
            record["error"] = f"{type(error).__name__}: {str(error)[:400]}"
            record["wall_s"] = time.perf_counter() - started
            return record
        record["metrics"] = {**run_summary(run.metrics),
                             "num_samples": int(setup.q_original.shape[0])}
        if task.method == "original":
            # The plant this demonstration ran on: its modes about the start pose.
            record["plant_modes"] = plant_modes(scenario.onboard.arm_description,
                                                setup.q_start).as_dict(3)
        record["simulated_s"] = setup.duration_s
        record["playback_reused"] = run.playback_reused
        check = run.self_contact
        record["contact_geometry"] = not (check is not None and check.certified)
        # The certified clearance, m; None when the run kept its geometry (or no pair can touch).
        record["self_clearance_m"] = (check.min_clearance_m if not record["contact_geometry"]
                                      and math.isfinite(check.min_clearance_m) else None)
        if task.method == "online-cks":
            # Where this run sits on each axis of the sensitivity study.
            sigma0 = np.asarray(settings.sigma, dtype=float)
            default_sigma0 = np.asarray(method_settings(setup.scenario, "online-cks")[1].sigma,
                                        dtype=float)
            reduced_q = settings.reduced_q
            sigma_min = (DEFAULT_SIGMA_MIN_RATIO * float(np.min(sigma0))
                         if reduced_q.sigma_min is None else reduced_q.sigma_min)
            record["online_cks"] = {
                "sigma0": float(np.max(sigma0 / default_sigma0)),
                "sigma_min": sigma_min / float(np.min(sigma0)),
                "rho": reduced_q.rho if reduced_q.step_rule == "multiplicative" else None,
                **{f"sigma_{key}": value
                   for key, value in run.metrics.get("sigma", {}).items()}}
    record["wall_s"] = time.perf_counter() - started
    return record


# --- running on Dask --------------------------------------------------------------------------


def _progress_line(done: int, total: int, started: float, record: dict) -> str:
    elapsed = time.perf_counter() - started
    eta = elapsed / done * (total - done)
    what = (f"{record['shape']}/{record['demo']} {record['label']}" if record["kind"] == "run"
            else f"{record['shape']} C8")
    what = f"{cell_name(record['plant'], record['speed'])} {what}"
    return f"[{done}/{total}] {what} ({record['wall_s']:.1f} s); elapsed {elapsed:.0f} s, " \
           f"ETA {eta:.0f} s"


def run_experiment(base: Scenario, config: ExperimentConfig, *, workers: int = 2,
                   scheduler: str | None = None,
                   progress: Callable[[str], None] | None = None,
                   tasks: Sequence[ExperimentTask] | None = None,
                   on_record: Callable[[dict], None] | None = None) -> list[dict]:
    """Runs every task and returns the records in task order.

    Args:
        base: The scenario every demonstration is placed in (limits, plant, smoother).
        config: The grid.
        workers: Worker processes of the local Dask cluster; 0 runs in this process.
        scheduler: Address of an existing Dask scheduler (``tcp://host:port``); overrides
            ``workers``.
        progress: Called with one line per finished task.
        tasks: A subset of :func:`make_tasks` (default all).
        on_record: Called with each record as soon as it reaches this process (in
            completion order), e.g. to keep it on disk so that an interrupted run can
            resume: in this process (``workers=0``) as each task finishes, on Dask as each
            demonstration's group of tasks finishes (an interrupted run loses the groups in
            progress).
    """
    tasks = list(make_tasks(config) if tasks is None else tasks)
    say = progress or (lambda line: None)
    keep = on_record or (lambda record: None)
    started = time.perf_counter()
    records: dict[int, dict] = {}

    def finished(record):
        records[record["index"]] = record
        keep(record)
        say(_progress_line(len(records), len(tasks), started, record))

    if not tasks:
        return []
    # One unit of work per demonstration: one IK pass, one setup, shared plant runs.
    groups = task_groups(tasks)
    if scheduler is None and workers == 0:
        for group in groups:
            for record in iter_task_group(group, base, config):
                finished(record)
        return [records[t.index] for t in tasks]
    if workers < 0:
        raise ValueError(f"workers = {workers!r} must be >= 0")
    try:
        from distributed import Client, LocalCluster, as_completed
    except ImportError as error:
        raise ImportError("the experiment runs on Dask: pip install 'telesmooth[bench]' (or "
                          "dask[distributed]); workers=0 runs without it") from error
    import dask

    cluster = None
    if scheduler is None:
        # Worker processes on this host only; no dashboard (the scheduler still serves its
        # health/metrics endpoint, on 127.0.0.1 like everything else here). No statistical
        # profiler in the workers: it samples every task's stack every 10 ms, which cost
        # 10 % of the experiment's time (docs/numerics.md).
        with dask.config.set({"distributed.worker.profile.enabled": False}):
            cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                                   host="127.0.0.1", dashboard_address=None)
        client = Client(cluster)
    else:
        client = Client(scheduler)
    try:
        # Long groups first (C8 runs seven demonstrations, a demonstration's group every
        # method) so the tail of the run is short.
        order = sorted(groups, key=lambda group: (group[0].kind != "c8", -len(group)))
        futures = [client.submit(run_task_group, group, base, config, pure=False,
                                 key=f"telesmooth-experiment-{group[0].index}")
                   for group in order]
        for future in as_completed(futures):
            for record in future.result():
                finished(record)
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
    return [records[t.index] for t in tasks]


