"""The paper's Table 2 for one scenario: every smoothing method through the same plant.

Pipeline (docs/method.md §6/§7):

    recorded operator session ─▶ ground-station IK ─▶ one joint sample z_k per uplink tick
      (exactly what the online chain's FIFO samples; :func:`joint_targets_at_uplink_rate`),
      over the recording and ``scenario.settle_s`` more (the operator holds the last pose)
        └─▶ each method on the same z (``smoothing.methods.smooth_recording``), same Φ, Q(σ_0),
            r and rest start, limits of ``scenario.smoother``
              └─▶ packet k = the estimate of sample k − d (d = L for the fixed-lag methods,
                  else 0), the start pose before that, the last estimate held after
                    └─▶ 4 Hz Uplink ─▶ the flexible-joint robot with its laser tracker
                        (the same stages as the online chain and the offline playback)

Every method is played through an identical plant for the same simulated time, so the response
errors are comparable. The online chain's pass-through, BMFLS and Online-CKS modes send exactly
the packets built here when the pre-simulator never holds (``tests/test_comparison.py`` checks
Online-CKS against :func:`~telesmooth.diagrams.simulation.simulate`).

The chain (``chain`` of :func:`compare_methods` and :func:`prepare_comparison`; the setup's
scenario carries it). ``"paper"`` (default): the uplink drives the robot directly, as in the
paper. ``"deployed"``: each method's packets go through the onboard receiver and the onboard
link guard to the robot, as the deployed chain runs them
(:func:`~telesmooth.diagrams.offline_playback.play_path`); the figures of the commands stay
those of what the method sent, e is read when the robot has reached each command (a ramp
after the robot began to move towards it, behind the link and the guard:
:func:`~telesmooth.diagrams.simulation.response_instants`), and ``metrics["guard"]`` says
what the guard did (:func:`~telesmooth.diagrams.simulation.guard_metrics`: the commands it
limited, the largest cut, the FD acceleration and jerk of what the robot received).

Metrics per method (index i = operator sample, 0 ≤ i < N):

* ``fd_acceleration`` / ``fd_jerk``: finite differences of the packet sequence *as the plant
  receives it* (start pose ×3 in front, last packet ×3 after) against a_max / j_max.
* ``position_deformation_rad``, ``velocity_deformation_rad_per_s``, ``cartesian_deformation_m``:
  estimate of sample i against z_i (docs/method.md §6 Def_q, E_def).
* e(i) = ‖FK(q̂_i) − x^A(t_{i+d} + ramp)‖: the robot's response to the packet carrying sample i,
  with the tracker read when the interpolator has reached that packet (the tracker sample
  taken at that instant; with a zero-order hold, at the end of the packet's hold:
  :func:`~telesmooth.diagrams.simulation.response_delay_s`). e_ORG is e of the
  ``original`` run, e_SMT that of the method, P = (Σe_ORG − Σe_SMT)/Σe_ORG × 100 %.
* ``operator_error_m``: ‖FK(z_i) − x^A(t_{i+d} + ramp)‖, the error against the operator's
  intent (at most E_def + e_SMT by the triangle inequality).
* ``residual_motion_m``: max ‖x^A(t) − FK(last packet)‖ once the robot has reached the packet
  carrying the operator's last real sample (the smoother's tail and the flexible links ringing
  after the operator stopped); ``settling_time_s``: from the operator's last sample until the
  tool stays within :data:`SETTLED_TOLERANCE_M` of its final position (includes the method's
  delay); NaN, with ``settled`` false, when it has not stayed inside for the run's last
  :data:`SETTLED_HOLD_S`.
* ``latency_s``: the shift τ that best aligns the tool track with the operator's intent
  (:func:`response_latency`); ``added_latency_s`` = τ − τ of the original.
* ``presim_violations``: samples the pre-simulator would reject (collision within the safety
  margin, joint limits). The comparison is a simulation, so they are reported, not enforced.

Method names are those of the registry, :data:`telesmooth.smoothing.methods.METHODS` (with
its aliases), among them ``offline-cks-trajectory``: Offline-CKS with hard finite-difference
limits and rest at the end (docs/method.md §2.6; the offline mode's default). Plain
``offline-cks`` is the paper's state box without a terminal constraint.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable

import numpy as np

from telesmooth.arms.collision import ArmCollisionModel
from telesmooth.arms.joint_vectors import as_per_joint
from telesmooth.arms.self_contact import SelfContactCheck
from telesmooth.diagrams.offline_playback import (
    RAMP_START_LOG,
    play_path,
    playback_guard_record,
    ramp_start_times,
    set_points,
)
from telesmooth.diagrams.offline_validation import validate_joint_path
from telesmooth.diagrams.scenario import CHAINS, Scenario, make_haptic_recording
from telesmooth.diagrams.session_sampling import joint_targets_at_uplink_rate, recording_ticks
from telesmooth.diagrams.simulation import (
    guard_record_metrics,
    plant_summary,
    response_delay_s,
    response_instants,
    sample_at,
    tool_positions,
)
from telesmooth.diagrams.teleoperation import scenario_smoother_config
from telesmooth.smoothing.methods import (
    METHOD_ALIASES,
    METHODS,
    SmoothingSettings,
    method_name,
    method_variant,
    smooth_recording,
)
from telesmooth.smoothing.metrics import (
    deformation_statistics,
    finite_differences,
    improvement_ratio,
    limit_statistics,
    motion_span,
    smoothing_metrics,
    tracking_errors,
)
from telesmooth.smoothing.offline import OFFLINE_SOLVERS, with_rest_history

__all__ = [
    "Comparison",
    "LEAST_DEFORMATION",
    "ComparisonSetup",
    "OperatorSamples",
    "SETTLED_TOLERANCE_M",
    "MethodRun",
    "compare_methods",
    "method_settings",
    "operator_samples",
    "prepare_comparison",
    "response_latency",
    "run_method",
    "run_summary",
    "set_improvement_ratios",
]

LEAST_DEFORMATION = "offline-hard"
"""The reference for how much deformation the limits force (the commands closest to the
operator within them): reports set every method's E_def beside it."""

