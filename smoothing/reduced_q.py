"""Online-CKS: the fixed-lag smoother with reduced-Q adaptation of σ (docs/method.md §4).

Each 4 Hz cycle, per joint:

    (X', P') = BMFLS_step(X, P, z_k, σ)
    viol := |x̂_{k−L|k}[2]| > a_max  or  |x̂_{k−L|k}[3]| > j_max     (trigger "state", default)
    A  (default): if viol: σ ← dec(σ), used from cycle k+1 on
    B1: while viol and σ > σ_min and n < n_max: σ ← dec(σ); redo this cycle's step
    B2: as B1 but re-filter the whole window (the last L+1 steps) from the stored checkpoint

    dec(σ) = max(ρ σ, σ_min)     multiplicative step (default, ρ = 0.8)
    dec(σ) = max(σ − Δσ, σ_min)  additive step (the paper's literal Δσ; ineffective,
                                 docs/method.md §4)

σ never increases within an operation. The σ reached is stored per operator and joint and is
the next operation's σ_0 (:mod:`telesmooth.smoothing.sigma_store` keeps it per operator).

The alternative trigger ``"fd"`` uses the finite-difference acceleration and jerk of the last
four sent positions instead of the output block's states.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from telesmooth.arms.joint_vectors import (
    as_per_joint,
    check_positive_int,
    check_positive_scalar,
    check_trajectory,
)
from telesmooth.compiled import readonly_copy
from telesmooth.safety.finite_differences import fd_acceleration, fd_jerk
from telesmooth.smoothing.fixed_lag import FixedLagSmoother, FixedLagState, frozen_instance
from telesmooth.smoothing.model import SCALED_TRANSITION, UNIT_PROCESS_COVARIANCE, JerkModel

REDUCED_Q_VARIANTS = ("A", "B1", "B2")
SIGMA_STEP_RULES = ("multiplicative", "additive")
VIOLATION_TRIGGERS = ("state", "fd")
DEFAULT_SIGMA_MIN_RATIO = 2.5e-4
"""σ_min = 2.5e-4 σ_0 by default (1e-7 for the default σ_0 = 4e-4, docs/method.md §4, §8)."""


@dataclass(frozen=True)
class ReducedQConfig:
    """How σ is reduced when the smoothed output breaks the limits (docs/method.md §4).

    Attributes:
        variant: "A" (one step per cycle, default), "B1" or "B2" (retries within the cycle).
        step_rule: "multiplicative" (σ ← ρσ, default) or "additive" (σ ← σ − Δσ).
        rho: multiplicative factor ρ in (0, 1).
        delta_sigma: additive step Δσ [rad²/s⁷]; None means σ_0 / 40.
        sigma_min: lower bound σ_min [rad²/s⁷]; None means 2.5e-4 σ_0.
        trigger: "state" (output block's acc/jerk states, default) or "fd" (finite
            differences of the last four sent positions).
        max_retries: n_max for the B variants.
    """

    variant: str = "A"
    step_rule: str = "multiplicative"
    rho: float = 0.8
    delta_sigma: float | None = None
    sigma_min: float | None = None
    trigger: str = "state"
    max_retries: int = 50

    def __post_init__(self):
        for name, value, allowed in (
            ("variant", self.variant, REDUCED_Q_VARIANTS),
            ("step_rule", self.step_rule, SIGMA_STEP_RULES),
            ("trigger", self.trigger, VIOLATION_TRIGGERS),
        ):
            if value not in allowed:
                raise ValueError(f"{name} = {value!r} must be one of {allowed}")
        if (isinstance(self.rho, bool) or not isinstance(self.rho, (int, float))
                or not (0.0 < float(self.rho) < 1.0)):
            raise ValueError(f"rho = {self.rho!r} must be in (0, 1)")
        if self.delta_sigma is not None:
            check_positive_scalar("delta_sigma", self.delta_sigma)
        if self.sigma_min is not None:
            check_positive_scalar("sigma_min", self.sigma_min)
        check_positive_int("max_retries", self.max_retries, minimum=0)


def decrease_sigma(sigma, sigma_min, config: ReducedQConfig, delta_sigma=None) -> np.ndarray:
    """dec(σ): one reduction step, never below σ_min and never an increase."""
    sigma = np.asarray(sigma, dtype=float)
    if config.step_rule == "multiplicative":
        reduced = config.rho * sigma
    else:
        reduced = sigma - delta_sigma
    return np.minimum(sigma, np.maximum(reduced, sigma_min))


@dataclass(frozen=True, eq=False)
class OnlineCksState:
    """Immutable Online-CKS state.

    Attributes:
        smoother: the fixed-lag smoother state after the last cycle.
        sigma: σ per joint to be used in the next cycle, shape (num_joints,).
        sent_positions: the last three sent positions, oldest first, shape (3, num_joints).
        window: for variant B2, (state before the step, z) of the last L+1 cycles.
    """

    smoother: FixedLagState
    sigma: np.ndarray
    sent_positions: np.ndarray
    window: tuple = field(default=())


@dataclass(frozen=True, eq=False)
class OnlineCksRun:
    """A whole recording streamed through Online-CKS.

    Attributes:
        outputs: x̂_{k−L|k} per cycle, shape (N, num_joints, 4), physical units.
        sigma: σ in effect after cycle k (used from k+1 on), shape (N, num_joints).
        triggered: whether cycle k's output broke a limit, shape (N, num_joints).
        final_state: the state after the last cycle (its σ is the operator's next σ_0).
    """

    outputs: np.ndarray
    sigma: np.ndarray
    triggered: np.ndarray
    final_state: OnlineCksState


class OnlineCks:
    """BMFLS + reduced-Q for all joints at once.

    Args:
        model: jerk model; ``model.sigma`` is σ_0 unless ``initial_state`` gets another.
        max_acceleration: a_max per joint [rad/s²] (scalar or sequence).
        max_jerk: j_max per joint [rad/s³].
        lag: L in samples.
        config: reduced-Q settings.
        method: fixed-lag implementation, "recursion" or "superstate".
        joint_names: for error messages and per-name limits.
    """

    def __init__(
        self,
        model: JerkModel,
        *,
        max_acceleration,
        max_jerk,
        lag: int = 3,
        config: ReducedQConfig = ReducedQConfig(),
        method: str = "recursion",
        joint_names=None,
    ):
        self.model = model
        self.config = config
        self.smoother = FixedLagSmoother(model, lag=lag, method=method)
        n = model.num_joints
        self.max_acceleration = as_per_joint(
            "max_acceleration_rad_per_s2", max_acceleration, n, joint_names, allow_inf=True
        )
        self.max_jerk = as_per_joint(
            "max_jerk_rad_per_s3", max_jerk, n, joint_names, allow_inf=True
        )
        self.sigma_min = (
            np.full(n, config.sigma_min)
            if config.sigma_min is not None
            else DEFAULT_SIGMA_MIN_RATIO * model.sigma
        )
        self.delta_sigma = (
            np.full(n, config.delta_sigma)
            if config.delta_sigma is not None
            else model.sigma / 40.0
        )
        # The default settings (variant A, the recursion form) run compiled
        # (smoothing/fixed_lag_kernel.py): compiled or loaded from numba's cache here, once
        # per process, not in the first cycle.
        self._compiled = None
        if config.variant == "A" and method == "recursion":
            from telesmooth.smoothing import fixed_lag_kernel as kernel

            dt = model.dt_s
            constants = [model.r, SCALED_TRANSITION, UNIT_PROCESS_COVARIANCE, model.scaling,
                         self.max_acceleration, self.max_jerk, self.sigma_min,
                         self.delta_sigma]
            self._compiled = (kernel.online_cks_tick, tuple(map(readonly_copy, constants)), (
                dt**7, dt**2, dt**3, float(config.rho), config.step_rule == "multiplicative",
                kernel.TRIGGER_STATE if config.trigger == "state" else kernel.TRIGGER_FD))

    @property
    def lag(self) -> int:
        return self.smoother.lag

    def initial_state(self, start_position, sigma0=None) -> OnlineCksState:
        """Rest start at ``start_position``; ``sigma0`` (e.g. a stored operator σ) overrides."""
        sigma = (
            self.model.sigma.copy()
            if sigma0 is None
            else as_per_joint("sigma0", sigma0, self.model.num_joints)
        )
        q0 = np.asarray(start_position, dtype=float)
        return OnlineCksState(
            smoother=self.smoother.initial_state(q0),
            sigma=sigma,
            sent_positions=np.tile(q0, (3, 1)),
        )

    def _violation(self, output, sent_positions) -> np.ndarray:
        """Per joint: does this cycle's command break a limit (docs/method.md §4 trigger)?"""
        if self.config.trigger == "state":
            acc, jerk = output[:, 2], output[:, 3]
        else:
            dt = self.model.dt_s
            p = np.vstack([sent_positions, output[None, :, 0]])
            acc = fd_acceleration(p[1], p[2], p[3], dt)
            jerk = fd_jerk(p[0], p[1], p[2], p[3], dt)
        return (np.abs(acc) > self.max_acceleration) | (np.abs(jerk) > self.max_jerk)

    def _decrease(self, sigma, mask):
        reduced = decrease_sigma(sigma, self.sigma_min, self.config, self.delta_sigma)
        return np.where(mask, reduced, sigma)

    def step(self, state: OnlineCksState, measurement):
        """One 4 Hz cycle. Returns (new state, x̂_{k−L|k} (num_joints, 4), triggered (J,))."""
        z = np.asarray(measurement, dtype=float)
        if self._compiled is not None:
            done = self._step_compiled(state, z)
            if done is not None:
                return done
        sigma = state.sigma
        new_smoother = self.smoother.step(state.smoother, z, sigma)
        output = self.smoother.output(new_smoother)
        triggered = self._violation(output, state.sent_positions)
        window = state.window
        if self.config.variant == "B2":
            window = (window + ((state.smoother, z),))[-(self.lag + 1):]
        if self.config.variant == "A":
            sigma = self._decrease(sigma, triggered)
        else:
            violating = triggered
            retries = 0
            while retries < self.config.max_retries:
                can_reduce = violating & (sigma > self.sigma_min)
                if not can_reduce.any():
                    break
                sigma = self._decrease(sigma, can_reduce)
                retries += 1
                if self.config.variant == "B1":
                    new_smoother = self.smoother.step(state.smoother, z, sigma)
                else:
                    new_smoother = window[0][0]
                    for _, z_window in window:
                        new_smoother = self.smoother.step(new_smoother, z_window, sigma)
                output = self.smoother.output(new_smoother)
                violating = self._violation(output, state.sent_positions)
        sent = np.vstack([state.sent_positions[1:], output[None, :, 0]])
        new_state = OnlineCksState(
            smoother=new_smoother, sigma=sigma, sent_positions=sent, window=window
        )
        return new_state, output, triggered

    def _step_compiled(self, state: OnlineCksState, z: np.ndarray):
        """:meth:`step` by the compiled kernel (variant A, recursion form), or None when the
        NumPy form must take the cycle (a non-finite or misshapen measurement or state: it
        raises the error that names them)."""
        tick, constants, scalars = self._compiled
        smoother = state.smoother
        means, cross = smoother.blocks_scaled, smoother.covariance
        n = means.shape[0]
        if means.shape != self.smoother._state_shape:
            return None         # another smoother's state: the NumPy form reports it
        new_means, new_cross = np.empty(means.shape), np.empty(cross.shape)
        output, triggered = np.empty((n, 4)), np.empty(n, dtype=bool)
        sigma, sent = np.empty(n), np.empty((3, n))
        r, phi, unit_q, scaling, a_max, j_max, sigma_min, delta_sigma = constants
        try:
            done = tick(means, cross, z, state.sigma, r, phi, unit_q, scaling, a_max, j_max,
                        sigma_min, delta_sigma, state.sent_positions, *scalars, new_means,
                        new_cross, output, triggered, sigma, sent)
        except TypeError:       # arrays of other dimensions or types than the kernel's
            return None
        if not done:
            return None
        new_state = frozen_instance(
            OnlineCksState, smoother=frozen_instance(
                FixedLagState, blocks_scaled=new_means, covariance=new_cross,
                steps=smoother.steps + 1),
            sigma=sigma, sent_positions=sent, window=state.window)
        return new_state, output, triggered

    def run(self, measurements, *, start_position=None, sigma0=None) -> OnlineCksRun:
        """Streams a recording (N, num_joints); row k of the outputs estimates sample k − L."""
        z = check_trajectory("measurements", measurements, num_joints=self.model.num_joints)
        state = self.initial_state(z[0] if start_position is None else start_position, sigma0)
        num_samples, num_joints = z.shape
        outputs = np.empty((num_samples, num_joints, 4))
        sigmas = np.empty((num_samples, num_joints))
        triggered = np.empty((num_samples, num_joints), dtype=bool)
        for k in range(num_samples):
            state, outputs[k], triggered[k] = self.step(state, z[k])
            sigmas[k] = state.sigma
        return OnlineCksRun(outputs=outputs, sigma=sigmas, triggered=triggered, final_state=state)
