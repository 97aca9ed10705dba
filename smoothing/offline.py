"""Offline-CKS: the inequality-constrained fixed-interval smoother as a Drake MathematicalProgram.

docs/method.md §2.5. Per joint, with decision variables Y ∈ ℝ^{4×N}
(the scaled states y_k = T x_k), minimise the Kalman-smoother negative log-likelihood multiplied
by r:

    f(Y) = ½ Σ_k (z_k − y_k[0])²
         + ½ (y_0 − T x̄_0)ᵀ W_0 (y_0 − T x̄_0),                 W_0 = r (T P_0 T)⁻¹
         + ½ Σ_{k≥1} (y_k − Φ̃ y_{k−1})ᵀ W (y_k − Φ̃ y_{k−1}),   W = r / (σ Δt⁷) · Q1⁻¹

subject to, by ``constraint``:

``"state"`` (the paper's (11), soft in the sense of docs/method.md §2.4)
    |y_k[2]| ≤ a_max Δt²,  |y_k[3]| ≤ j_max Δt³  for every k.
``"trajectory"`` (docs/method.md §2.6, hard limits on the positions actually sent)
    With the committed history p_{−3} = p_{−2} = p_{−1} = q_start in front (robot at rest):
    |Δp| ≤ v_max Δt (optional),  |Δ²p| ≤ a_max Δt²,  |Δ³p| ≤ j_max Δt³ over the whole sequence.
    Always feasible: the constant trajectory p_k ≡ q_start satisfies every row.
``"both"``: the two sets together. ``"none"``: no limits (equals the RTS smoother).

``rest_at_end`` adds y_{N−1}[1:4] = 0, and in trajectory mode also holds the last position for
three more samples so that the finite differences across the end stay within the limits.

Without active limits the minimiser is the RTS smoother (tested). The problem is a strictly
convex QP, so any correct solver returns the same trajectory; Clarabel runs with gap and
feasibility tolerances of 1e-12 first (then TOLERANCE_LADDER), which agrees with an independent
interior-point solve to better than 1e-6 (tested).

Conditioning: the program is written in the deviation δ = Y − Y_RTS from the unconstrained
optimum (the RTS smoother, exact to ~1e-15): f(Y_RTS + δ) = f(Y_RTS) + gᵀδ + ½ δᵀ C δ, where
g = ∇f(Y_RTS) is evaluated exactly (it is ~0). Written in Y directly, the objective is
dominated by ½Σz² and Clarabel stops with InsufficientProgress at tight tolerances as soon as
a limit is far from active; in δ the cost measures only what the limits change.

Build cost: the Hessian is block-tridiagonal with one repeated 8×8 pair block, so the process
term is added as bindings of one shared ``QuadraticCost`` over blocks of ``block_size``
consecutive states, and the measurement term as a single vectorised linear cost (DRAKE_NOTES §6).
"""

from __future__ import annotations

import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sparse
from pydrake.solvers import (
    ClarabelSolver,
    MathematicalProgram,
    QuadraticCost,
    SolverOptions,
)
from scipy.linalg import LinAlgError
from threadpoolctl import threadpool_limits

from telesmooth.arms.joint_vectors import (
    as_per_joint,
    check_finite_per_joint,
    check_positive_int,
    check_trajectory,
)
from telesmooth.smoothing.banded_ip import BandedIpOptions, BandedQp
from telesmooth.smoothing.kalman import GaussianPrior, rest_prior, rts_smoother
from telesmooth.smoothing.model import (
    SCALED_TRANSITION,
    UNIT_PROCESS_PRECISION,
    JerkModel,
)

OFFLINE_CONSTRAINTS = ("state", "trajectory", "both", "none")
OFFLINE_SOLVERS = ("drake", "banded-ip")
"""Offline-CKS solvers: the Drake MathematicalProgram (Clarabel) or the banded interior point."""
HISTORY_LENGTH = 3
"""Committed samples in front of the trajectory in ``"trajectory"`` mode (jerk needs 3)."""