_REFERENCE = "original"

_MAX_LATENCY_S = 5.0
"""The longest response latency :func:`response_latency` looks for, s."""

SETTLED_TOLERANCE_M = 1e-4
"""The tool counts as settled once it stays within this distance of its final position, m."""

SETTLED_HOLD_S = 0.5
"""…and has stayed within it for at least this long by the end of the run, s."""


@dataclasses.dataclass(frozen=True, eq=False)
class MethodRun:
    """One method played through the plant.

    Attributes:
        method: The name (one of :data:`~telesmooth.smoothing.methods.METHODS`).
        delay_ticks: d, packets between operator sample i and the packet carrying it.
        estimate: q̂_i, the method's estimate of each operator sample, rad, (N, J).
        packets: What the uplink sent at each tick t_k = k·Δt, rad, (N + d, J).
        t_s: The times of ``packets``, s.
        tracker_t_s, tool_position_m: The laser tracker's record, s and m, (T,), (T, 3).
        q_link, q_motor: Link and motor angles at the tracker rate, rad, (T, J).
        response_error_m: e(i) per operator sample, m, (N,).
        operator_error_m: ‖FK(z_i) − x^A‖ per operator sample, m, (N,).
        metrics: JSON-ready figures (see the module docstring).
        timings_s: "smooth" and "simulate" wall-clock times, s.
        playback_reused: True when the plant run is an earlier method's, whose packets
            were the same to the bit (see ``playbacks`` of :func:`run_method`).
        self_contact: The check of its plant run without collision geometry
            (:func:`~telesmooth.diagrams.offline_playback.play_path`): when it is certified
            the figures come from that run, otherwise (or when it is None) from a run of the
            plant with its geometry.
    """

    method: str
    delay_ticks: int
    estimate: np.ndarray
    packets: np.ndarray
    t_s: np.ndarray
    tracker_t_s: np.ndarray
    tool_position_m: np.ndarray
    q_link: np.ndarray
    q_motor: np.ndarray
    response_error_m: np.ndarray
    operator_error_m: np.ndarray
    metrics: dict
    timings_s: dict
    playback_reused: bool = False
    self_contact: SelfContactCheck | None = None


@dataclasses.dataclass(frozen=True, eq=False)
class Comparison:
    """Every method's run on one scenario.

    Attributes:
        setup: What every method ran on (:class:`ComparisonSetup`); its scenario, joint
            names, period, sample times, operator samples, start pose, duration and limits
            are also read directly (``comparison.t_s`` …).
        runs: method name → :class:`MethodRun`, in the requested order.
    """

    setup: ComparisonSetup
    runs: dict

    scenario = property(lambda self: self.setup.scenario, doc="The scenario.")
    joint_names = property(lambda self: self.setup.joint_names, doc="Joint order, (J,).")
    period_s = property(lambda self: self.setup.period_s, doc="Δt, s.")
    t_s = property(lambda self: self.setup.t_s, doc="Operator sample times t_i, s, (N,).")
    q_original = property(lambda self: self.setup.q_original,
                          doc="z_i, the operator's samples, rad, (N, J).")
    q_start = property(lambda self: self.setup.q_start,
                       doc="The robot's start pose, rad, (J,).")
    duration_s = property(lambda self: self.setup.duration_s,
                          doc="Simulated time of every run, s.")
    max_acceleration = property(lambda self: self.setup.max_acceleration,
                                doc="a_max per joint (scenario.smoother), (J,).")
    max_jerk = property(lambda self: self.setup.max_jerk,
                        doc="j_max per joint (scenario.smoother), (J,).")
    chain = property(lambda self: self.setup.scenario.chain,
                     doc='The chain every method was played through ("paper" or "deployed").')

    def plant(self) -> dict:
        """The plant every method ran on, with its vibration modes (:func:`plant_summary`)."""
        return plant_summary(self.scenario, self.q_start)

    def table(self) -> list[dict]:
        """One row per method with the Table 2 figures (worst joint for per-joint values)."""
        return [{"method": name, **run_summary(run.metrics),
                 "improvement_ratio_percent": run.metrics["improvement_ratio_percent"],
                 "added_latency_s": run.metrics["added_latency_s"]}
                for name, run in self.runs.items()]


