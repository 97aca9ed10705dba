"""Every smoothing method of the paper behind one call, aligned sample by sample
(docs/method.md §7).

``smooth_recording`` returns, for each input sample k, the estimate of that sample and the delay
after which the ground station sends it:

=================  ==============================================  ===========================
method             estimate of sample k                            sent after
=================  ==============================================  ===========================
``original``       z_k (alias ``pass-through``, the chain's name)   0
``kf``             x̂_{k|k}, the a-posteriori Kalman filter          0 (with filter phase lag)
``kf-predictor``   x̂_{k|k−1}, the one-step predictor                0
``offline-ks``     RTS over the whole recording                    offline (replayed from t_0)
``offline-cks``    Offline-CKS, Drake MathematicalProgram          offline (replayed from t_0)
``offline-cks-     Offline-CKS with hard FD limits and rest at     offline (replayed from t_0)
trajectory``       the end (``constraint="trajectory"``,
                   ``rest_at_end``: :func:`method_variant`)
``offline-hard``   closest to z within hard FD limits (not a       offline (replayed from t_0)
                   smoother: the least deformation the limits
                   force; smoothing.offline_hard)
``bmfls``          x̂_{k|k+L}, fixed-lag, constant σ_0               L Δt
``online-cks``     x̂_{k|k+L}, fixed-lag with reduced-Q σ_k          L Δt
``online-hard``    Online-CKS's x̂_{k|k+L} through the hard limiter   L Δt
                   (smoothing.online_hard: FD v/a/j always within)
``ruckig``         Ruckig's jerk-limited motion toward z_k (peer)   0 (trails the stream)
=================  ==============================================  ===========================

For the fixed-lag methods the operator is taken to hold the last pose after the recording ends
(L extra copies of the last sample), so every sample gets an estimate.
All methods share Φ, Q(σ_0), r and start at rest at z_0: the fixed-lag methods exactly, the
offline smoothers by their start prior (``SmoothingSettings.start_prior``: "rest" by default,
or the paper's "loose" one); the Kalman filters keep the paper's prior diag(r, 1e-4, 1e-3,
1e-2) (a filter's first estimates follow the first samples whichever prior it has).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import NamedTuple

import numpy as np

from telesmooth.arms.joint_vectors import (
    as_per_joint,
    check_positive_int,
    check_positive_scalar,
    check_trajectory,
)
from telesmooth.smoothing.fixed_lag import FixedLagSmoother
from telesmooth.smoothing.kalman import (
    START_PRIORS,
    kalman_filter,
    rest_prior,
    rts_smoother,
    start_prior,
)
from telesmooth.smoothing.model import DEFAULT_LAG, DEFAULT_R, DEFAULT_SIGMA, MAX_LAG, JerkModel
from telesmooth.smoothing.offline import solve_offline_cks
from telesmooth.smoothing.offline_hard import solve_offline_hard
from telesmooth.smoothing.online_hard import online_hard_run
from telesmooth.smoothing.reduced_q import OnlineCks, ReducedQConfig
from telesmooth.smoothing.ruckig_stream import ruckig_stream

METHODS = ("original", "kf", "kf-predictor", "offline-ks", "offline-cks",
           "offline-cks-trajectory", "offline-hard", "bmfls", "online-cks", "online-hard",
           "ruckig")
"""Every smoothing method, in the order of the paper's Table 2: the one registry that
``telesmooth smooth``, ``compare``, ``foresight``, ``experiment`` and ``demo`` and the
scenario's ``smoother.method`` read (each command takes the names of :data:`METHOD_ALIASES`
too)."""

METHOD_ALIASES = {"pass-through": "original"}
"""Other names of a method: the online chain's ``pass-through`` (no smoothing, the raw
samples with the chain's latency) is ``original``."""

FIXED_LAG_METHODS = ("bmfls", "online-cks", "online-hard")
"""The methods that send sample k after L samples (the fixed-lag smoothers; the forms of the
smoother itself are :data:`telesmooth.smoothing.fixed_lag.FIXED_LAG_FORMS`)."""

OFFLINE_METHODS = ("offline-ks", "offline-cks", "offline-cks-trajectory", "offline-hard")
"""The methods that need the whole recording."""

CHAIN_METHODS = ("original", "bmfls", "online-cks", "online-hard")
"""The methods the online chain's smoother runs (a scenario's ``smoother.method``; also
by their aliases)."""