@dataclass(frozen=True, eq=False)
class OfflineCksResult:
    """Offline-CKS solution.

    Attributes:
        states: x_k per joint, shape (N, num_joints, 4), physical units.
        is_success: True when every joint's program was solved.
        solution_results: Drake ``SolutionResult`` name per joint.
        solver_name: the solver used.
        objective: f(Y) per joint (negative log-likelihood × r, up to a constant).
        solve_time_s: solver time per joint [s] (as reported by the solver).
        build_time_s: program build time per joint [s].
        infeasible_constraints: for failed joints, Drake's names of violated constraints.
        tolerance_reached: the Clarabel tolerance that solved each joint (0.0 where the RTS
            solution already met every limit, so it is the exact optimum and no solve ran).
    """

    states: np.ndarray
    is_success: bool
    solution_results: tuple
    solver_name: str
    objective: np.ndarray
    solve_time_s: np.ndarray
    build_time_s: np.ndarray
    infeasible_constraints: tuple
    tolerance_reached: np.ndarray


TOLERANCE_LADDER = (1e-12, 1e-11, 1e-10, 1e-9, 1e-8)
"""Clarabel tolerances tried in turn, each first with Ruiz equilibration and then without it
(equilibration makes Clarabel stop early on some of these problems); the tolerance reached is
reported per joint."""


def tolerance_ladder(tolerance: float, looser=TOLERANCE_LADDER) -> tuple:
    """``tolerance`` first, then each value of ``looser`` above it: the tolerances a solve
    that stops short is tried at in turn."""
    return (float(tolerance), *(tol for tol in looser if tol > tolerance))


def finite_difference_operator(
    num_samples: int, order: int, *, history: int = 0, hold_at_end: int = 0
) -> tuple[sparse.csr_matrix, np.ndarray]:
    """Finite differences of order 1–3 of [history × q_start, p_0 … p_{N−1}, hold × p_{N−1}].

    Returns ``(A, c)`` such that the differences equal ``A p + c · q_start``; rows that involve
    no decision variable are dropped. A has shape (rows, num_samples).
    """
    coefficients = {1: [-1.0, 1.0], 2: [1.0, -2.0, 1.0], 3: [-1.0, 3.0, -3.0, 1.0]}[order]
    extended = history + num_samples + hold_at_end
    rows = extended - order
    if rows <= 0:
        return sparse.csr_matrix((0, num_samples)), np.zeros(0)
    diff = sparse.diags(coefficients, list(range(order + 1)), shape=(rows, extended), format="csr")
    # e = E p + c q_start: history columns are constants, hold columns repeat p_{N−1}.
    expand = sparse.csr_matrix(
        (np.ones(num_samples + hold_at_end),
         (history + np.arange(num_samples + hold_at_end),
          np.minimum(np.arange(num_samples + hold_at_end), num_samples - 1))),
        shape=(extended, num_samples))
    constant = np.zeros(extended)
    constant[:history] = 1.0
    a = (diff @ expand.tocsr()).tocsr()
    c = diff @ constant
    keep = np.diff(a.indptr) > 0
    return a[keep], c[keep]


def with_rest_history(positions, q_start, *, hold_at_end: int = HISTORY_LENGTH) -> np.ndarray:
    """[q_start × HISTORY_LENGTH, p_0 … p_{N−1}, p_{N−1} × hold_at_end] along axis 0: the
    position sequence a robot at rest at ``q_start`` receives when the last command is held
    (the sequence whose finite differences the trajectory mode limits). ``positions`` is
    (N,) or (N, J); ``q_start`` a scalar or (J,)."""
    p = np.asarray(positions, dtype=float)
    start = np.broadcast_to(np.asarray(q_start, dtype=float), p.shape[1:])
    return np.concatenate([np.repeat(start[None], HISTORY_LENGTH, axis=0), p,
                           np.repeat(p[-1:], hold_at_end, axis=0)])


