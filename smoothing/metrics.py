"""Evaluation metrics (docs/method.md §6): limits, deformation, Cartesian deformation, response
errors.

Finite differences of a sent position sequence p_k (period Δt):

    velocity      (p_{k+1} − p_k) / Δt
    acceleration  (p_{k+1} − 2 p_k + p_{k−1}) / Δt²
    jerk          (p_{k+2} − 3 p_{k+1} + 3 p_k − p_{k−1}) / Δt³

A value counts as over its limit when |value| > limit · (1 + VIOLATION_RTOL): a limit broken by
less than one part in 10⁶ is solver round-off, not a violation.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from telesmooth.safety.finite_differences import finite_differences

VIOLATION_RTOL = 1e-6


def limit_statistics(values, limit) -> dict:
    """Per-joint statistics of |values| (M, J) against ``limit`` (J,).

    Returns lists per joint: ``max_abs``, ``max_over_limit`` (max |value| / limit) and
    ``fraction_over_limit`` (share of samples with |value| > limit (1 + VIOLATION_RTOL)).
    """
    values = np.abs(np.asarray(values, dtype=float))
    limit = np.broadcast_to(np.asarray(limit, dtype=float), values.shape[1:])
    if values.shape[0] == 0:
        zeros = np.zeros(values.shape[1:])
        return {"max_abs": zeros.tolist(), "max_over_limit": zeros.tolist(),
                "fraction_over_limit": zeros.tolist(), "num_samples": 0}
    over = values > limit * (1.0 + VIOLATION_RTOL)
    return {
        "max_abs": values.max(axis=0).tolist(),
        "max_over_limit": (values.max(axis=0) / limit).tolist(),
        "fraction_over_limit": over.mean(axis=0).tolist(),
        "num_samples": int(values.shape[0]),
    }


def deformation_statistics(estimate, original) -> dict:
    """|estimate − original| per joint (docs/method.md §6, Def_q): mean (primary), RMS and max."""
    error = np.abs(np.asarray(estimate, dtype=float) - np.asarray(original, dtype=float))
    return {
        "mean": error.mean(axis=0).tolist(),
        "rms": np.sqrt((error**2).mean(axis=0)).tolist(),
        "max": error.max(axis=0).tolist(),
    }


def cartesian_deformation(
    estimate, original, forward_kinematics: Callable[[np.ndarray], np.ndarray]
) -> dict:
    """d(i) = ‖FK(q̂_i) − FK(q_i^ORG)‖ (docs/method.md §6, E_def): mean (primary), RMS and max [m].

    Args:
        estimate, original: joint trajectories, shape (M, J).
        forward_kinematics: maps (M, J) joint positions to (M, d) end-effector positions.
    """
    distance = np.linalg.norm(
        forward_kinematics(np.asarray(estimate)) - forward_kinematics(np.asarray(original)),
        axis=-1,
    )
    return {
        "mean": float(distance.mean()),
        "rms": float(np.sqrt((distance**2).mean())),
        "max": float(distance.max()),
    }


def tracking_errors(commanded_xy, measured_xy) -> np.ndarray:
    """e(i) = ‖x_cmd(i) − x^A(i)‖, the response error against the measured track
    (docs/method.md §6)."""
    return np.linalg.norm(np.asarray(commanded_xy) - np.asarray(measured_xy), axis=-1)


def improvement_ratio(errors_original, errors_smoothed) -> float:
    """P = (Σ e_ORG − Σ e_SMT) / Σ e_ORG × 100 % (docs/method.md §6)."""
    total_original = float(np.sum(errors_original))
    if total_original <= 0.0:
        raise ValueError(f"sum of e_ORG = {total_original!r} must be > 0 to form P")
    return 100.0 * (total_original - float(np.sum(errors_smoothed))) / total_original


MOTION_TOLERANCE_RAD = 1e-7
"""A sample is away from a pose when some joint differs from it by more than 0.1 µrad (0.05 µm
at half a metre: far under the tracker's 1 µm, far over the IK's round-off on a held hand)."""


def motion_span(positions, tolerance_rad: float = MOTION_TOLERANCE_RAD) -> tuple[int, int] | None:
    """The motion phase of a recording: (first, last) sample indices, inclusive.

    ``first`` is the last sample at the start pose before the first sample away from it,
    ``last`` the first sample at the final pose after the last sample away from it (the
    operator holds the start pose before, and the final pose after). None when no sample
    leaves the start pose (nothing moved).

    Args:
        positions: Samples, (N, J).
        tolerance_rad: How far (any joint) a sample must be from a pose to be away from it.
    """
    q = np.asarray(positions, dtype=float)
    leaves = np.flatnonzero(np.any(np.abs(q - q[0]) > tolerance_rad, axis=1))
    if leaves.size == 0:
        return None
    away = np.flatnonzero(np.any(np.abs(q - q[-1]) > tolerance_rad, axis=1))
    return int(max(0, leaves[0] - 1)), int(min(len(q) - 1, away[-1] + 1))


def smoothing_metrics(
    *,
    smoothed_positions,
    original_positions,
    dt_s: float,
    max_acceleration,
    max_jerk,
    max_velocity=None,
    smoothed_states=None,
    forward_kinematics=None,
    joint_names=None,
) -> dict:
    """All docs/method.md §6 metrics of one smoothed trajectory against the original, JSON-ready.

    Args:
        smoothed_positions: sent positions q̂_k aligned with the original samples, (M, J).
        original_positions: the operator's samples q_k^ORG, (M, J).
        dt_s: sample period.
        max_acceleration, max_jerk, max_velocity: per-joint limits (J,) (velocity optional).
        smoothed_states: the estimator's states (M, J, 4) if it has any (state acc/jerk and
            velocity-state deformation are reported then).
        forward_kinematics: optional FK for the Cartesian deformation.
        joint_names: labels in the output.
    """
    q_hat = np.asarray(smoothed_positions, dtype=float)
    q_org = np.asarray(original_positions, dtype=float)
    metrics = {
        "joint_names": list(joint_names) if joint_names is not None else None,
        "num_samples": int(q_hat.shape[0]),
        "dt_s": float(dt_s),
        "limits": {
            "max_acceleration_rad_per_s2":
                np.broadcast_to(max_acceleration, q_hat.shape[1:]).tolist(),
            "max_jerk_rad_per_s3": np.broadcast_to(max_jerk, q_hat.shape[1:]).tolist(),
        },
        "fd_acceleration": limit_statistics(finite_differences(q_hat, dt_s, 2), max_acceleration),
        "fd_jerk": limit_statistics(finite_differences(q_hat, dt_s, 3), max_jerk),
        "original_fd_acceleration": limit_statistics(
            finite_differences(q_org, dt_s, 2), max_acceleration),
        "original_fd_jerk": limit_statistics(finite_differences(q_org, dt_s, 3), max_jerk),
        "position_deformation_rad": deformation_statistics(q_hat, q_org),
    }
    velocity_original = finite_differences(q_org, dt_s, 1)
    if max_velocity is not None:
        metrics["limits"]["max_velocity_rad_per_s"] = np.broadcast_to(
            max_velocity, q_hat.shape[1:]).tolist()
        metrics["fd_velocity"] = limit_statistics(finite_differences(q_hat, dt_s, 1), max_velocity)
    if smoothed_states is not None:
        states = np.asarray(smoothed_states, dtype=float)
        metrics["state_acceleration"] = limit_statistics(states[:, :, 2], max_acceleration)
        metrics["state_jerk"] = limit_statistics(states[:, :, 3], max_jerk)
        # Velocity deformation: velocity state against the original's FD velocity.
        metrics["velocity_deformation_rad_per_s"] = deformation_statistics(
            states[1:, :, 1], velocity_original)
    else:
        metrics["velocity_deformation_rad_per_s"] = deformation_statistics(
            finite_differences(q_hat, dt_s, 1), velocity_original)
    if forward_kinematics is not None:
        metrics["cartesian_deformation_m"] = cartesian_deformation(q_hat, q_org,
                                                                   forward_kinematics)
    return metrics