def method_name(method, field: str = "method", known=METHODS) -> str:
    """The registry's name of ``method`` (an alias of :data:`METHOD_ALIASES` resolved).

    Args:
        method: A name of ``known`` or an alias of one.
        field: The option or field named in the error.
        known: The names accepted (default every method).

    Raises:
        ValueError: For another name (the closest names, then the list).
    """
    from telesmooth.user_input import unknown_choice

    name = METHOD_ALIASES.get(method, method) if isinstance(method, str) else method
    if name not in known:
        raise ValueError(unknown_choice(field, method, tuple(known) + tuple(
            alias for alias, target in METHOD_ALIASES.items() if target in known),
            noun="methods"))
    return name


def method_variant(method: str, settings: SmoothingSettings) -> tuple[str, SmoothingSettings]:
    """The :func:`smooth_recording` computation behind a method name: ``offline-cks-trajectory``
    is ``offline-cks`` with ``constraint="trajectory"`` and ``rest_at_end`` (docs/method.md
    §2.6; the offline mode's default); every other method is itself, ``settings`` unchanged.
    """
    method = method_name(method)
    if method == "offline-cks-trajectory":
        return "offline-cks", replace(settings, constraint="trajectory", rest_at_end=True)
    return method, settings


@dataclass(frozen=True)
class SmoothingSettings:
    """Everything a method needs besides the data; per-joint values may be scalars.

    Attributes:
        max_acceleration: a_max [rad/s²] (scalar, sequence or {joint: value}).
        max_jerk: j_max [rad/s³].
        max_velocity: v_max [rad/s] for Offline-CKS trajectory mode; None = no limit.
        sigma: σ_0 [rad²/s⁷] (the operator's jounce intensity).
        r: measurement variance [rad²].
        lag: L [samples] for the fixed-lag methods.
        constraint: Offline-CKS mode, "state" (paper) or "trajectory" (hard FD limits) etc.
        rest_at_end: Offline-CKS ends at rest.
        start_prior: How Offline-KS and Offline-CKS start (:data:`START_PRIORS`): "rest"
            (default: the robot at rest at z_0 one tick before the first sample, as the
            fixed-lag smoothers start) or "loose" (the paper's diag(r, 1e-4, 1e-3, 1e-2),
            which lets the estimate start already moving: a jerk step at the robot).
        fixed_lag_method: "recursion" or "superstate".
        reduced_q: reduced-Q settings for Online-CKS.
        offline_tolerance: Clarabel tolerances for Offline-CKS.
        offline_solver: "drake" (MathematicalProgram + Clarabel, banded IP as the fallback) or
            "banded-ip" (the banded interior point alone), see smoothing.offline.
        ruckig_target, ruckig_synchronization: how the ``ruckig`` peer is fed, see
            smoothing.ruckig_stream (its velocity limit is ``max_velocity``).
    """

    max_acceleration: object = np.inf
    max_jerk: object = np.inf
    max_velocity: object = None
    sigma: object = DEFAULT_SIGMA
    r: object = DEFAULT_R
    lag: int = DEFAULT_LAG
    constraint: str = "state"
    rest_at_end: bool = False
    start_prior: str = "rest"
    fixed_lag_method: str = "recursion"
    reduced_q: ReducedQConfig = field(default_factory=ReducedQConfig)
    offline_tolerance: float = 1e-12
    offline_solver: str = "drake"
    ruckig_target: str = "rest"
    ruckig_synchronization: str = "none"


@dataclass(frozen=True, eq=False)
class SmoothedRecording:
    """One method's result, aligned with the input samples.

    Attributes:
        method: the method name.
        positions: estimate of each input sample [rad], shape (N, num_joints).
        states: full state estimates (N, num_joints, 4), or None for ``original``.
        sent_delay_s: how long after sample k its command leaves the ground station [s].
        sigma: σ per step for Online-CKS (N, num_joints) (σ in effect after step k), else None.
        final_sigma: the σ an Online-CKS operator reached (num_joints,), else None.
        details: method-specific information (solver status for Offline-CKS).
    """

    method: str
    positions: np.ndarray
    states: np.ndarray | None
    sent_delay_s: float
    sigma: np.ndarray | None = None
    final_sigma: np.ndarray | None = None
    details: dict = field(default_factory=dict)


