"""How much of an online method's deviation needed foresight: the best continuation.

An online method commits each command when it sends it. Let z_0 … z_{N−1} be the operator's
samples and p_0 … p_{N−1} the commands a method sent for them (p_i carries sample i; for a
fixed-lag method it left the ground station L ticks after z_i arrived). For a sample index s,
the *best continuation* from s keeps p_0 … p_{s−1} and replaces the rest by

    p*_s … p*_{N−1} = argmin Σ_{i ≥ s} (p_i − z_i)²
                      subject to the finite-difference limits of docs/method.md §2.6 on the whole
                      sequence [q_rest × 3, p_0 … p_{s−1}, p_s … p_{N−1}],

i.e. the commands closest to the operator that any method, knowing the whole future, could
still have sent after those first s commands (per joint: the objective and the limits are
separable). So for every method within the limits whose first s commands are the same,

    Σ_{i ≥ s} (p_i − z_i)²  ≥  Σ_{i ≥ s} (p*_i − z_i)²          (per joint),

a lower bound on its remaining squared deviation. Swept over s it shows where a method's
deviation arises: once the bound from s is close to the method's own deviation, the loss was
already committed by command s − 1, and no rule could have avoided it without knowing, when
command s − 1 was sent, more of the operator's motion than the method did (a lag-L method had
seen z up to s − 1 + L). From s = 0 it is the trajectory-constrained least-squares optimum of
the whole recording.

Limits: |v| ≤ v_max (optional), |a| ≤ a_max, |u| ≤ j_max of the backward differences, as in
:func:`~telesmooth.smoothing.online_hard.online_hard_run` (the rest history counts; nothing
is imposed after p_{N−1}). The fixed prefix must itself be within the limits (else no
continuation exists; reported as a failure, not raised). Solved per joint with Clarabel
through a Drake ``MathematicalProgram`` (one shared unit ``QuadraticCost`` per variable, the
data term as one linear cost, the limits as one sparse linear constraint per order).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from pydrake.solvers import ClarabelSolver, MathematicalProgram, QuadraticCost, SolverOptions

from telesmooth.arms.joint_vectors import (
    _joint_label,
    as_per_joint,
    check_finite_per_joint,
    check_trajectory,
)
from telesmooth.smoothing.offline import finite_difference_operator, tolerance_ladder

__all__ = ["ContinuationResult", "ForesightSweep", "best_continuation", "foresight_sweep"]

_HISTORY = 3
_TOLERANCE = 1e-12
_LOOSER_TOLERANCES = (1e-10, 1e-8)
"""Tried in turn when Clarabel stops short of the requested tolerance (it may report
InsufficientProgress at 1e-12 on some problems and some CPUs); the status names the one met."""


@dataclasses.dataclass(frozen=True, eq=False)
class ContinuationResult:
    """The best continuation of one command sequence from one sample.

    Attributes:
        start: s, the first replaced sample.
        positions: [p_0 … p_{s−1}, p*_s … p*_{N−1}], rad, (N, J) (NaN where a joint
            failed).
        squared_error: Σ_{i ≥ s} (p*_i − z_i)² per joint, rad², (J,).
        is_success: per joint, (J,).
        status: per joint, the solver's result ("SolutionResult.kSolutionFound", with
            " at tolerance 1e-10" when only a looser tolerance was met, or why not).
    """

    start: int
    positions: np.ndarray
    squared_error: np.ndarray
    is_success: np.ndarray
    status: tuple


def _limit_rows(num_samples: int, start: int, order: int):
    """The backward differences of order ``order`` of [history × rest, p_0 … p_{N−1}]
    (:func:`~telesmooth.smoothing.offline.finite_difference_operator`, positions relative to
    the rest pose so the history contributes nothing), split at ``start``: (D_x, D_prefix)
    over the rows that touch a free variable x = p_start … p_{N−1} (D_x on x, D_prefix on the
    fixed p_0 … p_{start−1}), and the rows over the prefix alone (checked, not imposed)."""
    operator, _ = finite_difference_operator(num_samples, order, history=_HISTORY)
    operator = operator.tocsc()
    free, prefix = operator[:, start:], operator[:, :start]
    touches = np.diff(free.tocsr().indptr) > 0
    return free[touches], prefix[touches].toarray(), prefix[~touches].toarray()


def best_continuation(commands, reference, start: int, dt_s: float, *, max_acceleration,
                      max_jerk, max_velocity=None, rest=None, joint_names=None,
                      tolerance: float = _TOLERANCE) -> ContinuationResult:
    """The commands closest to ``reference`` that could follow the first ``start`` commands
    within the FD limits (module docstring).

    Args:
        commands: p_i, rad, (N, J): what a method sent, aligned with the samples.
        reference: z_i, rad, (N, J): the operator's samples.
        start: s, 0 ≤ s < N: p_0 … p_{s−1} are kept.
        dt_s: Δt, s.
        max_acceleration, max_jerk: a_max [rad/s²], j_max [rad/s³], scalar or per joint.
        max_velocity: v_max [rad/s], scalar or per joint, or None (no limit).
        rest: q_rest, rad, (J,): the pose held before p_0 (default z_0).
        joint_names: labels for errors.
        tolerance: Clarabel's gap and feasibility tolerances; if it stops short of them, the
            looser ones of ``_LOOSER_TOLERANCES`` are tried in turn (the status names the
            tolerance met when it is not this one).

    Returns:
        ContinuationResult; a joint whose prefix breaks a limit (no continuation exists) or
        whose solve fails has ``is_success`` False and NaN positions.

    Raises:
        ValueError: bad shapes, non-finite values, a start outside [0, N), bad limits.
    """
    z = check_trajectory("reference", reference, joint_names=joint_names)
    num_samples, num_joints = z.shape
    p = check_trajectory("commands", commands, num_joints=num_joints, joint_names=joint_names)
    if p.shape != z.shape:
        raise ValueError(f"commands has shape {p.shape} but reference has shape {z.shape}")
    if isinstance(start, bool) or not isinstance(start, (int, np.integer)) or not (
            0 <= start < num_samples):
        raise ValueError(f"start = {start!r} must be an integer in [0, {num_samples})")
    if isinstance(dt_s, bool) or not (isinstance(dt_s, (int, float, np.integer, np.floating))
                                      and math.isfinite(dt_s) and dt_s > 0):
        raise ValueError(f"dt_s = {dt_s!r} must be a positive number of seconds")
    acc = as_per_joint("max_acceleration_rad_per_s2", max_acceleration, num_joints, joint_names)
    jerk = as_per_joint("max_jerk_rad_per_s3", max_jerk, num_joints, joint_names)
    vel = (np.full(num_joints, np.inf) if max_velocity is None else as_per_joint(
        "max_velocity_rad_per_s", max_velocity, num_joints, joint_names, allow_inf=True))
    q_rest = z[0] if rest is None else check_finite_per_joint("rest", rest, num_joints,
                                                              joint_names)

    n = num_samples - start
    limits = [(order, limit * dt_s**order) for order, limit in ((1, vel), (2, acc), (3, jerk))]
    rows = {order: _limit_rows(num_samples, start, order) for order, _ in limits}
    solver, options = ClarabelSolver(), SolverOptions()
    ladder = tolerance_ladder(tolerance, _LOOSER_TOLERANCES)
    unit = QuadraticCost(np.array([[1.0]]), np.zeros(1), 0.0, is_convex=True)
    positions = p.copy()
    squared = np.full(num_joints, np.nan)
    success = np.zeros(num_joints, dtype=bool)
    status = []
    for j in range(num_joints):
        # Positions relative to the rest pose: round-off does not grow with the joint angle.
        fixed = p[:start, j] - q_rest[j]
        target = z[start:, j] - q_rest[j]
        prog = MathematicalProgram()
        x = prog.NewContinuousVariables(n, f"p_j{j}")
        for i in range(n):     # ½ Σ x_i² − Σ z_i x_i = ½ Σ (x_i − z_i)² + const
            prog.AddCost(unit, x[i:i + 1])
        prog.AddLinearCost(-target, 0.0, x)
        prefix_ok = True
        for order, limit in limits:
            if not math.isfinite(limit[j]):
                continue
            d, selector, prefix_only = rows[order]
            offset = selector @ fixed
            prefix_ok &= bool(np.all(np.abs(prefix_only @ fixed) <= limit[j] * (1 + 1e-9)))
            prog.AddLinearConstraint(d, -limit[j] - offset, limit[j] - offset, x) \
                .evaluator().set_description(f"fd{order}_limit_j{j}")
        if not prefix_ok:
            status.append(f"the first {start} commands already break a limit of "
                          f"{_joint_label(j, joint_names)}")
            positions[start:, j] = np.nan
            continue
        for tol in ladder:
            for name in ("tol_gap_abs", "tol_gap_rel", "tol_feas", "tol_ktratio"):
                options.SetOption(solver.id(), name, tol)
            result = solver.Solve(prog, None, options)
            if result.is_success():
                break
        status.append(str(result.get_solution_result()) + (
            f" at tolerance {tol:g}" if tol != tolerance else ""))
        if not result.is_success():
            positions[start:, j] = np.nan
            continue
        solution = result.GetSolution(x)
        positions[start:, j] = solution + q_rest[j]
        squared[j] = float(np.sum((solution - target) ** 2))
        success[j] = True
    return ContinuationResult(start=int(start), positions=positions, squared_error=squared,
                              is_success=success, status=tuple(status))


@dataclasses.dataclass(frozen=True, eq=False)
class ForesightSweep:
    """Best continuations of one command sequence from several samples.

    Attributes:
        starts: s per row, (S,).
        method_squared_error: Σ_{i ≥ s} (p_i − z_i)² of the method itself, rad², (S, J).
        bound_squared_error: the same of the best continuation from s, rad², (S, J).
        continuations: the :class:`ContinuationResult` per start.
    """

    starts: np.ndarray
    method_squared_error: np.ndarray
    bound_squared_error: np.ndarray
    continuations: tuple


def foresight_sweep(commands, reference, dt_s: float, *, starts=None, step: int = 4,
                    progress=None, **limits) -> ForesightSweep:
    """:func:`best_continuation` from every ``step``-th sample (or the given ``starts``).

    Args:
        commands, reference, dt_s: as for :func:`best_continuation`.
        starts: sample indices, or None for 0, step, 2·step, … < N.
        step: spacing of the default starts (≥ 1).
        progress: optional callable(done, total), called after each start.
        **limits: max_acceleration, max_jerk, max_velocity, rest, joint_names, tolerance.

    Raises:
        ValueError: as :func:`best_continuation`, or a bad ``step``.
    """
    z = np.asarray(reference, dtype=float)
    p = np.asarray(commands, dtype=float)
    if starts is None:
        if isinstance(step, bool) or not isinstance(step, (int, np.integer)) or step < 1:
            raise ValueError(f"step = {step!r} must be an integer >= 1")
        starts = range(0, z.shape[0], step)
    starts = np.array(list(starts), dtype=int)
    continuations = []
    for done, start in enumerate(starts, 1):
        continuations.append(best_continuation(p, z, int(start), dt_s, **limits))
        if progress is not None:
            progress(done, len(starts))
    method = np.array([np.sum((p[s:] - z[s:]) ** 2, axis=0) for s in starts])
    bound = np.array([c.squared_error for c in continuations])
    return ForesightSweep(starts=starts, method_squared_error=method,
                          bound_squared_error=bound, continuations=tuple(continuations))