def run_summary(metrics: dict) -> dict:
    """A run's figures as one flat row, the worst joint for per-joint values.

    Everything :func:`run_method` measures on its own; P and the added latency need the
    original's run and are added by the caller (:meth:`Comparison.table`, the experiment).
    """
    def worst(key, field):
        return float(np.max(metrics[key][field]))

    return {
        "delay_s": metrics["delay_s"],
        "fd_acc_max_over_limit": worst("fd_acceleration", "max_over_limit"),
        "fd_acc_fraction_over": worst("fd_acceleration", "fraction_over_limit"),
        "fd_jerk_max_over_limit": worst("fd_jerk", "max_over_limit"),
        "fd_jerk_fraction_over": worst("fd_jerk", "fraction_over_limit"),
        "original_fd_acc_max_over_limit": worst("original_fd_acceleration", "max_over_limit"),
        "original_fd_jerk_max_over_limit": worst("original_fd_jerk", "max_over_limit"),
        "position_deformation_mean_rad": worst("position_deformation_rad", "mean"),
        "position_deformation_max_rad": worst("position_deformation_rad", "max"),
        "velocity_deformation_mean_rad_per_s": worst("velocity_deformation_rad_per_s", "mean"),
        "cartesian_deformation_mean_m": metrics["cartesian_deformation_m"]["mean"],
        "cartesian_deformation_max_m": metrics["cartesian_deformation_m"]["max"],
        **_state_summary(metrics),
        "position_deformation_motion_mean_rad": metrics["motion_deformation"][
            "position_mean_rad"],
        "cartesian_deformation_motion_mean_m": metrics["motion_deformation"]["cartesian_mean_m"],
        "e_motion_mean_m": metrics["response_error_m"]["motion_mean"],
        "e_settle_mean_m": metrics["response_error_m"]["settle_mean"],
        "e_tracker_rate_mean_m": metrics["response_error_tracker_rate_m"]["mean"],
        "e_tracker_rate_max_m": metrics["response_error_tracker_rate_m"]["max"],
        "e_tracker_rate_motion_mean_m": metrics["response_error_tracker_rate_m"]["motion_mean"],
        "e_tracker_rate_settle_mean_m": metrics["response_error_tracker_rate_m"]["settle_mean"],
        "e_mean_m": metrics["response_error_m"]["mean"],
        "e_max_m": metrics["response_error_m"]["max"],
        "e_sum_m": metrics["response_error_m"]["sum"],
        "operator_error_mean_m": metrics["operator_error_m"]["mean"],
        "residual_motion_m": metrics["residual_motion_m"],
        "settling_time_s": metrics["settling_time_s"],
        "settled": float(metrics["settled"]),
        "latency_s": metrics["latency_s"],
        "link_deflection_max_rad": float(np.max(metrics["link_deflection_max_abs_rad"])),
        "presim_violations": metrics["presim_violations"]["total"],
        **_guard_summary(metrics.get("guard")),
    }


def _state_summary(metrics: dict) -> dict:
    """The worst joint's state acceleration and jerk over their limits, and the share of
    samples over (None for a method without states, e.g. the original)."""
    out = {}
    for name, key in (("acc", "state_acceleration"), ("jerk", "state_jerk")):
        stats = metrics.get(key)
        out[f"state_{name}_max_over_limit"] = (float(np.max(stats["max_over_limit"]))
                                               if stats else None)
        out[f"state_{name}_fraction_over"] = (float(np.max(stats["fraction_over_limit"]))
                                              if stats else None)
    return out


def _guard_summary(guard: dict | None) -> dict:
    """The guard's figures of a deployed run as flat row entries (none in the paper's chain):
    commands issued and limited, the largest cut (worst joint), the largest distance from the
    stream, and the FD acceleration and jerk of what the robot received over their limits."""
    if guard is None:
        return {}
    received = guard["received"]
    return {
        "guard_commands": guard["commands"],
        "guard_limited": guard["limited"],
        "guard_largest_cut_rad": float(np.max(guard["largest_cut_rad"])),
        "guard_stream_distance_rad": guard["stream_distance_rad"],
        "received_fd_acc_max_over_limit": float(np.max(
            received["fd_acceleration"]["max_over_limit"])),
        "received_fd_jerk_max_over_limit": float(np.max(received["fd_jerk"]["max_over_limit"])),
    }