def smooth_recording(
    positions,
    dt_s: float,
    method: str,
    settings: SmoothingSettings = SmoothingSettings(),
    *,
    joint_names=None,
    sigma0=None,
) -> SmoothedRecording:
    """Runs one method on a recording.

    Args:
        positions: the operator's joint samples z_k, shape (N, num_joints) [rad].
        dt_s: sample period [s].
        method: one of METHODS, or an alias (METHOD_ALIASES); ``offline-cks-trajectory``
            replaces ``settings.constraint`` and ``settings.rest_at_end`` (:func:`method_variant`).
        settings: limits and tuning.
        joint_names: labels for error messages and per-name settings.
        sigma0: Online-CKS only: the operator's stored σ (overrides settings.sigma as σ_0).

    Raises:
        ValueError: unknown method or invalid input/settings (naming the field and joint).
        RuntimeError: Offline-CKS did not solve (with the solver's status).
    """
    if not isinstance(method, str) or (method not in METHODS and method not in METHOD_ALIASES):
        raise ValueError(f"method = {method!r} must be one of {METHODS}")
    name, (method, settings) = method_name(method), method_variant(method, settings)
    if settings.start_prior not in START_PRIORS:
        raise ValueError(f"start_prior = {settings.start_prior!r} must be one of {START_PRIORS}")
    z = check_trajectory("positions", positions, joint_names=joint_names, min_samples=2)
    num_joints = z.shape[1]
    dt_s = check_positive_scalar("dt_s", dt_s)
    lag = check_positive_int("lag", settings.lag, minimum=0)
    if lag > max(len(z), DEFAULT_LAG) or lag > MAX_LAG:
        # Past the recording's length every estimate already sees all of it; a longer lag
        # only adds held samples, at a cost that grows like L² per sample.
        raise ValueError(f"lag = {lag} samples is longer than the recording ({len(z)} samples)"
                         if lag <= MAX_LAG else f"lag = {lag} must be at most {MAX_LAG} samples")
    model = JerkModel.make(dt_s, settings.sigma, settings.r, num_joints=num_joints,
                           joint_names=joint_names)
    return _RUNS[method](_Run(method, name, z, dt_s, model, lag, settings, joint_names, sigma0))


class _Run(NamedTuple):
    """What every method's run takes (checked by :func:`smooth_recording`)."""

    method: str                # the computation (:func:`method_variant`'s)
    name: str                  # the name the result carries (the caller's, resolved)
    z: np.ndarray              # (N, J) the samples
    dt_s: float
    model: JerkModel
    lag: int                   # L, samples (the fixed-lag methods)
    settings: SmoothingSettings
    joint_names: object
    sigma0: object             # Online-CKS's σ_0 (scalar or per joint), or None (the model's)


def _run_original(run: _Run) -> SmoothedRecording:
    return SmoothedRecording(run.name, run.z.copy(), None, 0.0)


def _run_kalman_filter(run: _Run) -> SmoothedRecording:
    z, model = run.z, run.model
    result = kalman_filter(z, model, rest_prior(z[0], model))
    states = result.filtered_mean if run.method == "kf" else result.predicted_mean
    return SmoothedRecording(run.name, states[:, :, 0].copy(), states, 0.0)


def _run_offline_ks(run: _Run) -> SmoothedRecording:
    z, model, settings = run.z, run.model, run.settings
    states = rts_smoother(z, model, start_prior(settings.start_prior, z[0], model)).mean
    return SmoothedRecording(run.name, states[:, :, 0].copy(), states, 0.0,
                             details={"start_prior": settings.start_prior})


def _run_offline_cks(run: _Run) -> SmoothedRecording:
    z, model, settings, joint_names = run.z, run.model, run.settings, run.joint_names
    result = solve_offline_cks(
        z, model,
        max_acceleration=settings.max_acceleration,
        max_jerk=settings.max_jerk,
        max_velocity=settings.max_velocity,
        constraint=settings.constraint,
        rest_at_end=settings.rest_at_end,
        prior=start_prior(settings.start_prior, z[0], model),
        joint_names=joint_names,
        tolerance=settings.offline_tolerance,
        solver=settings.offline_solver,
    )
    details = {
        "constraint": settings.constraint,
        "start_prior": settings.start_prior,
        "solver": result.solver_name,
        "solution_results": list(result.solution_results),
        "solve_time_s": result.solve_time_s.tolist(),
        "build_time_s": result.build_time_s.tolist(),
    }
    if not result.is_success:
        raise RuntimeError(
            "Offline-CKS failed: "
            f"{dict(zip(joint_names or range(z.shape[1]), result.solution_results))}; "
            f"violated constraints: {result.infeasible_constraints}"
        )
    return SmoothedRecording(run.name, result.states[:, :, 0].copy(), result.states, 0.0,
                             details=details)


def _run_offline_hard(run: _Run) -> SmoothedRecording:
    # The least deformation the limits allow: the samples moved only where the FD limits
    # force it, from rest at z_0 to rest at the end (smoothing.offline_hard).
    z, dt_s, settings, joint_names = run.z, run.dt_s, run.settings, run.joint_names
    hard = solve_offline_hard(
        z, dt_s, max_acceleration=settings.max_acceleration, max_jerk=settings.max_jerk,
        max_velocity=settings.max_velocity, start_position=z[0], rest_at_end=True,
        joint_names=joint_names)
    if not hard.is_success:
        raise RuntimeError(
            f"offline-hard failed: {dict(zip(joint_names or range(z.shape[1]), hard.status))}")
    states = finite_difference_states(hard.positions, z[0], dt_s)
    return SmoothedRecording(run.name, hard.positions.copy(), states, 0.0,
                             details={"status": list(hard.status),
                                      "iterations": hard.iterations.tolist()})