def _block_hessian(pair_hessian: np.ndarray, num_pairs: int) -> np.ndarray:
    """Hessian over states (y_{s−1}, …, y_{s+B−1}) for B = num_pairs process terms plus the
    measurement terms of the B states the block owns (all but the first)."""
    size = 4 * (num_pairs + 1)
    hessian = np.zeros((size, size))
    for j in range(num_pairs):
        hessian[4 * j : 4 * j + 8, 4 * j : 4 * j + 8] += pair_hessian
        hessian[4 * (j + 1), 4 * (j + 1)] += 1.0  # ½ y_k[0]² of the measurement term
    return hessian


def solve_offline_cks(
    measurements,
    model: JerkModel,
    *,
    max_acceleration=np.inf,
    max_jerk=np.inf,
    max_velocity=None,
    constraint: str = "state",
    rest_at_end: bool = False,
    prior: GaussianPrior | None = None,
    start_position=None,
    joint_names=None,
    tolerance: float = 1e-12,
    block_size: int = 32,
    solver: str = "drake",
    banded_options: BandedIpOptions | None = None,
    threads: int | None = None,
) -> OfflineCksResult:
    """Solves Offline-CKS for every joint (docs/method.md §2.5/§2.6).

    Args:
        measurements: z_k, shape (N, num_joints) [rad], uniform period model.dt_s.
        model: jerk model (Δt, σ, r per joint).
        max_acceleration: a_max per joint [rad/s²]; +inf disables.
        max_jerk: j_max per joint [rad/s³]; +inf disables.
        max_velocity: v_max per joint [rad/s] (trajectory mode only); None disables.
        constraint: "state" (paper, default), "trajectory" (hard FD limits), "both", "none".
        rest_at_end: require rest at the last sample (see module docstring).
        prior: N(x̄_0, P_0); default rest at z_0 with diag(r, 1e-4, 1e-3, 1e-2) (docs/method.md §8).
        start_position: q_start of the committed history (trajectory mode); default z_0.
        joint_names: used in constraint names and error messages.
        tolerance: the tightest Clarabel tol_gap_abs/tol_gap_rel/tol_feas tried first; if
            Clarabel cannot reach it (InsufficientProgress/AlmostSolved), the solve is
            repeated with each looser value of TOLERANCE_LADDER down to 1e-8 and the tolerance
            reached is reported per joint.
        block_size: states per shared cost binding (a build-speed knob only).
        solver: "drake" (default: the MathematicalProgram solved by Clarabel; a joint that
            Clarabel cannot solve at any tolerance of the ladder is solved again by the banded
            interior point, and ``solver_name`` says so) or "banded-ip" (only the banded
            interior point of :mod:`telesmooth.smoothing.banded_ip`; ``tolerance`` and
            ``block_size`` do not apply).
        banded_options: tolerances and linear-algebra route of the banded interior point.
        threads: with ``solver="banded-ip"``, joints solved at once in threads (the joints are
            independent, and LAPACK, the sparse products and numpy's loops release the GIL).
            Default 1, one after the other: one joint's interior point holds about 1.5 kB
            (state box) to 1.8 kB (trajectory mode) per sample, so one at a time it stays
            within the memory of one RTS pass over six joints (3.7 kB per sample), two at
            once do not (4.0 / 5.4 kB measured at N = 10⁵); two threads are up to ~1.7×
            faster on two idle cores. The result does not depend on it.

    Returns:
        OfflineCksResult; check ``is_success``. Invalid input raises ValueError.
    """
    if constraint not in OFFLINE_CONSTRAINTS:
        raise ValueError(f"constraint = {constraint!r} must be one of {OFFLINE_CONSTRAINTS}")
    if solver not in OFFLINE_SOLVERS:
        raise ValueError(f"solver = {solver!r} must be one of {OFFLINE_SOLVERS}")
    banded_options = banded_options if banded_options is not None else BandedIpOptions()
    if threads is not None:
        threads = check_positive_int("threads", threads)
    z = check_trajectory("measurements", measurements, num_joints=model.num_joints,
                         joint_names=joint_names, min_samples=2)
    num_samples, num_joints = z.shape
    names = list(joint_names) if joint_names is not None else [f"j{i}" for i in range(num_joints)]
    acc = as_per_joint("max_acceleration_rad_per_s2", max_acceleration, num_joints, names,
                       allow_inf=True)
    jerk = as_per_joint("max_jerk_rad_per_s3", max_jerk, num_joints, names, allow_inf=True)
    vel = (np.full(num_joints, np.inf) if max_velocity is None else
           as_per_joint("max_velocity_rad_per_s", max_velocity, num_joints, names, allow_inf=True))
    block_size = check_positive_int("block_size", block_size)
    prior = prior if prior is not None else rest_prior(z[0], model)
    q_start = z[0] if start_position is None else check_finite_per_joint(
        "start_position", start_position, num_joints, joint_names)

    dt = model.dt_s
    states = np.empty((num_samples, num_joints, 4))
    results, objective, solve_times, build_times, infeasible = [], [], [], [], []
    success = True
    clarabel = ClarabelSolver()
    options = SolverOptions()
    solvers_used = []
    ladder = tolerance_ladder(tolerance)
    reached = []

    def meets_the_limits(joint_states, j):
        return _limit_excess(joint_states, q_start[j], dt, acc[j], jerk[j], vel[j],
                             constraint, rest_at_end) == 0.0

    def solve_banded(j) -> dict:
        """Joint j by the banded IP, from the optimum without limits (the RTS smoother's,
        computed with the same banded factorisation; with ``rest_at_end`` the rest is in it).
        ckbs step 1: when that optimum meets every limit it is the optimum (result None).
        The objective is reported, as on the drake path, as the cost above the RTS
        smoother's (the optimum without limits and without the rest at the end)."""
        start = time.perf_counter()
        problem = banded_problem(z[:, j], model, j, prior, q_start[j], acc[j], jerk[j],
                                 vel[j], constraint, rest_at_end)
        a, c, f, lower, upper, fixed = problem
        shift = np.array([q_start[j], 0.0, 0.0, 0.0])
        qp = BandedQp(*problem, banded_options)
        built = time.perf_counter()

        def optimum_without_limits(qp_):
            try:
                y = qp_.unconstrained_optimum()
            except (LinAlgError, ValueError):
                return None
            return y if np.all(np.isfinite(y)) else None

        y_free = optimum_without_limits(qp)
        result = None
        if y_free is not None:
            free_states = model.from_scaled(y_free.reshape(num_samples, 4) + shift)
            if not meets_the_limits(free_states, j):
                result = qp.run(y_free)
        else:    # the interior point starts from rest and reports what goes wrong
            result = qp.run(np.zeros(4 * num_samples))
        y_rts = y_free
        if rest_at_end or y_free is None:
            y_rts = optimum_without_limits(BandedQp(
                a, c, f[:0], lower[:0], upper[:0], np.zeros_like(fixed), banded_options))
        if result is None:
            y, joint_states = y_free, free_states
        elif result.converged:
            y = result.y
            joint_states = model.from_scaled(y.reshape(num_samples, 4) + shift)
        else:
            y, joint_states = None, np.full((num_samples, 4), np.nan)
        cost = np.nan if y is None or y_rts is None else 0.5 * float(
            np.sum((a @ y - c) ** 2) - np.sum((a @ y_rts - c) ** 2))
        return dict(result=result, states=joint_states, objective=cost,
                    build_s=built - start, solve_s=time.perf_counter() - built)

    presolved = {}
    if solver == "banded-ip":
        workers = min(num_joints, threads or 1)
        if workers > 1:
            with _one_blas_thread(), ThreadPoolExecutor(max_workers=workers) as pool:
                presolved = dict(enumerate(pool.map(solve_banded, range(num_joints))))
    else:
        reference = model.to_scaled(rts_smoother(z, model, prior).mean)  # Y_RTS, (N, J, 4)
    for j in range(num_joints):
        infeasible.append(())
        if solver == "drake":
            rts_states = model.from_scaled(reference[:, j])
            rts_at_rest = not rest_at_end or not np.any(reference[-1, j, 1:])
            if rts_at_rest and meets_the_limits(rts_states, j):
                # ckbs step 1: the unconstrained optimum meets every limit: the optimum.
                states[:, j, :] = rts_states
                results.append("kSolutionFound")
                objective.append(0.0)
                solve_times.append(0.0)
                build_times.append(0.0)
                reached.append(0.0)
                continue
            solved = _solve_joint_drake(
                z[:, j], reference[:, j], model, j, names[j], prior, q_start[j], acc[j],
                jerk[j], vel[j], constraint, rest_at_end, block_size, clarabel, options, ladder)
            if solved["success"]:
                solvers_used.append(clarabel.solver_id().name())
                states[:, j, :] = solved["states"]
                results.append(solved["result"])
                objective.append(solved["objective"])
                solve_times.append(solved["solve_time"])
                build_times.append(solved["build_time"])
                reached.append(solved["tolerance"])
                continue
            fallback = (f"{clarabel.solver_id().name()} failed ({solved['result']}), "
                        "banded-ip fallback")
        else:
            fallback = None
        # The banded interior point: requested, or Clarabel failed on this joint.
        if j not in presolved:
            with _one_blas_thread():
                presolved[j] = solve_banded(j)
        banded = presolved[j]
        result = banded["result"]
        solvers_used.append(fallback or "banded-ip")
        build_times.append(banded["build_s"] + (solved["build_time"] if fallback else 0.0))
        solve_times.append(banded["solve_s"])
        states[:, j, :] = banded["states"]
        objective.append(banded["objective"])
        if result is None or result.converged:
            results.append("kSolutionFound")
            reached.append(0.0 if result is None else banded_options.primal_tolerance)
        else:
            success = False
            results.append(f"banded-ip: {result.status}")
            reached.append(np.nan)
            infeasible[-1] = solved["infeasible"] if fallback else ()
    return OfflineCksResult(
        states=states,
        is_success=success,
        solution_results=tuple(results),
        solver_name=", ".join(dict.fromkeys(solvers_used)) or (
            clarabel.solver_id().name() if solver == "drake" else "banded-ip"),
        objective=np.array(objective),
        solve_time_s=np.array(solve_times),
        build_time_s=np.array(build_times),
        infeasible_constraints=tuple(infeasible),
        tolerance_reached=np.array(reached),
    )