def method_settings(scenario: Scenario, method: str, offline_solver: str = "drake"
                    ) -> tuple[str, SmoothingSettings]:
    """The ``smooth_recording`` method and settings a comparison method uses on ``scenario``.

    All methods share σ_0, r (divided by the samples per period under the period mean), L,
    a_max, j_max and the reduced-Q settings of ``scenario.smoother``. ``offline_solver``
    ("drake" or "banded-ip", :data:`~telesmooth.smoothing.offline.OFFLINE_SOLVERS`) solves the
    Offline-CKS methods.

    Raises:
        ValueError: For an unknown method or solver.
    """
    if not isinstance(method, str) or (method not in METHODS and method not in METHOD_ALIASES):
        raise ValueError(f"method = {method!r} must be one of {METHODS}")
    if offline_solver not in OFFLINE_SOLVERS:
        raise ValueError(f"offline_solver = {offline_solver!r} must be one of {OFFLINE_SOLVERS}")
    config = scenario_smoother_config(scenario)
    settings = SmoothingSettings(
        max_acceleration=config.max_acceleration_rad_per_s2,
        max_jerk=config.max_jerk_rad_per_s3, sigma=config.sigma, r=config.r, lag=config.lag,
        fixed_lag_method=config.fixed_lag_method, reduced_q=config.reduced_q,
        offline_solver=offline_solver, start_prior=config.start_prior)
    return method_variant(method, settings)


def _settle_ticks(scenario: Scenario) -> int:
    return math.ceil(scenario.settle_s / scenario.uplink.period_s - 1e-9)


@dataclasses.dataclass(frozen=True, eq=False)
class ComparisonSetup:
    """What every method of one scenario shares: the operator's samples, limits and plant run.

    Built once per scenario by :func:`prepare_comparison`; :func:`run_method` plays one method.

    Attributes:
        scenario: The scenario; its ``chain`` is the chain every method is played through.
        joint_names: Joint order, (J,).
        period_s: Δt, s.
        t_s: Operator sample times t_i, s, (N,) (the recording and ``settle_s`` of holding).
        q_original: z_i, rad, (N, J).
        q_start: The robot's start pose, rad, (J,).
        num_operator_samples: Samples that carry the recording (the rest hold its last pose).
        duration_s: Simulated time of every run (long enough for the fixed-lag delay), s.
        ramp_s: How long after its send time each command's response is read
            (:func:`~telesmooth.diagrams.simulation.response_delay_s`), s.
        max_acceleration, max_jerk: a_max, j_max per joint, (J,).
        operator_tool_m: FK(z_i), m, (N, 3).
        collision_model: The pre-simulator's collision model (violations are reported).
        motion: The operator's motion phase, (first, last) sample indices inclusive
            (:func:`~telesmooth.smoothing.metrics.motion_span`), or None if the operator
            never moved.
    """

    scenario: Scenario
    joint_names: tuple
    period_s: float
    t_s: np.ndarray
    q_original: np.ndarray
    q_start: np.ndarray
    num_operator_samples: int
    duration_s: float
    ramp_s: float
    max_acceleration: np.ndarray
    max_jerk: np.ndarray
    operator_tool_m: np.ndarray
    collision_model: ArmCollisionModel
    motion: tuple[int, int] | None = None

    def fk(self, q) -> np.ndarray:
        """Tool positions of joint positions ``q`` (…, J), m."""
        return tool_positions(self.scenario, q)


@dataclasses.dataclass(frozen=True, eq=False)
class OperatorSamples:
    """The operator's joint samples at the uplink rate (plain arrays; cheap to ship).

    Attributes:
        t_s: Sample times, s, (N,).
        q: z_i, rad, (N, J): the recording through the ground station's IK, then the last pose
            held for ``scenario.settle_s``.
        q_start: The robot's start pose, rad, (J,).
        num_operator_samples: Samples that carry the recording.
    """

    t_s: np.ndarray
    q: np.ndarray
    q_start: np.ndarray
    num_operator_samples: int


def operator_samples(scenario: Scenario) -> OperatorSamples:
    """Runs the scenario's recording through the ground station's IK (one sample per tick).

    Raises:
        ValueError: A scenario without a recording (``haptic.source = 'lcm'``).
    """
    recording = make_haptic_recording(scenario)
    if recording is None:
        raise ValueError("compare needs a recorded session; haptic.source = 'lcm' is a live "
                         "device")
    # The operator's samples, then the operator holding the last pose while the robot settles.
    num_operator_samples = recording_ticks(scenario, recording)
    t_s, z, q_start, _ = joint_targets_at_uplink_rate(
        scenario, num_ticks=num_operator_samples + _settle_ticks(scenario))
    return OperatorSamples(t_s=t_s, q=z, q_start=np.asarray(q_start, dtype=float).copy(),
                           num_operator_samples=num_operator_samples)


