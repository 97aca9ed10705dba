"""The online smoother of the ground station: BMFLS with reduced-Q σ adaptation at 4 Hz.

Consumes the FIFO's newest sample z_k at every uplink tick and emits x̂_{k−L|k}, the smoothed
estimate of the sample leaving the FIFO at that tick, so the smoothed command and the raw
delayed command are the same instant of the operator's motion (docs/method.md §5.1: the FIFO is the
smoother window; total added latency L·Δt). The numerics are the core's
:class:`~telesmooth.smoothing.reduced_q.OnlineCks` (docs/method.md §3, §4), one tick the pure step
:func:`telesmooth.smoothing.smoother_step.smoother_step`; this system only keeps the step's state
in the Context and wires ports.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import LeafSystem, ValueProducer

from telesmooth.arms.joint_vectors import as_per_joint, check_joint_vector
from telesmooth.safety.limiter import limiter_params
from telesmooth.smoothing.kalman import START_PRIORS
from telesmooth.smoothing.methods import CHAIN_METHODS, METHOD_ALIASES, method_name
from telesmooth.smoothing.model import (
    DEFAULT_LAG,
    DEFAULT_R,
    DEFAULT_SIGMA,
    MAX_LAG,
    STATE_SIZE,
    JerkModel,
)
from telesmooth.smoothing.reduced_q import OnlineCks, ReducedQConfig
from telesmooth.smoothing.smoother_step import (
    SmootherStepParams,
    SmootherStepStateVector,
    smoother_initial_state,
    smoother_step,
)
from telesmooth.systems.codec_state import CodecState
from telesmooth.systems.timing import check_period

__all__ = ["ONLINE_SMOOTHER_METHODS", "ReducedQSmoother", "ReducedQSmootherConfig"]

ONLINE_SMOOTHER_METHODS = CHAIN_METHODS + tuple(
    alias for alias, method in METHOD_ALIASES.items() if method in CHAIN_METHODS)
"""The names :attr:`ReducedQSmootherConfig.method` takes: the registry's
:data:`~telesmooth.smoothing.methods.CHAIN_METHODS` and their aliases (``pass-through`` is
``original``)."""


@dataclasses.dataclass(frozen=True)
class ReducedQSmootherConfig:
    """Settings of the online smoother.

    Attributes:
        method: ``"online-cks"`` (BMFLS + reduced-Q, default), ``"bmfls"`` (fixed σ),
            ``"pass-through"`` (also ``"original"``, its name in the method registry: no
            smoothing, the raw z_{k−L}, with the same latency), or
            ``"online-hard"`` (Online-CKS through the hard limiter of
            :mod:`telesmooth.smoothing.online_hard`: the FD acceleration and jerk of the sent
            commands never exceed the limits, which must then be finite).
        period_s: Δt, the uplink period, s.
        lag: L, samples of fixed lag (= the FIFO length); 3 for 0.75 s at 4 Hz.
        sigma: σ_0, intensity of the white jounce noise (the model's process noise) per
            joint (scalar or per joint), rad²/s⁷.
        r: Measurement noise variance of the hand, rad².
        max_acceleration_rad_per_s2: a_max per joint (scalar or per joint); online-cks only.
        max_jerk_rad_per_s3: j_max per joint; online-cks only.
        reduced_q: The σ adaptation settings (variant A/B1/B2, step rule, trigger, σ_min).
        fixed_lag_method: ``"recursion"`` (exact O(L) update, default) or ``"superstate"``.
        start_prior: How the offline smoothers that ``compare``, ``experiment`` and the
            offline mode run on the same settings start: ``"rest"`` (default: the robot at
            rest at its start pose one tick before the first sample, as this smoother
            starts) or ``"loose"`` (the paper's prior, which lets the estimate start moving).
    """

    method: str = "online-cks"
    period_s: float = 0.25
    lag: int = DEFAULT_LAG
    sigma: float | tuple = DEFAULT_SIGMA
    r: float = DEFAULT_R
    max_acceleration_rad_per_s2: float | tuple = 0.05
    max_jerk_rad_per_s3: float | tuple = 0.1
    reduced_q: ReducedQConfig = dataclasses.field(default_factory=ReducedQConfig)
    fixed_lag_method: str = "recursion"
    start_prior: str = "rest"

    def __post_init__(self) -> None:
        if self.start_prior not in START_PRIORS:
            raise ValueError(f"start_prior = {self.start_prior!r} must be one of {START_PRIORS}")
        if not isinstance(self.method, str) or self.method not in ONLINE_SMOOTHER_METHODS:
            raise ValueError(
                f"ReducedQSmootherConfig.method = {self.method!r} must be one of "
                f"{ONLINE_SMOOTHER_METHODS}"
            )
        check_period("ReducedQSmootherConfig.period_s", self.period_s)
        if isinstance(self.lag, bool) or not isinstance(self.lag, (int, np.integer)) or (
                self.lag < 0) or self.lag > MAX_LAG:
            raise ValueError(
                f"ReducedQSmootherConfig.lag = {self.lag!r} must be an integer in 0..{MAX_LAG}"
            )
        for name, allow_inf in (("sigma", False), ("r", False),
                                ("max_acceleration_rad_per_s2", True),
                                ("max_jerk_rad_per_s3", True)):
            _check_positive_values(name, getattr(self, name), allow_inf=allow_inf)


def _check_positive_values(name, value, *, allow_inf):
    """A scalar must be positive here; per-joint sequences are checked with the joint names
    when the smoother (or a Scenario) knows them."""
    if np.ndim(value) != 0:
        return
    for item in (value,):
        label = name
        try:
            number = float(item)
        except (TypeError, ValueError):
            raise ValueError(f"{label} = {item!r} must be a number") from None
        if isinstance(item, bool) or np.isnan(number) or number <= 0.0 or (
                np.isinf(number) and not allow_inf):
            raise ValueError(f"{label} = {number!r} must be positive"
                             + (" (inf = no limit)" if allow_inf else " and finite"))


class ReducedQSmoother(LeafSystem):
    r"""Fixed-lag smoother (BMFLS) with reduced-Q adaptation, one step per uplink tick.

    .. pydrake_system::

        name: ReducedQSmoother
        input_ports:
        - q_sample
        - reset (optional)
        output_ports:
        - q_smoothed
        - state_smoothed
        - sigma
        - triggered

    Ports (J = num_joints):

    - ``q_sample``: z_k, the joint sample entering the FIFO at this tick (the FIFO's
      ``q_newest``), rad, (J,).
    - ``reset``: 1 when the FIFO was refilled at this tick (collision hold), (1,);
      unconnected = never.
    - ``q_smoothed``: position of x̂_{k−L|k}, rad, (J,): the command to send.
    - ``state_smoothed``: x̂_{k−L|k} as [q (J), q̇ (J), q̈ (J), q⃛ (J)], rad, rad/s, rad/s²,
      rad/s³, (4J,).
    - ``sigma``: σ per joint in effect for the next tick, (J,) (the paper's σ_k; reduced-Q
      lowers it when the command breaks a_max or j_max; never raised).
    - ``triggered``: 1 per joint if this tick's command broke a limit, (J,).

    State: the pure step's :class:`~telesmooth.smoothing.smoother_step.SmootherStepState` (the
    Online-CKS record: superstate means and covariances of the L+1 blocks, σ, the last three
    sent positions, the B2 checkpoints; the raw window of the last L+1 samples, for
    ``pass-through``; the hard limiter's state for ``online-hard``) packed into one discrete
    vector. Updated at t_k = k·period_s.

    Equations per tick (docs/method.md §3.2, §4.2), with X the state after tick k−1:

        if reset_k:  X ← rest state at z_k (blocks [z_k, 0, 0, 0], P = 0), σ kept
        (X', σ', x̂_{k−L|k}, triggered) = OnlineCks.step(X, z_k)
        bmfls: a_max = j_max = ∞ (σ never changes);  pass-through: output [z_{k−L}, 0, 0, 0]

    Like :class:`~telesmooth.systems.delay_fifo.DelayFifo`, the outputs are those of a tick
    taken at the current time (computed from the state and the current input), so the uplink
    sampling them at t_k sends x̂_{k−L|k} at t_k. At t = 0 the smoother is at rest at
    ``initial_position_rad``; the first L outputs estimate samples before the start (that
    pose, at rest).
    """

    def __init__(self, config: ReducedQSmootherConfig = ReducedQSmootherConfig(), *,
                 joint_names, initial_position_rad=None, sigma0=None):
        super().__init__()
        joint_names = tuple(str(name) for name in joint_names)
        n = len(joint_names)
        if n == 0:
            raise ValueError("joint_names must name at least one joint")
        self._config = config
        self._joint_names = joint_names
        sigma = as_per_joint("sigma", config.sigma, n, joint_names)
        model = JerkModel.make(config.period_s, sigma, config.r, num_joints=n,
                               joint_names=joint_names)
        limits_off = config.method not in ("online-cks", "online-hard")
        self._online = OnlineCks(
            model,
            max_acceleration=np.inf if limits_off else config.max_acceleration_rad_per_s2,
            max_jerk=np.inf if limits_off else config.max_jerk_rad_per_s3,
            lag=config.lag,
            config=config.reduced_q,
            method=config.fixed_lag_method,
            joint_names=joint_names,
        )
        q0 = np.zeros(n) if initial_position_rad is None else check_joint_vector(
            "initial_position_rad", initial_position_rad, joint_names)
        # online-hard: the limits (immutable) in the params, the limiter's state in the step's.
        limiter = None if config.method != "online-hard" else limiter_params(
            dt_s=config.period_s, max_acceleration=config.max_acceleration_rad_per_s2,
            max_jerk=config.max_jerk_rad_per_s3, joint_names=joint_names)
        self._params = SmootherStepParams(
            online=self._online, pass_through=method_name(config.method) == "original",
            limiter=limiter, period_s=config.period_s)
        initial = smoother_initial_state(self._params, q0, sigma0)

        self._q_sample_input = self.DeclareVectorInputPort("q_sample", n)
        self._reset_input = self.DeclareVectorInputPort("reset", 1)
        self._state = CodecState(self, initial, SmootherStepStateVector(self._params, initial))
        self._tick_cache = self.DeclareCacheEntry(
            "tick", ValueProducer(allocate=lambda: AbstractValue.Make(object()),
                                  calc=lambda c, value: value.set_value(self._compute_tick(c))))
        self.DeclarePeriodicDiscreteUpdateEvent(config.period_s, 0.0, self._update_smoother)
        # A forced update runs the same tick on demand (CalcForcedDiscreteVariableUpdate).
        self.DeclareForcedDiscreteUpdateEvent(self._update_smoother)

        self._q_smoothed_output = self.DeclareVectorOutputPort(
            "q_smoothed", n, lambda c, out: out.SetFromVector(self._tick(c).output[:, 0]))
        self._state_smoothed_output = self.DeclareVectorOutputPort(
            "state_smoothed", STATE_SIZE * n,
            lambda c, out: out.SetFromVector(self._tick(c).output.T.ravel()))
        self._sigma_output = self.DeclareVectorOutputPort(
            "sigma", n, lambda c, out: out.SetFromVector(self._tick(c).state.online.sigma))
        self._triggered_output = self.DeclareVectorOutputPort(
            "triggered", n,
            lambda c, out: out.SetFromVector(self._tick(c).triggered.astype(float)))

    # -- accessors ------------------------------------------------------------------------

    @property
    def config(self) -> ReducedQSmootherConfig:
        return self._config

    @property
    def joint_names(self) -> tuple[str, ...]:
        return self._joint_names

    @property
    def online(self) -> OnlineCks:
        """The core smoother this system steps (for cross-checks)."""
        return self._online

    def get_q_sample_input_port(self):
        return self._q_sample_input

    def get_reset_input_port(self):
        return self._reset_input

    def get_q_smoothed_output_port(self):
        return self._q_smoothed_output

    def get_state_smoothed_output_port(self):
        return self._state_smoothed_output

    def get_sigma_output_port(self):
        return self._sigma_output

    def get_triggered_output_port(self):
        return self._triggered_output

    # -- the tick -------------------------------------------------------------------------

    def _tick(self, context):
        """The tick at this time, computed once per context change (shared by every output
        port and the update)."""
        return self._tick_cache.Eval(context)

    def _compute_tick(self, context):
        """The tick at this time (:func:`smoother_step` on the state and the inputs)."""
        reset = self._reset_input.HasValue(context) and self._reset_input.Eval(context)[0] > 0.5
        return smoother_step(self._params, self._state.get(context),
                             self._q_sample_input.Eval(context), reset)

    def _update_smoother(self, context, discrete_state):
        self._state.store(discrete_state, self._tick(context).state)