def _one_blas_thread():
    """BLAS (OpenBLAS) limited to one thread while the banded interior point runs.

    Its vectors and bands are long but its BLAS calls are small (dot products, the rank-1
    updates of a banded Cholesky with bandwidth 7 to 12): OpenBLAS's threads only wait on
    each other, and with the joints already in threads they compete for the same cores.
    Measured at N = 10⁵, one joint, the other core busy: 3.7 s with the default threads,
    1.7 s with one. The limit is process-wide for the duration of the solve.
    """
    return threadpool_limits(limits=1, user_api="blas")


def _solve_joint_drake(z, y_ref, model, j, name, prior, q_start, acc, jerk, vel, constraint,
                       rest_at_end, block_size, clarabel, options, ladder) -> dict:
    """One joint with the MathematicalProgram and Clarabel (tolerance ladder, back-off)."""
    dt = model.dt_s
    # Solve; then check the limits on the result itself and, if the solver's tolerance left a
    # violation above 1e-7 of a limit, tighten the limits by twice that and solve again (a
    # back-off), so that what is returned meets the limits it promises.
    shrink = 1.0
    build_time = 0.0
    solution = None
    for _attempt in range(4):
        start = time.perf_counter()
        prog, delta = _build_program(z, y_ref, model, j, name, prior, q_start, acc * shrink,
                                     jerk * shrink, vel * shrink, constraint, rest_at_end,
                                     block_size)
        build_time += time.perf_counter() - start
        # Without Ruiz equilibration first: with it Clarabel has reported kSolutionFound at
        # 1e-12 for a point 4e-4 rad from the optimum (cost 4e-6 too high, Δt = 0.1 s).
        for tol, equilibrate in ((tol, eq) for tol in ladder for eq in (False, True)):
            for key in ("tol_gap_abs", "tol_gap_rel", "tol_feas"):
                options.SetOption(clarabel.solver_id(), key, float(tol))
            options.SetOption(clarabel.solver_id(), "equilibrate_enable", equilibrate)
            result = clarabel.Solve(prog, None, options)
            if result.is_success():
                break
        if not result.is_success():
            break
        solution = model.from_scaled(y_ref + result.GetSolution(delta).T)
        excess = _limit_excess(solution, q_start, dt, acc, jerk, vel, constraint, rest_at_end)
        if excess <= 1e-7:
            break
        shrink *= 1.0 - 2.0 * excess
    success = bool(result.is_success())
    name = result.get_solution_result().name
    if success and excess > 1e-7:
        # Clarabel's answer still breaks a limit after the back-offs (a tolerance too loose
        # for the scale of the limits, e.g. j_max Δt³ ~ 1e-9 rad): not returned as a
        # solution; the caller solves the joint by the banded interior point instead.
        success, name = False, f"limits not met after the back-offs ({excess:.3g} over)"
    return {
        "success": success,
        "states": solution,
        "result": name,
        "objective": result.get_optimal_cost() if success else np.nan,
        "solve_time": result.get_solver_details().solve_time,
        "build_time": build_time,
        "tolerance": tol if success else np.nan,
        "infeasible": () if success else tuple(result.GetInfeasibleConstraintNames(prog)),
    }


