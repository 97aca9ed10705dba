"""Biswas–Mahalanabis fixed-lag smoother (BMFLS), docs/method.md §3, with an exact fast recursion.

The superstate ``X_k = [x_k; x_{k−1}; …; x_{k−L}]`` holds the FIFO contents as states. A Kalman
filter on (Φ_BM, H_BM, Q_BM, r) is the whole algorithm; after step k, block i of the
a-posteriori superstate is x̂_{k−i|k}, and block L, x̂_{k−L|k}, is the command sent to the robot.
It equals the RTS estimate of x_{k−L} from z_0 … z_k (tested).

Two exact implementations share one interface (``method=``):

``"superstate"`` (docs/method.md §3.1)
    The superstate Kalman filter. Φ_BM is a shift, so the prediction
    ``Φ_BM P Φ_BMᵀ + Q_BM`` is assembled block-wise in O((n(L+1))²) instead of the dense
    O((n(L+1))³) product; the update is a rank-one downdate. Mathematically identical to the
    dense form (tested against it).

``"recursion"`` (docs/method.md §3.2, R1 in a-posteriori form; default)
    Keeps the smoothed blocks x̂_{k−i|k} and the cross covariances
    ``C_k^{(i)} = E[e_{k−i|k} e_{k|k}ᵀ]`` (C^{(0)} = P_{k|k}). One step with measurement z:

        Σ^{(0)} = Φ C^{(0)} Φᵀ + Q_k,      Σ^{(i)} = C^{(i−1)} Φᵀ          (i = 1 … L)
        x̂_{k|k−1} = Φ x̂_{k−1|k−1};         x̂_{k−i|k−1} = previous block i−1
        S = Σ^{(0)}_{00} + r,   ν = z − x̂_{k|k−1}[0]
        x̂_{k−i|k} = x̂_{k−i|k−1} + Σ^{(i)} Hᵀ ν / S
        C^{(i)} ← Σ^{(i)} − Σ^{(i)} Hᵀ H Σ^{(0)} / S

    This is Simon's §9.3 fixed-lag smoother with the cross covariances propagated in time
    (Σ_{k+1}^{(i+1)} = Σ_k^{(i)} (I − K_k H)ᵀ Φᵀ), O(L n³) per step with a handful of
    vectorised operations. Time-varying σ_k is exact because each cross covariance carries the
    gains of the steps it has lived through.

Start-up (docs/method.md §3.1, I1): the robot rests at q_0 before operation; every block is
[q_0, 0, 0, 0] with covariance (1·1ᵀ) ⊗ P_rest (P_rest = 0 by default), i.e. the FIFO starts
pre-filled with the rest pose and the first L outputs are the rest pose.

All arrays are vectorised over joints; states are kept in the scaled form internally.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from telesmooth.arms.joint_vectors import (
    check_finite_per_joint,
    check_positive_int,
    check_trajectory,
)
from telesmooth.compiled import readonly_copy
from telesmooth.smoothing.model import (
    MAX_LAG,
    SCALED_TRANSITION,
    STATE_SIZE,
    UNIT_PROCESS_COVARIANCE,
    JerkModel,
)

FIXED_LAG_FORMS = ("recursion", "superstate")
"""The two forms of the fixed-lag smoother (its ``method`` argument); the fixed-lag *smoothing
methods* are :data:`telesmooth.smoothing.methods.FIXED_LAG_METHODS`."""


@dataclass(frozen=True, eq=False)
class FixedLagState:
    """Immutable smoother state after ``steps`` measurements.

    Attributes:
        blocks_scaled: x̃_{k−i|k} for i = 0 … L, shape (num_joints, L+1, 4), scaled units.
        covariance: method-specific covariance data (scaled units): the superstate covariance
            (num_joints, 4(L+1), 4(L+1)) or the cross covariances (num_joints, L+1, 4, 4).
        steps: number of measurements absorbed since the rest start.
    """

    blocks_scaled: np.ndarray
    covariance: np.ndarray
    steps: int


def frozen_instance(cls, **fields):
    """An instance of the frozen dataclass ``cls`` from all its ``fields``, as ``cls(**fields)``
    builds it, for the per-tick paths: a frozen dataclass's ``__init__`` sets each field by
    ``object.__setattr__``, a microsecond per state at 4 Hz rates that are otherwise a few µs.
    Only for classes without ``__post_init__`` or defaults left out (tests check both)."""
    instance = object.__new__(cls)
    instance.__dict__.update(fields)
    return instance


class FixedLagSmoother:
    """BMFLS for all joints at once; immutable, steps are pure functions of the state.

    Args:
        model: jerk model (Δt, σ_0, r per joint). σ can be overridden per step.
        lag: L, the fixed lag in samples (L = 3 for 0.75 s at 4 Hz).
        method: ``"recursion"`` (default) or ``"superstate"``; both are exact.
        rest_covariance: P_rest (4, 4) of the rest start, physical units; default 0.
    """

    def __init__(
        self,
        model: JerkModel,
        *,
        lag: int = 3,
        method: str = "recursion",
        rest_covariance=None,
    ):
        if method not in FIXED_LAG_FORMS:
            raise ValueError(f"method = {method!r} must be one of {FIXED_LAG_FORMS}")
        self.model = model
        self.lag = check_positive_int("lag", lag, minimum=0)
        if self.lag > MAX_LAG:
            raise ValueError(f"lag = {self.lag} must be at most {MAX_LAG} samples")
        self.method = method
        if rest_covariance is None:
            rest_covariance = np.zeros((STATE_SIZE, STATE_SIZE))
        rest_covariance = np.asarray(rest_covariance, dtype=float)
        if rest_covariance.shape != (STATE_SIZE, STATE_SIZE) or not np.all(
            np.isfinite(rest_covariance)
        ):
            raise ValueError(
                f"rest_covariance must be a finite (4, 4) matrix; got {rest_covariance!r}"
            )
        self._rest_cov_scaled = model.cov_to_scaled(rest_covariance)
        self._default_q_scaled = model.scaled_process_covariance()  # Q̃(σ_0), reused each tick
        # The recursion form runs compiled (smoothing/fixed_lag_kernel.py, the same arithmetic
        # in a fixed summation order): compiled or loaded from numba's cache here, once per
        # process, not in the first step.
        self._compiled = None
        if method == "recursion":
            from telesmooth.smoothing import fixed_lag_kernel

            constants = tuple(readonly_copy(c) for c in (
                model.sigma, model.r, SCALED_TRANSITION, UNIT_PROCESS_COVARIANCE))
            self._compiled = (fixed_lag_kernel, constants, model.dt_s**7)
        self._state_shape = (model.num_joints, self.lag + 1, STATE_SIZE)

    @property
    def num_blocks(self) -> int:
        return self.lag + 1

    def initial_state(self, start_position) -> FixedLagState:
        """Rest start (I1) at ``start_position`` (num_joints,) [rad]."""
        q0 = check_finite_per_joint("start_position", start_position, self.model.num_joints)
        num_joints, blocks = self.model.num_joints, self.num_blocks
        means = np.zeros((num_joints, blocks, STATE_SIZE))
        means[:, :, 0] = q0[:, None]
        if self.method == "superstate":
            cov = np.kron(np.ones((blocks, blocks)), self._rest_cov_scaled)
            cov = np.broadcast_to(cov, (num_joints,) + cov.shape).copy()
        else:
            cov = np.broadcast_to(
                self._rest_cov_scaled, (num_joints, blocks, STATE_SIZE, STATE_SIZE)
            ).copy()
        return FixedLagState(blocks_scaled=means, covariance=cov, steps=0)

    def step(self, state: FixedLagState, measurement, sigma=None) -> FixedLagState:
        """Absorbs z_k (num_joints,) [rad] with σ_k (num_joints,) for the transition into k."""
        if self._compiled is not None:
            new_state = self._step_compiled(state, measurement, sigma)
            if new_state is not None:
                return new_state
        z = check_finite_per_joint("measurement", measurement, self.model.num_joints)
        q_scaled = (self._default_q_scaled if sigma is None
                    else self.model.scaled_process_covariance(sigma))
        if self.method == "superstate":
            return self._step_superstate(state, z, q_scaled)
        return self._step_recursion(state, z, q_scaled)

    def output(self, state: FixedLagState) -> np.ndarray:
        """x̂_{k−L|k}, the command block, shape (num_joints, 4), physical units."""
        return self.model.from_scaled(state.blocks_scaled[:, self.lag])

    def blocks(self, state: FixedLagState) -> np.ndarray:
        """All blocks x̂_{k−i|k}, shape (num_joints, L+1, 4), physical units."""
        return self.model.from_scaled(state.blocks_scaled)

    def run(self, measurements, *, start_position=None, sigma_schedule=None) -> np.ndarray:
        """Streams a whole recording; returns x̂_{k−L|k} for every step k, shape (N, J, 4).

        Row k is the estimate of sample k − L (the rest pose for k < L).
        ``sigma_schedule[k]`` (N, J) is the σ for step k (default: model σ).
        """
        z = check_trajectory(
            "measurements", measurements, num_joints=self.model.num_joints
        )
        start = z[0] if start_position is None else start_position
        state = self.initial_state(start)
        outputs = np.empty((z.shape[0], self.model.num_joints, STATE_SIZE))
        for k in range(z.shape[0]):
            sigma = None if sigma_schedule is None else sigma_schedule[k]
            state = self.step(state, z[k], sigma)
            outputs[k] = self.output(state)
        return outputs

    def _step_compiled(self, state, measurement, sigma):
        """:meth:`step` of the recursion form by the compiled kernel, or None when the NumPy
        form must take it (a non-finite or misshapen measurement, σ or state: it raises the
        error that names them)."""
        kernel, (default_sigma, r, phi, unit_q), dt7 = self._compiled
        means, cross = state.blocks_scaled, state.covariance
        if means.shape != self._state_shape:
            return None
        new_means, new_cross = np.empty(means.shape), np.empty(cross.shape)
        try:
            done = kernel.recursion_step(
                means, cross, np.asarray(measurement, dtype=float),
                default_sigma if sigma is None else np.asarray(sigma, dtype=float), r, phi,
                unit_q, dt7, new_means, new_cross)
        except TypeError:       # arrays of other dimensions or types than the kernel's
            return None
        if not done:
            return None
        return frozen_instance(FixedLagState, blocks_scaled=new_means, covariance=new_cross,
                               steps=state.steps + 1)

    # -- the two exact implementations -------------------------------------------------------

    def _step_superstate(self, state, z, q_scaled):
        phi = SCALED_TRANSITION
        n = STATE_SIZE
        x = state.blocks_scaled.reshape(self.model.num_joints, -1)
        p = state.covariance
        # X_{k|k−1} = Φ_BM X_{k−1|k−1}: block 0 propagates, the others shift down.
        x_pred = np.empty_like(x)
        x_pred[:, :n] = x[:, :n] @ phi.T
        x_pred[:, n:] = x[:, :-n]
        # P_{k|k−1} = Φ_BM P Φ_BMᵀ + Q_BM, assembled block-wise.
        p_pred = np.empty_like(p)
        p_pred[:, n:, n:] = p[:, :-n, :-n]
        top = phi @ p[:, :n, :-n]
        p_pred[:, :n, n:] = top
        p_pred[:, n:, :n] = np.swapaxes(top, -1, -2)
        p_pred[:, :n, :n] = phi @ p[:, :n, :n] @ phi.T + q_scaled
        # S = H_BM P Hᵀ_BM + r;  K = P Hᵀ / S;  X += K ν;  P −= K S Kᵀ
        pht = p_pred[:, :, 0]
        s = pht[:, 0] + self.model.r
        innovation = z - x_pred[:, 0]
        x_post = x_pred + pht * (innovation / s)[:, None]
        p_post = p_pred - pht[:, :, None] * pht[:, None, :] / s[:, None, None]
        p_post = 0.5 * (p_post + np.swapaxes(p_post, -1, -2))
        return FixedLagState(
            blocks_scaled=x_post.reshape(state.blocks_scaled.shape),
            covariance=p_post,
            steps=state.steps + 1,
        )

    def _step_recursion(self, state, z, q_scaled):
        phi = SCALED_TRANSITION
        means = state.blocks_scaled
        cross = state.covariance
        # Prior blocks: x̂_{k|k−1} = Φ x̂_{k−1|k−1}; x̂_{k−i|k−1} = old block i−1.
        prior = np.empty_like(means)
        prior[:, 0] = means[:, 0] @ phi.T
        prior[:, 1:] = means[:, :-1]
        # Σ^{(0)} = Φ P_{k−1|k−1} Φᵀ + Q_k;  Σ^{(i)} = C^{(i−1)} Φᵀ.
        sigma_cross = np.empty_like(cross)
        sigma_cross[:, 0] = phi @ cross[:, 0] @ phi.T + q_scaled
        sigma_cross[:, 1:] = cross[:, :-1] @ phi.T
        # Column 0 of Σ^{(i)} is Σ^{(i)} Hᵀ; row 0 of Σ^{(0)} is H Σ^{(0)}.
        sht = sigma_cross[:, :, :, 0]
        hs0 = sigma_cross[:, 0, 0, :]
        s = hs0[:, 0] + self.model.r
        innovation = z - prior[:, 0, 0]
        posterior = prior + sht * (innovation / s)[:, None, None]
        new_cross = (sigma_cross
                     - sht[:, :, :, None] * hs0[:, None, None, :] / s[:, None, None, None])
        new_cross[:, 0] = 0.5 * (new_cross[:, 0] + np.swapaxes(new_cross[:, 0], -1, -2))
        return FixedLagState(blocks_scaled=posterior, covariance=new_cross, steps=state.steps + 1)
