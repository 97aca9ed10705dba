"""The per-joint 4-state jerk model of the paper (docs/method.md §1) and its scaled form.

Each joint i is smoothed on its own. Its state is ``x = [q, q̇, q̈, q⃛]`` (rad, rad/s, rad/s²,
rad/s³), driven by white jounce noise of intensity σ (rad²/s⁷) and observed through a noisy
position sample of variance r (rad²):

    ẋ = A x + G w,   z = H x + v,   E[w(t) w(s)] = σ δ(t − s),   E[v²] = r

Exact discretisation with period Δt (docs/method.md §1.2): ``x_{k+1} = Φ x_k + w_k``,
``w_k ~ N(0, Q)``, ``Q_ab = σ Δt^(7−a−b) / ((7−a−b) (3−a)! (3−b)!)``.

Scaled state (docs/method.md §1.2): with ``T = diag(1, Δt, Δt², Δt³)`` and ``x̃ = T x``, the
transition ``Φ̃ = T Φ T⁻¹`` no longer depends on Δt and ``Q̃ = σ Δt⁷ Q1``. Every estimator in this
package works in the scaled state internally (cond(Q) in physical units grows like Δt⁻⁶ at 100 Hz)
and maps back with ``x = T⁻¹ x̃``.
"""

from __future__ import annotations

from dataclasses import dataclass
from math import factorial

import numpy as np

from telesmooth.arms.joint_vectors import (
    as_per_joint,
    check_positive_scalar,
)

STATE_SIZE = 4
"""Per-joint state dimension n: position, velocity, acceleration, jerk."""

STATE_NAMES = ("position", "velocity", "acceleration", "jerk")

# Q at Δt = 1, σ = 1 (docs/method.md §1.2 closed form).
UNIT_PROCESS_COVARIANCE = np.array(
    [
        [1.0 / ((7 - a - b) * factorial(3 - a) * factorial(3 - b)) for b in range(STATE_SIZE)]
        for a in range(STATE_SIZE)
    ]
)
"""Q1: the process covariance at Δt = 1 s and σ = 1 (dimensionless, scaled state)."""

UNIT_PROCESS_PRECISION = np.array(
    [
        [100800.0, -50400.0, 10080.0, -840.0],
        [-50400.0, 25920.0, -5400.0, 480.0],
        [10080.0, -5400.0, 1200.0, -120.0],
        [-840.0, 480.0, -120.0, 16.0],
    ]
)
"""Q1⁻¹, exact integers (docs/method.md §1.2)."""

SCALED_TRANSITION = np.array(
    [
        [1.0, 1.0, 0.5, 1.0 / 6.0],
        [0.0, 1.0, 1.0, 0.5],
        [0.0, 0.0, 1.0, 1.0],
        [0.0, 0.0, 0.0, 1.0],
    ]
)
"""Φ̃ = T Φ T⁻¹, independent of Δt."""

MEASUREMENT_MATRIX = np.array([[1.0, 0.0, 0.0, 0.0]])
"""H: only the position is measured (H̃ = H since T_00 = 1)."""


def transition_matrix(dt_s: float) -> np.ndarray:
    """Φ(Δt) = expm(A Δt), shape (4, 4)."""
    dt = check_positive_scalar("dt_s", dt_s)
    return np.array(
        [
            [1.0, dt, dt**2 / 2.0, dt**3 / 6.0],
            [0.0, 1.0, dt, dt**2 / 2.0],
            [0.0, 0.0, 1.0, dt],
            [0.0, 0.0, 0.0, 1.0],
        ]
    )


def process_covariance(dt_s: float, sigma) -> np.ndarray:
    """Exact Q(Δt, σ) in physical units.

    Args:
        dt_s: sample period Δt [s].
        sigma: jounce intensity σ [rad²/s⁷], scalar or array of any shape.

    Returns:
        Array of shape ``np.shape(sigma) + (4, 4)``.
    """
    dt = check_positive_scalar("dt_s", dt_s)
    sigma = np.asarray(sigma, dtype=float)
    powers = np.array([[dt ** (7 - a - b) for b in range(4)] for a in range(4)])
    return sigma[..., None, None] * (UNIT_PROCESS_COVARIANCE * powers)