def prepare_comparison(scenario: Scenario, samples: OperatorSamples | None = None, *,
                       chain: str = "paper") -> ComparisonSetup:
    """The operator's samples at the uplink rate and everything the methods share.

    Args:
        scenario: The scenario.
        samples: Its :func:`operator_samples`, if already computed.
        chain: ``"paper"`` (default: the uplink drives the robot, as in the paper) or
            ``"deployed"`` (through the onboard receiver and link guard): the setup's
            scenario is ``scenario`` with this chain, whatever chain it had.

    Raises:
        ValueError: A scenario without a recording (``haptic.source = 'lcm'``), an unknown
            chain, or link faults with the paper's chain.
    """
    scenario = _with_chain(scenario, chain)
    if samples is None:
        samples = operator_samples(scenario)
    arm = scenario.arm_description
    names = arm.joint_names
    n = arm.num_joints
    period = scenario.uplink.period_s
    t_s, z, q_start = samples.t_s, samples.q, samples.q_start
    num_operator_samples = samples.num_operator_samples
    lag = scenario_smoother_config(scenario).lag
    ramp = response_delay_s(scenario)
    # Every run: the last packet that carries an operator sample (after the fixed-lag delay),
    # its ramp, and the settling.
    duration = (z.shape[0] - 1 + lag) * period + ramp + max(period, scenario.settle_s)
    a_max = as_per_joint("max_acceleration_rad_per_s2",
                         scenario.smoother.max_acceleration_rad_per_s2, n, names, allow_inf=True)
    j_max = as_per_joint("max_jerk_rad_per_s3", scenario.smoother.max_jerk_rad_per_s3, n,
                         names, allow_inf=True)
    collision_model = ArmCollisionModel(
        arm, scenario.workspace_or_default,
        distance_horizon_m=scenario.collision_checker.distance_horizon_m)
    return ComparisonSetup(
        scenario=scenario, joint_names=names, period_s=period, t_s=t_s, q_original=z,
        q_start=q_start, num_operator_samples=num_operator_samples, duration_s=duration,
        ramp_s=ramp, max_acceleration=a_max, max_jerk=j_max,
        operator_tool_m=tool_positions(scenario, z),
        collision_model=collision_model, motion=motion_span(z))


def _with_chain(scenario: Scenario, chain: str) -> Scenario:
    """``scenario`` with ``chain`` (the same object if it has it already)."""
    if chain not in CHAINS:
        raise ValueError(f"chain = {chain!r} must be one of {CHAINS}")
    return scenario if scenario.chain == chain else dataclasses.replace(scenario, chain=chain)


def response_latency(operator_tool_m, t_s, tracker_t_s, tool_position_m, *,
                     max_latency_s: float) -> float:
    """The time shift τ ≥ 0 that best aligns the tool with the operator's intent, s.

    τ minimises mean_i ‖FK(z_i) − x^A(t_i + τ)‖ over τ on the tracker's clock (its sample
    period is the resolution), 0 ≤ τ ≤ ``max_latency_s``, with x^A linearly interpolated.
    Only samples with t_i + ``max_latency_s`` inside the tracker's record count, so every τ is
    scored on the same samples.
    """
    t_s = np.asarray(t_s, dtype=float)
    tracker_t_s = np.asarray(tracker_t_s, dtype=float)
    step = float(np.median(np.diff(tracker_t_s)))
    shifts = np.arange(0.0, max_latency_s + 0.5 * step, step)
    keep = t_s + max_latency_s <= tracker_t_s[-1]
    if not keep.any():
        raise ValueError("the tracker record is shorter than max_latency_s after the first "
                         "operator sample")
    times = t_s[keep][None, :] + shifts[:, None]
    measured = np.stack([np.interp(times, tracker_t_s, tool_position_m[:, axis])
                         for axis in range(tool_position_m.shape[1])], axis=-1)
    cost = np.linalg.norm(measured - operator_tool_m[keep][None, :, :], axis=-1).mean(axis=1)
    return float(shifts[int(np.argmin(cost))])