def _limit_excess(states, q_start, dt, acc, jerk, vel, constraint, rest_at_end) -> float:
    """Largest relative excess max(|value| / limit − 1, 0) over the limits of ``constraint``,
    evaluated on one joint's states (N, 4) in physical units."""
    excess = 0.0

    def worst(values, limit):
        return float(np.max(np.abs(values)) / limit - 1.0) if np.isfinite(limit) and len(
            values) else 0.0

    if constraint in ("state", "both"):
        excess = max(excess, worst(states[:, 2], acc), worst(states[:, 3], jerk))
    if constraint in ("trajectory", "both"):
        extended = with_rest_history(states[:, 0], q_start,
                                     hold_at_end=HISTORY_LENGTH if rest_at_end else 0)
        for order, limit in ((1, vel), (2, acc), (3, jerk)):
            excess = max(excess, worst(np.diff(extended, n=order) / dt**order, limit))
    return max(excess, 0.0)


def _objective_gradient(z, y_ref, prior_mean, w0, w):
    """∇f at Y_RTS (N, 4) for one joint (scaled, ×r); ~0 up to the RTS round-off."""
    phi = SCALED_TRANSITION
    gradient = np.zeros_like(y_ref)
    gradient[:, 0] += y_ref[:, 0] - z  # measurement
    gradient[0] += w0 @ (y_ref[0] - prior_mean)  # prior
    residual = y_ref[1:] - y_ref[:-1] @ phi.T  # y_k − Φ̃ y_{k−1}
    weighted = residual @ w.T
    gradient[1:] += weighted
    gradient[:-1] -= weighted @ phi
    return gradient


