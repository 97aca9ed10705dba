"""Offline-hard: the commands closest to the operator within hard finite-difference limits.

For the operator's samples z_0 … z_{N−1} of one joint and a robot at rest at q_start,

    p* = argmin_p  Σ_k (p_k − z_k)²
         subject to |Δᵏp| ≤ limit_k Δtᵏ  (k = 1, 2, 3: v_max, a_max, j_max; each optional)
         on the whole sequence the robot receives: [q_start × 3, p_0 … p_{N−1}] and, with
         ``rest_at_end`` (default), p_{N−1} held three more samples,

the same rest conventions as Offline-CKS in trajectory mode (the robot starts at rest and
ends at rest; the history and the hold count). It is not a smoother: it deforms the operator's
samples only where the limits force it, and by the least squared amount, so its Cartesian
deformation is the least any method that keeps the limits can have (up to the difference
between joint and Cartesian measures): the reference for how much deformation the limits force.
It needs the whole recording in advance (offline). Without ``rest_at_end`` it is the best
continuation from the first sample of :mod:`telesmooth.smoothing.foresight`.

Per joint a strictly convex QP in the positions relative to q_start (so the rest history
contributes nothing and round-off does not grow with the joint angle), solved by the banded
interior point of :mod:`telesmooth.smoothing.banded_ip` with A = I and F the finite
differences normalised by their limits (half-bandwidth 3). Always feasible: p_k ≡ q_start
keeps every limit.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import scipy.sparse as sparse

from telesmooth.arms.joint_vectors import as_per_joint, check_finite_per_joint, check_trajectory
from telesmooth.smoothing.banded_ip import BandedIpOptions, BandedQp
from telesmooth.smoothing.offline import HISTORY_LENGTH, finite_difference_operator

__all__ = ["OfflineHardResult", "offline_hard_problem", "solve_offline_hard"]


@dataclasses.dataclass(frozen=True, eq=False)
class OfflineHardResult:
    """The offline-hard commands.

    Attributes:
        positions: p*_k, rad, (N, J) (NaN for a joint that did not converge).
        squared_error: Σ_k (p*_k − z_k)² per joint, rad², (J,).
        is_success: True when every joint converged.
        status: per joint, the interior point's status ("converged", "unconstrained": the
            samples already keep every limit, or why it failed).
        iterations: Newton steps per joint, (J,).
    """

    positions: np.ndarray
    squared_error: np.ndarray
    is_success: bool
    status: tuple
    iterations: np.ndarray


def offline_hard_problem(z, q_start: float, dt_s: float, limits, *, rest_at_end: bool = True):
    """One joint's problem for :class:`~telesmooth.smoothing.banded_ip.BandedQp`.

    Args:
        z: The joint's samples, rad, (N,).
        q_start: The rest pose before the first command, rad.
        dt_s: Δt, s.
        limits: (v_max, a_max, j_max) in rad/s, rad/s², rad/s³; +inf = no limit.
        rest_at_end: Hold the last command three more samples (rest at the end).

    Returns:
        (A, c, F, lower, upper, fixed) over y = p − q_start: ½‖A y − c‖² = ½‖p − z‖², and
        lower ≤ F y ≤ upper the normalised finite-difference limits (±1).
    """
    z = np.asarray(z, dtype=float)
    n = z.size
    rows = []
    for order, limit in zip((1, 2, 3), limits):
        if not math.isfinite(limit):
            continue
        operator, _ = finite_difference_operator(
            n, order, history=HISTORY_LENGTH, hold_at_end=HISTORY_LENGTH if rest_at_end else 0)
        rows.append(operator / (limit * dt_s**order))
    f = sparse.vstack(rows, format="csr") if rows else sparse.csr_matrix((0, n))
    ones = np.ones(f.shape[0])
    return (sparse.identity(n, format="csr"), z - q_start, f, -ones, ones,
            np.zeros(n, dtype=bool))


def solve_offline_hard(reference, dt_s: float, *, max_acceleration, max_jerk,
                       max_velocity=None, start_position=None, rest_at_end: bool = True,
                       joint_names=None, options: BandedIpOptions | None = None
                       ) -> OfflineHardResult:
    """Offline-hard for every joint (module docstring).

    Args:
        reference: z_k, rad, (N, J), uniform period ``dt_s``.
        dt_s: Δt, s.
        max_acceleration, max_jerk: a_max [rad/s²], j_max [rad/s³], scalar or per joint
            (+inf: no limit).
        max_velocity: v_max [rad/s], scalar or per joint, or None (no limit).
        start_position: q_start, rad, (J,): the rest pose before the first command
            (default z_0).
        rest_at_end: End at rest: the last command held three more samples within the limits.
        joint_names: labels for errors.
        options: the interior point's tolerances.

    Returns:
        OfflineHardResult; a joint that does not converge is reported, not raised.

    Raises:
        ValueError: bad shapes, non-finite values or limits (naming the field and joint).
    """
    z = check_trajectory("reference", reference, joint_names=joint_names, min_samples=2)
    num_samples, num_joints = z.shape
    if isinstance(dt_s, bool) or not (isinstance(dt_s, (int, float, np.integer, np.floating))
                                      and math.isfinite(dt_s) and dt_s > 0):
        raise ValueError(f"dt_s = {dt_s!r} must be a positive number of seconds")
    acc = as_per_joint("max_acceleration_rad_per_s2", max_acceleration, num_joints,
                       joint_names, allow_inf=True)
    jerk = as_per_joint("max_jerk_rad_per_s3", max_jerk, num_joints, joint_names,
                        allow_inf=True)
    vel = (np.full(num_joints, np.inf) if max_velocity is None else as_per_joint(
        "max_velocity_rad_per_s", max_velocity, num_joints, joint_names, allow_inf=True))
    q_start = z[0] if start_position is None else check_finite_per_joint(
        "start_position", start_position, num_joints, joint_names)
    options = options if options is not None else BandedIpOptions()
    positions = np.full((num_samples, num_joints), np.nan)
    squared = np.full(num_joints, np.nan)
    iterations = np.zeros(num_joints, dtype=int)
    status = []
    for j in range(num_joints):
        problem = offline_hard_problem(z[:, j], q_start[j], float(dt_s),
                                       (vel[j], acc[j], jerk[j]), rest_at_end=rest_at_end)
        _, c, f, lower, upper, _ = problem
        y = c.copy()                                   # the samples themselves
        if f.shape[0] == 0 or np.all(np.abs(f @ y) <= 1.0):
            status.append("unconstrained")
        else:
            qp = BandedQp(*problem, options)
            result = qp.run(np.zeros_like(y))         # from rest: strictly within every limit
            iterations[j] = result.iterations
            status.append(result.status)
            if not result.converged:
                continue
            y = result.y
        positions[:, j] = y + q_start[j]
        squared[j] = float(np.sum((positions[:, j] - z[:, j]) ** 2))
    return OfflineHardResult(positions=positions, squared_error=squared,
                             is_success=bool(np.all(np.isfinite(squared))),
                             status=tuple(status), iterations=iterations)