def _run_ruckig(run: _Run) -> SmoothedRecording:
    settings = run.settings
    states = ruckig_stream(run.z, run.dt_s, max_acceleration=settings.max_acceleration,
                           max_jerk=settings.max_jerk, max_velocity=settings.max_velocity,
                           target=settings.ruckig_target,
                           synchronization=settings.ruckig_synchronization,
                           joint_names=run.joint_names)
    return SmoothedRecording(run.name, states[:, :, 0].copy(), states, 0.0,
                             details={"target": settings.ruckig_target,
                                      "synchronization": settings.ruckig_synchronization})


def _held(run: _Run) -> np.ndarray:
    """The samples and L copies of the last: the operator holds the last pose (the fixed-lag
    methods)."""
    return np.vstack([run.z, np.repeat(run.z[-1:], run.lag, axis=0)])


def _run_bmfls(run: _Run) -> SmoothedRecording:
    lag = run.lag
    outputs = FixedLagSmoother(run.model, lag=lag,
                               method=run.settings.fixed_lag_method).run(_held(run))
    states = outputs[lag:]
    return SmoothedRecording(run.name, states[:, :, 0].copy(), states, lag * run.dt_s,
                             details={"lag": lag})


def _run_online_cks(run: _Run) -> SmoothedRecording:
    z, dt_s, lag, settings = run.z, run.dt_s, run.lag, run.settings
    online = OnlineCks(
        run.model,
        max_acceleration=settings.max_acceleration,
        max_jerk=settings.max_jerk,
        lag=lag,
        config=settings.reduced_q,
        method=settings.fixed_lag_method,
        joint_names=run.joint_names,
    )
    sigma0 = run.sigma0
    if sigma0 is not None:
        sigma0 = as_per_joint("sigma0", sigma0, run.z.shape[1], run.joint_names)
    result = online.run(_held(run), sigma0=sigma0)
    states = result.outputs[lag:]
    details = {"lag": lag, "variant": settings.reduced_q.variant,
               "step_rule": settings.reduced_q.step_rule,
               "cycles_triggered": result.triggered.sum(axis=0).tolist()}
    if run.method == "online-hard":
        # The estimate each tick leaves the ground station through the hard limiter: the sent
        # sequence (after the robot's rest at z_0) meets every FD limit exactly.
        positions = online_hard_run(
            states[:, :, 0], dt_s, max_acceleration=settings.max_acceleration,
            max_jerk=settings.max_jerk, max_velocity=settings.max_velocity, q_start=z[0],
            joint_names=run.joint_names)
        states = finite_difference_states(positions, z[0], dt_s)
        details["limited_max_abs_rad"] = np.abs(positions - result.outputs[lag:, :, 0]).max(
            axis=0).tolist()
    return SmoothedRecording(
        run.name, states[:, :, 0].copy(), states, lag * dt_s,
        sigma=result.sigma[lag:], final_sigma=result.final_state.sigma.copy(), details=details)


_RUNS = {"original": _run_original, "kf": _run_kalman_filter,
         "kf-predictor": _run_kalman_filter, "offline-ks": _run_offline_ks,
         "offline-cks": _run_offline_cks, "offline-hard": _run_offline_hard,
         "ruckig": _run_ruckig, "bmfls": _run_bmfls, "online-cks": _run_online_cks,
         "online-hard": _run_online_cks}
"""Each computation :func:`method_variant` names (``offline-cks-trajectory`` is
``offline-cks`` with other settings) and the function that runs it."""


def finite_difference_states(positions, rest, dt_s: float) -> np.ndarray:
    """[p, FD velocity, FD acceleration, FD jerk] of a sent sequence after rest at ``rest``.

    Args:
        positions: p_k, (N, J).
        rest: The pose held before p_0 (p_{−1} = p_{−2} = p_{−3}), (J,).
        dt_s: Δt.

    Returns:
        (N, J, 4): backward differences (p_k − p_{k−1})/Δt etc., the history included.
    """
    positions = np.asarray(positions, dtype=float)
    history = np.vstack([np.repeat(np.asarray(rest, dtype=float)[None, :], 3, axis=0),
                         positions])
    states = np.empty(positions.shape + (4,))
    states[:, :, 0] = positions
    difference = history
    for order in (1, 2, 3):
        difference = np.diff(difference, axis=0) / dt_s
        states[:, :, order] = difference[3 - order:]
    return states