def _build_program(z, y_ref, model, j, name, prior, q_start, acc, jerk, vel, constraint,
                   rest_at_end, block_size):
    """One joint's QP in δ = Y − Y_RTS; returns (program, δ (4, N) decision variables)."""
    num_samples = z.shape[0]
    dt = model.dt_s
    r = model.r[j]
    prog = MathematicalProgram()
    delta = prog.NewContinuousVariables(4, num_samples, f"dy_{name}")

    prior_mean = prior.mean[j] * model.scaling
    w0 = r * np.linalg.inv(model.cov_to_scaled(prior.cov[j]))
    w = r / (model.sigma[j] * dt**7) * UNIT_PROCESS_PRECISION
    # Linear term gᵀδ with g = ∇f(Y_RTS), one vectorised cost.
    gradient = _objective_gradient(z, y_ref, prior_mean, w0, w)
    prog.AddLinearCost(gradient.ravel(), 0.0, delta.T.ravel()).evaluator().set_description(
        f"gradient_at_rts_{name}")
    # ½ δ_0ᵀ (W_0 + e_0 e_0ᵀ) δ_0: the prior and the first measurement.
    h0 = w0.copy()
    h0[0, 0] += 1.0
    prog.AddCost(QuadraticCost(h0, np.zeros(4), 0.0, is_convex=True),
                 delta[:, 0]).evaluator().set_description(f"prior_{name}")
    # ½ (δ_k − Φ̃ δ_{k−1})ᵀ W (δ_k − Φ̃ δ_{k−1}) + ½ δ_k[0]², shared over blocks of states.
    difference = np.hstack([-SCALED_TRANSITION, np.eye(4)])
    pair_hessian = difference.T @ w @ difference
    shared = {}
    s = 1
    while s < num_samples:
        pairs = min(block_size, num_samples - s)
        if pairs not in shared:
            shared[pairs] = QuadraticCost(_block_hessian(pair_hessian, pairs),
                                          np.zeros(4 * (pairs + 1)), 0.0, is_convex=True)
        prog.AddCost(shared[pairs], delta[:, s - 1 : s + pairs].T.ravel())
        s += pairs

    if constraint in ("state", "both"):
        for row, limit, label in ((2, acc * dt**2, "acceleration"), (3, jerk * dt**3, "jerk")):
            if np.isfinite(limit):
                prog.AddBoundingBoxConstraint(-limit - y_ref[:, row], limit - y_ref[:, row],
                                              delta[row, :]).evaluator().set_description(
                    f"{label}_state_box_{name}")
    if constraint in ("trajectory", "both"):
        hold = HISTORY_LENGTH if rest_at_end else 0
        for order, limit, label in ((1, vel * dt, "velocity"), (2, acc * dt**2, "acceleration"),
                                    (3, jerk * dt**3, "jerk")):
            if not np.isfinite(limit):
                continue
            a, c = finite_difference_operator(num_samples, order, history=HISTORY_LENGTH,
                                              hold_at_end=hold)
            offset = c * q_start + a @ y_ref[:, 0]
            prog.AddLinearConstraint(a.tocsc(), -limit - offset, limit - offset,
                                     delta[0, :]).evaluator().set_description(
                f"fd_{label}_limit_{name}")
    if rest_at_end:
        target = -y_ref[-1, 1:]
        prog.AddBoundingBoxConstraint(target, target, delta[1:, num_samples - 1]).evaluator(
        ).set_description(f"rest_at_end_{name}")
    return prog, delta