def run_method(setup: ComparisonSetup, method: str, *, settings: SmoothingSettings | None = None,
               base_method: str | None = None, label: str | None = None,
               offline_solver: str = "drake", playbacks: dict | None = None,
               sigma0=None) -> MethodRun:
    """Smooths the operator's samples with one method and plays the packets through the plant.

    Args:
        setup: From :func:`prepare_comparison`.
        method: A name of :data:`~telesmooth.smoothing.methods.METHODS` (its settings come
            from the scenario).
        settings, base_method: Override the ``smooth_recording`` settings and method (e.g. a
            sensitivity study of Online-CKS); both default to :func:`method_settings`.
        label: The run's name (default ``method``).
        offline_solver: Solver of the Offline-CKS methods (see :func:`method_settings`).
        playbacks: A dict kept by the caller across the methods of one ``setup`` (start it
            empty): each plant run is stored in it under the exact packets played (their
            bytes, with the states sent beside them), and a method whose packets equal an
            earlier one's to the bit reuses that run instead of simulating it again (its
            arrays are made read-only, the first run's too: they are shared). The
            playback is deterministic, so every figure is the same as a new run's (several
            methods often send the same packets: e.g. Offline-CKS and the Kalman smoother
            when no limit binds). None: every method is simulated.
        sigma0: Online-CKS only: the operator's stored σ to start from (σ carried over from
            earlier operations; default the settings' σ_0).

    Returns:
        The run; ``metrics["improvement_ratio_percent"]`` is NaN until the caller sets it
        against the original (see :func:`set_improvement_ratios`).

    Raises:
        RuntimeError: The method failed to produce a command sequence (the message names it).
    """
    scenario = setup.scenario
    names = setup.joint_names
    n = len(names)
    period = setup.period_s
    z = setup.q_original
    q_start = setup.q_start
    num_samples = z.shape[0]
    ramp = setup.ramp_s
    label = label or method
    started = time.perf_counter()
    default_method, default_settings = method_settings(scenario, method, offline_solver)
    base_method = base_method or default_method
    settings = settings or default_settings
    try:
        result = smooth_recording(z, period, base_method, settings, joint_names=names,
                                  sigma0=sigma0)
    except RuntimeError as error:
        raise RuntimeError(f"method {label!r} failed: {error}") from error
    estimate = result.positions
    states = result.states if result.states is not None else np.concatenate(
        [estimate[:, :, None], np.zeros(estimate.shape + (3,))], axis=2)
    delay = round(result.sent_delay_s / period)
    rest = np.zeros((delay, n, 4))
    rest[:, :, 0] = q_start
    packet_states = np.concatenate([rest, states], axis=0)
    packets = packet_states[:, :, 0]
    smoothed = time.perf_counter()

    deployed = scenario.chain == "deployed"
    key = None if playbacks is None else _playback_key(setup, packet_states)
    reused = key is not None and key in playbacks
    if reused:
        logs, self_contact = playbacks[key]
    else:
        logs, self_contact = play_path(
            scenario, packets, states=packet_states, q_start=q_start,
            duration_s=setup.duration_s, name=f"compare_{label}", chain=scenario.chain,
            collision_model=setup.collision_model if deployed else None)
        if playbacks is not None:
            playbacks[key] = (_read_only(logs), self_contact)
    simulated = time.perf_counter()

    fk = setup.fk
    tracker = logs["tracker"]
    tracker_t = tracker.t_s
    tool = tracker.tool_position_m
    if deployed:
        # Behind the link and the guard the robot begins to move towards packet k at the
        # interpolator's poll after the guard's command: read it a ramp after that.
        response_t = response_instants(period * np.arange(len(packets)),
                                       ramp_start_times(logs), ramp)[delay:]
    else:
        response_t = (np.arange(num_samples) + delay) * period + ramp
    measured = sample_at(tracker_t, tool, response_t)
    estimate_tool = fk(estimate)
    e = tracking_errors(estimate_tool, measured)
    e_operator = tracking_errors(setup.operator_tool_m, measured)
    # What the plant receives: start pose ×3, the packets, the last packet held.
    received = with_rest_history(packets, q_start)
    a_max, j_max = setup.max_acceleration, setup.max_jerk
    metrics = smoothing_metrics(
        smoothed_positions=estimate, original_positions=z, dt_s=period,
        max_acceleration=a_max, max_jerk=j_max, smoothed_states=result.states,
        forward_kinematics=fk, joint_names=names)
    metrics["fd_acceleration"] = limit_statistics(finite_differences(received, period, 2),
                                                  a_max)
    metrics["fd_jerk"] = limit_statistics(finite_differences(received, period, 3), j_max)
    metrics["response_error_m"] = {"mean": float(e.mean()), "max": float(e.max()),
                                   "sum": float(e.sum()), **_phase_means(e, setup.motion)}
    # The same at the tracker's rate: every tracker sample against the set-point the robot
    # was following at that instant (its ramp), split at the response instants of the
    # motion phase's first and last samples.
    ramps = logs[RAMP_START_LOG if deployed else "command_ramp"].values
    e_tracker = tracking_errors(fk(set_points(
        ramps, tracker_t, scenario.onboard.interpolator.ramp_duration_s,
        lead_s=scenario.onboard.time_step_s)), tool)
    metrics["response_error_tracker_rate_m"] = {
        "mean": float(e_tracker.mean()), "max": float(e_tracker.max()),
        **_phase_means(e_tracker, _tracker_phases(setup.motion, response_t, ramp, tracker_t))}
    metrics["motion_deformation"] = _motion_deformation(setup, estimate, estimate_tool)
    metrics["operator_error_m"] = {"mean": float(e_operator.mean()),
                                   "max": float(e_operator.max())}
    metrics["improvement_ratio_percent"] = math.nan
    # After the operator stops: the tool's motion about its final position, from when the
    # packet carrying the operator's last sample has been reached.
    num_operator_samples = setup.num_operator_samples
    distance_to_final = np.linalg.norm(tool - fk(packets[-1]), axis=-1)
    after = tracker_t >= (response_t[num_operator_samples - 1] if deployed else
                          (num_operator_samples - 1 + delay) * period + ramp)
    metrics["residual_motion_m"] = float(distance_to_final[after].max()) \
        if after.any() else math.nan
    outside = np.flatnonzero(distance_to_final > SETTLED_TOLERANCE_M)
    # Not inside for the last SETTLED_HOLD_S of the run: not settled (NaN; the time is
    # unknown, not the run's length).
    metrics["settled"] = bool(outside.size == 0 or
                              tracker_t[outside[-1]] <= tracker_t[-1] - SETTLED_HOLD_S)
    metrics["settling_time_s"] = (
        0.0 if outside.size == 0 else
        max(0.0, float(tracker_t[outside[-1]]) - (num_operator_samples - 1) * period)
        if metrics["settled"] else math.nan)
    metrics["latency_s"] = response_latency(
        setup.operator_tool_m, setup.t_s, tracker_t, tool,
        max_latency_s=min(_MAX_LATENCY_S, float(tracker_t[-1] - setup.t_s[0]) / 2))
    deflection = tracker.q_link - tracker.q_motor
    metrics["link_deflection_max_abs_rad"] = np.abs(deflection).max(axis=0).tolist()
    violations = validate_joint_path(packets, period * np.arange(len(packets)), scenario,
                                     start_position=q_start, check_fd_limits=False,
                                     collision_model=setup.collision_model)
    kinds = {kind: sum(v.kind == kind for v in violations)
             for kind in ("non_finite", "joint_limit", "collision")}
    metrics["presim_violations"] = {**kinds, "total": len(violations)}
    metrics["delay_s"] = delay * period
    metrics["chain"] = scenario.chain
    metrics["guard"] = (guard_record_metrics(
        playback_guard_record(logs, scenario.command_receiver.poll_period_s), scenario, names,
        q_start) if deployed else None)
    metrics["details"] = result.details
    if result.sigma is not None and result.final_sigma is not None:
        # The reduced-Q σ of an online smoother: where it started, ended and whether it never
        # grew (claim C8).
        start = np.broadcast_to(np.asarray(settings.sigma if sigma0 is None else sigma0,
                                           dtype=float), (n,))
        path = np.vstack([start[None, :], np.asarray(result.sigma, dtype=float).reshape(-1, n)])
        metrics["sigma"] = {"start": start.tolist(), "end": np.asarray(
            result.final_sigma, dtype=float).tolist(),
            "monotone": bool(np.diff(path, axis=0).max(initial=0.0) <= 0.0)}
    timings = {"smooth": smoothed - started, "simulate": simulated - smoothed}
    metrics["timings_s"] = timings
    return MethodRun(
        method=label, delay_ticks=delay, estimate=estimate, packets=packets,
        t_s=period * np.arange(len(packets)), tracker_t_s=tracker_t, tool_position_m=tool,
        q_link=tracker.q_link, q_motor=tracker.q_motor, response_error_m=e,
        operator_error_m=e_operator, metrics=metrics, timings_s=timings,
        playback_reused=reused, self_contact=self_contact)


