"""Kalman filter and Rauch–Tung–Striebel fixed-interval smoother (Offline-KS),
docs/method.md §3, §7.

All joints are processed at once: measurements are ``(num_samples, num_joints)``, states
``(num_samples, num_joints, 4)`` and covariances ``(num_samples, num_joints, 4, 4)``, in physical
units. Internally everything runs in the scaled state x̃ = T x (see ``model``).

Conventions:
    * The prior N(x̄_0, P_0) is the prediction for the first sample: x̂_{0|−1} = x̄_0.
    * ``sigma_schedule[k]`` is the σ used for the transition from k − 1 to k (row 0 unused),
      so a time-varying σ_k as in the reduced-Q smoother is reproduced exactly.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from telesmooth.arms.joint_vectors import check_trajectory
from telesmooth.smoothing.model import SCALED_TRANSITION, JerkModel, process_covariance

OFFLINE_REST_PRIOR_DIAG = (None, 1e-4, 1e-3, 1e-2)
"""docs/method.md §8 offline rest prior: P_0 = diag(r, 1e-4, 1e-3, 1e-2) (None stands for r)."""


@dataclass(frozen=True, eq=False)
class GaussianPrior:
    """Prior N(mean, cov) of the first state, per joint.

    Attributes:
        mean: shape (num_joints, 4), physical units.
        cov: shape (num_joints, 4, 4), physical units, symmetric positive semi-definite.
    """

    mean: np.ndarray
    cov: np.ndarray


def rest_prior(start_position, model: JerkModel, cov_diagonal=OFFLINE_REST_PRIOR_DIAG):
    """Robot at rest at ``start_position`` (num_joints,) with covariance diag(r, 1e-4, …)."""
    q0 = np.asarray(start_position, dtype=float)
    mean = np.zeros((model.num_joints, 4))
    mean[:, 0] = q0
    diag = np.empty((model.num_joints, 4))
    for a, value in enumerate(cov_diagonal):
        diag[:, a] = model.r if value is None else value
    cov = np.zeros((model.num_joints, 4, 4))
    cov[:, np.arange(4), np.arange(4)] = diag
    return GaussianPrior(mean=mean, cov=cov)


START_PRIORS = ("rest", "loose")
"""How the offline smoothers start: ``"rest"``, the robot at rest at the start pose one tick
before the first sample (:func:`rest_start_prior`, as the online smoothers start), or
``"loose"``, the paper's prior diag(r, 1e-4, 1e-3, 1e-2) at the first sample
(:func:`rest_prior`)."""


def rest_start_prior(start_position, model: JerkModel) -> GaussianPrior:
    """The robot at rest at ``start_position`` one tick before the first sample.

    x_{−1} = [q_start, 0, 0, 0] exactly, so the first sample's state is its prediction:
    x_0 ~ N(Φ x_{−1}, Q(Δt, σ)) = N([q_start, 0, 0, 0], Q(Δt, σ)) per joint. This is how the
    fixed-lag smoothers start (their rest covariance is 0 and their first step predicts with
    Q), so every smoother then assumes the same robot. With σ = 4e-4 rad²/s⁷ and Δt = 0.25 s
    the first sample's velocity has a standard deviation of 1.4e-4 rad/s, against 0.01 rad/s
    in :func:`rest_prior`: a smoother given that loose prior may start already moving, which
    the robot, at rest, receives as a jerk step.
    """
    q0 = np.asarray(start_position, dtype=float)
    mean = np.zeros((model.num_joints, 4))
    mean[:, 0] = q0
    return GaussianPrior(mean=mean, cov=process_covariance(model.dt_s, model.sigma))


def start_prior(kind: str, start_position, model: JerkModel) -> GaussianPrior:
    """The prior named by ``kind`` (:data:`START_PRIORS`)."""
    if kind == "rest":
        return rest_start_prior(start_position, model)
    if kind == "loose":
        return rest_prior(start_position, model)
    raise ValueError(f"start_prior = {kind!r} must be one of {START_PRIORS}")


@dataclass(frozen=True, eq=False)
class FilterResult:
    """Kalman filter output, physical units.

    Attributes:
        predicted_mean: x̂_{k|k−1}, shape (N, J, 4).
        predicted_cov: P_{k|k−1}, shape (N, J, 4, 4).
        filtered_mean: x̂_{k|k}, shape (N, J, 4).
        filtered_cov: P_{k|k}, shape (N, J, 4, 4).
    """

    predicted_mean: np.ndarray
    predicted_cov: np.ndarray
    filtered_mean: np.ndarray
    filtered_cov: np.ndarray


@dataclass(frozen=True, eq=False)
class SmootherResult:
    """Fixed-interval smoother output x̂_{k|N−1}, P_{k|N−1}, physical units, (N, J, 4[, 4])."""

    mean: np.ndarray
    cov: np.ndarray


def _sigma_rows(model: JerkModel, sigma_schedule, num_samples: int) -> np.ndarray:
    if sigma_schedule is None:
        return np.broadcast_to(model.sigma, (num_samples, model.num_joints))
    schedule = np.asarray(sigma_schedule, dtype=float)
    if schedule.shape != (num_samples, model.num_joints):
        raise ValueError(
            f"sigma_schedule has shape {schedule.shape}; expected "
            f"({num_samples}, {model.num_joints})"
        )
    if not np.all(np.isfinite(schedule[1:])) or np.any(schedule[1:] <= 0):
        row, col = np.argwhere(~(np.isfinite(schedule[1:]) & (schedule[1:] > 0)))[0]
        raise ValueError(
            f"sigma_schedule[{row + 1}, {col}] = {float(schedule[row + 1, col])!r} "
            f"for joint {col} "
            "must be finite and > 0"
        )
    return schedule


def _filter_scaled(measurements, model: JerkModel, prior: GaussianPrior, sigma_schedule):
    """The filter recursion in scaled coordinates; returns four scaled arrays."""
    z = check_trajectory("measurements", measurements, num_joints=model.num_joints)
    num_samples, num_joints = z.shape
    sigmas = _sigma_rows(model, sigma_schedule, num_samples)
    # Shorthand: Φ̃, r per joint, Q̃ per step computed from σ_k.
    phi = SCALED_TRANSITION
    r = model.r
    x_pred = np.empty((num_samples, num_joints, 4))
    p_pred = np.empty((num_samples, num_joints, 4, 4))
    x_filt = np.empty((num_samples, num_joints, 4))
    p_filt = np.empty((num_samples, num_joints, 4, 4))
    x = model.to_scaled(prior.mean)
    p = model.cov_to_scaled(prior.cov)
    q_constant = model.scaled_process_covariance() if sigma_schedule is None else None
    for k in range(num_samples):
        if k > 0:
            # x̃_{k|k−1} = Φ̃ x̃_{k−1|k−1};  P̃_{k|k−1} = Φ̃ P̃ Φ̃ᵀ + Q̃_k
            x = x @ phi.T
            q_k = q_constant if q_constant is not None else model.scaled_process_covariance(
                sigmas[k]
            )
            p = phi @ p @ phi.T + q_k
        x_pred[k] = x
        p_pred[k] = p
        # S = H P Hᵀ + r (scalar per joint);  K = P Hᵀ / S;  x += K ν;  P −= K S Kᵀ
        pht = p[:, :, 0]
        s = pht[:, 0] + r
        gain = pht / s[:, None]
        innovation = z[k] - x[:, 0]
        x = x + gain * innovation[:, None]
        p = p - gain[:, :, None] * pht[:, None, :]
        p = 0.5 * (p + np.swapaxes(p, -1, -2))
        x_filt[k] = x
        p_filt[k] = p
    return x_pred, p_pred, x_filt, p_filt


def kalman_filter(
    measurements, model: JerkModel, prior: GaussianPrior, *, sigma_schedule=None
) -> FilterResult:
    """Runs the Kalman filter over a whole recording (docs/method.md §7 "KF").

    Args:
        measurements: commanded joint positions z_k, shape (N, num_joints) [rad].
        model: the jerk model (Δt, σ, r per joint).
        prior: N(x̄_0, P_0) for the first state.
        sigma_schedule: optional σ_k per step and joint, shape (N, num_joints).

    Returns:
        Both the a-posteriori x̂_{k|k} and the predictor x̂_{k|k−1} with covariances.
    """
    x_pred, p_pred, x_filt, p_filt = _filter_scaled(measurements, model, prior, sigma_schedule)
    return FilterResult(
        predicted_mean=model.from_scaled(x_pred),
        predicted_cov=model.cov_from_scaled(p_pred),
        filtered_mean=model.from_scaled(x_filt),
        filtered_cov=model.cov_from_scaled(p_filt),
    )


def rts_smoother(
    measurements, model: JerkModel, prior: GaussianPrior, *, sigma_schedule=None
) -> SmootherResult:
    """Offline-KS: the RTS fixed-interval smoother over the whole recording (docs/method.md §7).

    Backward pass, for k = N−2 … 0:
        C_k = P_{k|k} Φᵀ P_{k+1|k}⁻¹
        x̂_{k|N} = x̂_{k|k} + C_k (x̂_{k+1|N} − x̂_{k+1|k})
        P_{k|N} = P_{k|k} + C_k (P_{k+1|N} − P_{k+1|k}) C_kᵀ

    The means equal the minimiser of the unconstrained IPLM objective (docs/method.md §2.3), which
    is what the tests check against a dense solve.
    """
    x_pred, p_pred, x_filt, p_filt = _filter_scaled(measurements, model, prior, sigma_schedule)
    phi = SCALED_TRANSITION
    num_samples = x_pred.shape[0]
    x_smooth = np.empty_like(x_filt)
    p_smooth = np.empty_like(p_filt)
    x_smooth[-1] = x_filt[-1]
    p_smooth[-1] = p_filt[-1]
    for k in range(num_samples - 2, -1, -1):
        # C_k = P_{k|k} Φ̃ᵀ P̃_{k+1|k}⁻¹, computed as a solve: P̃_{k+1|k} C_kᵀ = Φ̃ P_{k|k}
        gain = np.swapaxes(np.linalg.solve(p_pred[k + 1], phi @ p_filt[k]), -1, -2)
        x_smooth[k] = x_filt[k] + np.einsum("jab,jb->ja", gain, x_smooth[k + 1] - x_pred[k + 1])
        p = p_filt[k] + gain @ (p_smooth[k + 1] - p_pred[k + 1]) @ np.swapaxes(gain, -1, -2)
        p_smooth[k] = 0.5 * (p + np.swapaxes(p, -1, -2))
    return SmootherResult(mean=model.from_scaled(x_smooth), cov=model.cov_from_scaled(p_smooth))