def banded_problem(z, model: JerkModel, joint: int, prior: GaussianPrior, q_start: float, acc,
                   jerk, vel, constraint: str, rest_at_end: bool):
    """One joint's Offline-CKS in the form of :func:`~telesmooth.smoothing.banded_ip.
    solve_banded_qp`: ½‖A y − c‖² with l ≤ F y ≤ u and y[fixed] = 0.

    The same objective and limits as the MathematicalProgram of :func:`solve_offline_cks`, in
    the scaled state with every position shifted by ``q_start`` (so the committed rest history
    is zero); the limit rows are divided by their limit (bounds ±1).

    Returns:
        (A (rows, 4N) csr, c (rows,), F (m, 4N) csr, lower (m,), upper (m,), fixed (4N,) bool).
    """
    z = np.asarray(z, dtype=float)
    num_samples = z.shape[0]
    n = 4 * num_samples
    dt = model.dt_s
    r = model.r[joint]
    shift = np.array([q_start, 0.0, 0.0, 0.0])
    # A in CSR, written in place row by row (band-sized temporaries cost more in first touches
    # of memory than in arithmetic at N = 10⁶): N measurement rows y_k[0] (one entry each),
    # 4 prior rows (4 entries), 4 (N − 1) process rows (8 entries: blocks k − 1 and k).
    num_rows = num_samples + 4 + 4 * (num_samples - 1)
    nnz = num_samples + 16 + 32 * (num_samples - 1)
    index_type = np.int32 if max(nnz, n) < 2**31 else np.int64
    data = np.empty(nnz)
    indices = np.empty(nnz, dtype=index_type)
    indptr = np.empty(num_rows + 1, dtype=index_type)
    c = np.zeros(num_rows)
    # Measurements: y_k[0] = z_k − q_start, unit weight.
    data[:num_samples] = 1.0
    indices[:num_samples] = 4 * np.arange(num_samples, dtype=index_type)
    indptr[:num_samples + 1] = np.arange(num_samples + 1)
    c[:num_samples] = z - q_start
    # Prior: C_0 (y_0 − (T x̄_0 − shift)), W_0 = C_0ᵀ C_0 = r (T P_0 T)⁻¹.
    w0 = r * np.linalg.inv(model.cov_to_scaled(prior.cov[joint]))
    c0 = np.linalg.cholesky(0.5 * (w0 + w0.T)).T
    first = num_samples
    data[first:first + 16] = c0.ravel()
    indices[first:first + 16] = np.tile(np.arange(4), 4)
    indptr[num_samples + 1:num_samples + 5] = first + 4 * np.arange(1, 5)
    c[num_samples:num_samples + 4] = c0 @ (prior.mean[joint] * model.scaling - shift)
    # Process: C_W (y_k − Φ̃ y_{k−1}), W = r / (σ Δt⁷) Q1⁻¹ = C_Wᵀ C_W, k = 1 … N−1.
    w = r / (model.sigma[joint] * dt**7) * UNIT_PROCESS_PRECISION
    cw = np.linalg.cholesky(0.5 * (w + w.T)).T
    pair = cw @ np.hstack([-SCALED_TRANSITION, np.eye(4)])            # (4, 8)
    first += 16
    data[first:].reshape(num_samples - 1, 32)[:] = pair.ravel()
    np.add((4 * np.arange(num_samples - 1, dtype=index_type))[:, None],
           np.tile(np.arange(8, dtype=index_type), 4)[None, :],
           out=indices[first:].reshape(num_samples - 1, 32))
    indptr[num_samples + 5:] = first + 8 * np.arange(1, 4 * (num_samples - 1) + 1)
    a = sparse.csr_matrix((data, indices, indptr), shape=(num_rows, n))

    limit_rows = []
    if constraint in ("state", "both"):
        for component, limit in ((2, acc * dt**2), (3, jerk * dt**3)):
            if np.isfinite(limit):
                limit_rows.append(sparse.csr_matrix(
                    (np.full(num_samples, 1.0 / limit),
                     (np.arange(num_samples), 4 * np.arange(num_samples) + component)),
                    shape=(num_samples, n)))
    if constraint in ("trajectory", "both"):
        hold = HISTORY_LENGTH if rest_at_end else 0
        spread = sparse.csr_matrix((np.ones(num_samples),
                                    (np.arange(num_samples), 4 * np.arange(num_samples))),
                                   shape=(num_samples, n))
        for order, limit in ((1, vel * dt), (2, acc * dt**2), (3, jerk * dt**3)):
            if np.isfinite(limit):
                fd, _ = finite_difference_operator(num_samples, order, history=HISTORY_LENGTH,
                                                   hold_at_end=hold)
                limit_rows.append((fd @ spread) / limit)
    f = sparse.vstack(limit_rows).tocsr() if limit_rows else sparse.csr_matrix((0, n))
    fixed = np.zeros(n, dtype=bool)
    if rest_at_end:
        fixed[4 * (num_samples - 1) + 1:] = True
    return a, c, f, -np.ones(f.shape[0]), np.ones(f.shape[0]), fixed