def state_scaling(dt_s: float) -> np.ndarray:
    """The diagonal of T = diag(1, Δt, Δt², Δt³), shape (4,)."""
    dt = check_positive_scalar("dt_s", dt_s)
    return dt ** np.arange(STATE_SIZE, dtype=float)


@dataclass(frozen=True, eq=False)
class JerkModel:
    """Parameters of the per-joint jerk model, one value per joint.

    Attributes:
        dt_s: sample period Δt [s].
        sigma: jounce intensity σ per joint [rad²/s⁷], shape (num_joints,).
        r: position measurement variance per joint [rad²], shape (num_joints,).
    """

    dt_s: float
    sigma: np.ndarray
    r: np.ndarray

    @staticmethod
    def make(dt_s: float, sigma, r, *, num_joints: int, joint_names=None) -> JerkModel:
        """Validates and broadcasts scalar or per-joint σ and r to ``(num_joints,)``."""
        dt = check_positive_scalar("dt_s", dt_s)
        return JerkModel(
            dt_s=dt,
            sigma=as_per_joint("sigma", sigma, num_joints, joint_names),
            r=as_per_joint("r", r, num_joints, joint_names),
        )

    @property
    def num_joints(self) -> int:
        return int(self.sigma.shape[0])

    @property
    def scaling(self) -> np.ndarray:
        """diag(T), shape (4,)."""
        return state_scaling(self.dt_s)

    def scaled_process_covariance(self, sigma=None) -> np.ndarray:
        """Q̃ = σ Δt⁷ Q1 per joint, shape (num_joints, 4, 4); ``sigma`` overrides self.sigma."""
        sigma = self.sigma if sigma is None else np.asarray(sigma, dtype=float)
        return (sigma * self.dt_s**7)[..., None, None] * UNIT_PROCESS_COVARIANCE

    def to_scaled(self, x: np.ndarray) -> np.ndarray:
        """x̃ = T x for states with a trailing axis of size 4."""
        return np.asarray(x, dtype=float) * self.scaling

    def from_scaled(self, x_scaled: np.ndarray) -> np.ndarray:
        """x = T⁻¹ x̃ for states with a trailing axis of size 4."""
        return np.asarray(x_scaled, dtype=float) / self.scaling

    def cov_to_scaled(self, cov: np.ndarray) -> np.ndarray:
        """P̃ = T P T for covariances with trailing axes (4, 4)."""
        s = self.scaling
        return np.asarray(cov, dtype=float) * s[:, None] * s[None, :]

    def cov_from_scaled(self, cov_scaled: np.ndarray) -> np.ndarray:
        """P = T⁻¹ P̃ T⁻¹."""
        s = self.scaling
        return np.asarray(cov_scaled, dtype=float) / (s[:, None] * s[None, :])


def sigma_from_bandwidth(cutoff_hz: float, *, r: float, dt_s: float) -> float:
    """σ for an RTS −3 dB bandwidth f_c: σ = r Δt (2π f_c / 0.9)⁸ (docs/method.md §1.4, §8).

    The bandwidth grows only as σ^(1/8): halving it needs σ / 256.
    """
    fc = check_positive_scalar("cutoff_hz", cutoff_hz)
    r = check_positive_scalar("r", r)
    dt = check_positive_scalar("dt_s", dt_s)
    return r * dt * (2.0 * np.pi * fc / 0.9) ** 8


DEFAULT_DT_S = 0.25
"""4 Hz uplink period of the paper [P]."""
DEFAULT_R = 1e-6
"""(1e-3 rad)², docs/method.md §8."""
DEFAULT_SIGMA = 4e-4
"""σ_0 for f_c ≈ 0.36 Hz at Δt = 0.25 s, r = 1e-6 (docs/method.md §8)."""
DEFAULT_LAG = 3
"""L = 0.75 s / 0.25 s (docs/method.md §5.1)."""
MAX_LAG = 1000
"""Longest fixed lag accepted, samples: a fixed-lag step costs about L² (the superstate's L³),
so L = 10⁴ on a 40-sample recording takes minutes for nothing (at 4 Hz, 1000 samples is
250 s of lag; at 100 Hz, 10 s)."""