def _phase_means(errors: np.ndarray, phases) -> dict:
    """Mean of ``errors`` over the motion phase and over the settle phase after it.

    ``phases`` is (first, last) inclusive sample indices of the motion (the settle phase is
    every later sample), or a pair of boolean masks (motion, settle), or None (no motion:
    NaN for both).
    """
    if phases is None:
        return {"motion_mean": math.nan, "settle_mean": math.nan}
    first, last = phases
    if isinstance(first, np.ndarray):
        motion, settle = errors[first], errors[last]
    else:
        motion, settle = errors[first:last + 1], errors[last + 1:]
    return {"motion_mean": float(motion.mean()) if motion.size else math.nan,
            "settle_mean": float(settle.mean()) if settle.size else math.nan}


def _tracker_phases(motion, response_t: np.ndarray, ramp_s: float, tracker_t: np.ndarray):
    """(motion, settle) masks over the tracker's samples: the motion phase from when the
    robot began towards the motion's first sample (its response instant less the ramp) to
    the response instant of its last; the settle phase after that. None without motion."""
    if motion is None:
        return None
    first, last = motion
    begin, end = response_t[first] - ramp_s, response_t[last]
    return (tracker_t >= begin) & (tracker_t <= end), tracker_t > end


def _motion_deformation(setup: ComparisonSetup, estimate: np.ndarray,
                        estimate_tool: np.ndarray) -> dict:
    """The deformations over the operator's motion phase only (the holds before and after
    it add zeros to every method's mean): worst joint's mean position deformation, rad, and
    the mean Cartesian deformation, m; NaN without motion. ``estimate_tool`` is
    FK(``estimate``), already computed for e."""
    if setup.motion is None:
        return {"position_mean_rad": math.nan, "cartesian_mean_m": math.nan}
    first, last = setup.motion
    part = slice(first, last + 1)
    position = deformation_statistics(estimate[part], setup.q_original[part])
    cartesian = np.linalg.norm(estimate_tool[part] - setup.operator_tool_m[part], axis=-1)
    return {"position_mean_rad": float(np.max(position["mean"])),
            "cartesian_mean_m": float(cartesian.mean())}


def _playback_key(setup: ComparisonSetup, packet_states: np.ndarray) -> tuple:
    """What a playback depends on: the setup (its scenario, start pose and duration; the key
    holds the object itself, so a dict shared across setups never mixes them) and the packets
    with their states, exactly."""
    states = np.ascontiguousarray(packet_states, dtype=float)
    return (setup, states.shape, states.tobytes())


def _read_only(logs: dict) -> dict:
    """The playback's logs with every array read-only (the runs that reuse them share them)."""
    for record in logs.values():
        for value in vars(record).values():
            if isinstance(value, np.ndarray):
                value.flags.writeable = False
    return logs


def _how_played(run: MethodRun, duration_s: float) -> str:
    """How a run's plant run was made, for the progress line of :func:`compare_methods`."""
    if run.playback_reused:
        return "the same packets as an earlier method: its plant run reused"
    text = f"{duration_s:.1f} s simulated in {run.timings_s['simulate']:.1f} s"
    check = run.self_contact
    if check is None or check.certified:
        return text
    why = f": {check.reason}" if check.reason else ""
    return f"{text} with the arm's collision geometry (self-contact not excluded{why})"


def set_improvement_ratios(runs: dict, reference: str = _REFERENCE) -> None:
    """Sets P of every run in ``runs`` (name → MethodRun) against ``runs[reference]``."""
    e_org = runs[reference].response_error_m
    for run in runs.values():
        run.metrics["improvement_ratio_percent"] = improvement_ratio(e_org,
                                                                     run.response_error_m)
        run.metrics["added_latency_s"] = (run.metrics["latency_s"]
                                          - runs[reference].metrics["latency_s"])


def compare_methods(scenario: Scenario, methods=METHODS, *,
                    progress: Callable[[str], None] | None = None,
                    offline_solver: str = "drake", chain: str = "paper") -> Comparison:
    """Runs each method on the scenario's recorded session through the same plant.

    Args:
        scenario: A scenario with a recorded session (not ``haptic.source = 'lcm'``).
        chain: ``"paper"`` (default: the paper's chain, the uplink drives the robot) or
            ``"deployed"`` (each method's packets through the onboard receiver and link
            guard); the scenario's own ``chain`` is not read.
        methods: Names from :data:`~telesmooth.smoothing.methods.METHODS` (or their aliases);
            ``original`` is always run (it is the
            reference of P) and comes first.
        progress: Called with a one-line message per method.
        offline_solver: Solver of the Offline-CKS methods: "drake" (the MathematicalProgram)
            or "banded-ip" (the banded interior point; the same optimum to ~1e-6 rad).

    Returns:
        The comparison. A method that fails (e.g. Offline-CKS reports no solution) raises.

    Raises:
        ValueError: Unknown or repeated method names; a scenario without a recording.
        RuntimeError: A method failed to produce a command sequence (the message names it).
    """
    methods = tuple(methods)
    unknown = [m for m in methods if not isinstance(m, str)
               or (m not in METHODS and m not in METHOD_ALIASES)]
    if unknown:
        raise ValueError(f"methods {unknown!r} are not among {METHODS}")
    methods = tuple(method_name(m) for m in methods)
    if len(set(methods)) != len(methods):
        raise ValueError(f"methods = {methods!r} repeats a method")
    if offline_solver not in OFFLINE_SOLVERS:
        raise ValueError(f"offline_solver = {offline_solver!r} must be one of {OFFLINE_SOLVERS}")
    methods = (_REFERENCE,) + tuple(m for m in methods if m != _REFERENCE)
    say = progress or (lambda message: None)
    setup = prepare_comparison(scenario, chain=chain)
    runs = {}
    playbacks = {}
    for number, method in enumerate(methods, start=1):
        run = run_method(setup, method, offline_solver=offline_solver, playbacks=playbacks)
        runs[method] = run
        set_improvement_ratios({_REFERENCE: runs[_REFERENCE], method: run})
        say(f"[{number}/{len(methods)}] {method}: smoothed in {run.timings_s['smooth']:.2f} s, "
            f"{_how_played(run, setup.duration_s)}; "
            f"P = {run.metrics['improvement_ratio_percent']:.1f} %")
    return Comparison(setup=setup, runs=runs)
