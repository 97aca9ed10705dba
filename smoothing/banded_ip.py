"""A structure-exploiting interior-point solver for Offline-CKS (docs/method.md §2.3, §2.5, §2.6).

Per joint the Offline-CKS problem is a least-squares objective with two-sided linear limits,

    minimise ½‖A y − c‖²   subject to   l ≤ F y ≤ u,   y_v = 0 for the fixed entries v,

over the scaled states y = [y_0; …; y_{N−1}] (4N values, y_k = T x_k). The rows of A are the
measurements (y_k[0] = z_k), the prior and the whitened process terms C_W (y_k − Φ̃ y_{k−1})
(the objective of docs/method.md §2.5, scaled by r). F holds, normalised by their limits so that
every bound is ±1, either the state box rows y_k[2] / (a_max Δt²), y_k[3] / (j_max Δt³) (the
paper's (11)) or the finite-difference rows of docs/method.md §2.6 on the positions, or both.
``rest_at_end`` fixes y_{N−1}[1:4] = 0. Positions are shifted by q_start first, so the committed
rest history contributes nothing to the rows and round-off does not grow with the joint angle.

Method: Mehrotra's predictor-corrector primal-dual interior point (the ckbs affine method of
docs/method.md §2.3 with a second-order corrector). Each Newton step solves

    (AᵀA + Fᵀ D F) Δy = b,    D = λ_u / s_u + λ_l / s_l,

whose matrix is banded: half-bandwidth 7 from the block-tridiagonal AᵀA, 12 with the third
differences of the positions (4 consecutive samples × 4 states). Two linear-algebra routes:

``"cholesky"``
    LAPACK banded Cholesky (``dpbtrf``, lower storage, called so that joints in threads run
    at once: :mod:`~telesmooth.smoothing.lapack_banded`), O(N·b²) per step with no Python
    loop over samples. Accurate while AᵀA is well conditioned (Δt ≳ 0.05 s with the
    docs/method.md §8 σ and r: cond ≈ 5e7 at 4 Hz).
``"qr"``
    A sequential banded QR of the whitened rows [A; √D F] (a square-root information
    smoother): it never forms the normal equations, so its accuracy depends on cond(A) rather
    than cond(A)². At Δt = 0.01 s cond(AᵀA) ≈ 1e17 and the Cholesky factorisation breaks down
    (not positive definite, or garbage), while the QR route still solves to ~1e-8. One small
    dense QR per sample: O(N) Python steps per Newton step.
``"auto"`` (default)
    Cholesky when the ratio of the largest to the smallest pivot of chol(AᵀA) squared is below
    1e12, else QR.

Every joint is solved independently; failures are reported per joint, never raised.
"""

from __future__ import annotations

import dataclasses
import functools
import math

import numpy as np
import scipy.sparse as sparse
from scipy.linalg import LinAlgError, solve_banded

from telesmooth.smoothing.lapack_banded import cholesky_lower_band, solve_lower_band

__all__ = ["BandedIpOptions", "BandedIpResult", "BandedQp", "LINEAR_SOLVERS", "solve_banded_qp"]

LINEAR_SOLVERS = ("auto", "cholesky", "qr")

# ``auto`` uses Cholesky while (max pivot / min pivot)² of chol(AᵀA) stays below this.
_CHOLESKY_CONDITION_LIMIT = 1e12
# Fraction of the distance to the boundary a step may go.
_STEP_FRACTION = 0.99
_START_MULTIPLIER = 0.01
# An iterate within this factor of the gap tolerance is accepted when the Cholesky route
# breaks down on the next step, or when the iteration ends without converging after it
# (see ``run``).
_ACCEPTABLE_GAP_FACTOR = 10.0
# Rows per chunk where a pass over a whole matrix would allocate large temporaries.
_CHUNK_ROWS = 1 << 15
# Rows per chunk of _gram_band (each row of A pairs up to 36 entries: 1 << 13 rows keep its
# temporaries near 10 MB).
_GRAM_CHUNK_ROWS = 1 << 13
# A Newton step is refined while its stationarity residual exceeds this share of the dual
# residual it corrects, at most this many times (``BandedQp._refine``).
_REFINEMENT_RATIO = 1e-2
_MAX_REFINEMENTS = 3
# Relative round-off allowed in a limit row's value F y (see ``run``).
_PRIMAL_ROUND_OFF = 1e-13


@dataclasses.dataclass(frozen=True)
class BandedIpOptions:
    """Tolerances of the interior-point method.

    Attributes:
        primal_tolerance: max violation of a normalised row (a fraction of its limit), or
            1e-13 of the row's terms |F||y| when that round-off floor is larger.
        gap_tolerance: mean complementarity sᵀλ / m. The objective is flat along some
            directions, and this tolerance sets how far the positions can be from the
            optimum: measured against the MathematicalProgram (Clarabel at 1e-12) on the
            benchmark's recordings, 6 joints, the largest position difference was
            1.1e-6 / 7.9e-7 rad (N = 10³ / 10⁴, trajectory mode) with 1e-14, 1.9e-7 /
            2.5e-7 with 1e-15 (the default; ~5 % more Newton steps) and 6e-9 / 6e-8 with
            1e-16. The dual tolerance did not change it. Late in the iterations the normal
            equations can lose definiteness in floating point; an iterate that already meets
            10× this tolerance (and the others) is then returned instead of continuing by the
            much slower QR route. It is also returned, the best such iterate, when the steps
            after it lose ground and the iteration ends without converging (seen on
            degenerate active sets: the dual residual grows again as the gap collapses).
        dual_tolerance: ‖∇ Lagrangian‖∞ relative to the size of its terms (round-off leaves
            ~1e-9 at 4 Hz, docs/method.md §2.3 notes, in the absolute gradient; this relative
            measure reaches 1e-10).
        max_iterations: Newton steps before giving up (200). With the Newton steps refined
            (``BandedQp._refine``) all 630 joints of the offline-hard problems of the 210
            LASA demonstrations at 4× the hand's speed converge: median 13 steps, 99th
            percentile 17–20, but the slowest joint depends on the BLAS's last bits: 90
            (Zshape/6), 65 (BendedLine/2) and 122 (LShape/0) steps with OpenBLAS's
            SkylakeX, Sandybridge and Haswell kernels, a different problem each time.
            Unrefined, 16 of them need more than 200 steps (BendedLine/1's wrist 258) and
            BendedLine/2's shoulder does not converge in 1000.
        linear_solver: "auto", "cholesky" or "qr" (module docstring).
    """

    primal_tolerance: float = 1e-10
    gap_tolerance: float = 1e-15
    dual_tolerance: float = 1e-10
    max_iterations: int = 200
    linear_solver: str = "auto"

    def __post_init__(self) -> None:
        for name in ("primal_tolerance", "gap_tolerance", "dual_tolerance"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ValueError(f"BandedIpOptions.{name} = {value!r} must be positive")
        if isinstance(self.max_iterations, bool) or not isinstance(self.max_iterations, int) \
                or self.max_iterations < 1:
            raise ValueError(f"BandedIpOptions.max_iterations = {self.max_iterations!r} must "
                             "be a positive integer")
        if self.linear_solver not in LINEAR_SOLVERS:
            raise ValueError(f"BandedIpOptions.linear_solver = {self.linear_solver!r} must be "
                             f"one of {LINEAR_SOLVERS}")


@dataclasses.dataclass(frozen=True, eq=False)
class BandedIpResult:
    """Solution of one joint's problem.

    Attributes:
        y: the solution (4N,); NaN when not converged.
        converged: whether every tolerance was met.
        status: "converged", "max_iterations" or "numerical_failure: …".
        iterations: Newton steps taken.
        linear_solver: the route used ("cholesky" or "qr").
        primal_residual, gap, dual_residual: the final measures.
        multipliers: λ_u − λ_l per row of F (positive where the upper limit is active).
    """

    y: np.ndarray
    converged: bool
    status: str
    iterations: int
    linear_solver: str
    primal_residual: float
    gap: float
    dual_residual: float
    multipliers: np.ndarray


def _gram_band(rows: sparse.csr_matrix, half_bandwidth: int) -> np.ndarray:
    """Lower band storage band[j, i − j] = (MᵀM)[i, j] (j ≤ i ≤ j + u) of the Gram matrix
    of M's rows, shape (n, u + 1), the layout of :mod:`~telesmooth.smoothing.lapack_banded`
    (LAPACK's banded Cholesky is about twice as fast on the lower storage as on the upper
    one, measured at N = 10⁵).

    MᵀM is never formed: each row with entries v_a (column c_a) adds v_a·v_b at
    (max(c_a, c_b), min(c_a, c_b)) for every pair a ≤ b of its entries, summed chunk by chunk
    of rows (the product's CSR form would be ~1.4× M, and its temporaries more).
    ``half_bandwidth`` must be at least the widest row's span (c_max − c_min).
    """
    rows = sparse.csr_matrix(rows)
    if not rows.has_canonical_format:      # a repeated column would pair with itself
        rows = rows.copy()
        rows.sum_duplicates()
    n = rows.shape[1]
    width = half_bandwidth + 1
    band = np.zeros(n * width)
    indptr, indices, data = rows.indptr, rows.indices, rows.data
    counts = np.diff(indptr)
    for start in range(0, rows.shape[0], _GRAM_CHUNK_ROWS):
        stop = min(rows.shape[0], start + _GRAM_CHUNK_ROWS)
        chunk_counts = counts[start:stop]
        first_entry = indptr[start:stop]
        most = int(chunk_counts.max(initial=0))
        flat_parts, value_parts = [], []
        for first in range(most):
            for second in range(first, most):
                with_pair = np.flatnonzero(chunk_counts > second)
                entry_a = first_entry[with_pair] + first
                entry_b = first_entry[with_pair] + second
                col_a, col_b = indices[entry_a], indices[entry_b]
                low = np.minimum(col_a, col_b)
                flat_parts.append(low.astype(np.int64) * width + np.abs(col_a - col_b))
                value_parts.append(data[entry_a] * data[entry_b])
        if not flat_parts:
            continue
        flat = np.concatenate(flat_parts)
        # The pairs of these rows fall in columns [min, max] of the chunk's entries.
        base = int(flat.min())
        local = np.bincount(flat - base, weights=np.concatenate(value_parts))
        band[base:base + local.size] += local
    return band.reshape(n, width)


def _half_bandwidth(a: sparse.csr_matrix, f: sparse.csr_matrix) -> int:
    """Half-bandwidth of AᵀA + Fᵀ D F: the widest row of A or of F (a row with entries in
    columns i and j puts an entry at (i, j) of its Gram matrix)."""
    width = 0
    for rows in (a, f):
        nonempty = np.diff(rows.indptr) > 0
        if np.any(nonempty):
            first = np.minimum.reduceat(rows.indices, rows.indptr[:-1][nonempty])
            last = np.maximum.reduceat(rows.indices, rows.indptr[:-1][nonempty])
            width = max(width, int(np.max(last - first)))
    return width


class BandedQp:
    """One joint's problem (A, c, F, l, u, fixed) prepared once: its optimum without the
    limits (:meth:`unconstrained_optimum`) and the interior point (:meth:`run`) share the
    banded structure. :func:`solve_banded_qp` is the one-call form."""

    def __init__(self, a, c, f, lower, upper, fixed, options: BandedIpOptions):
        self.a = sparse.csr_matrix(a)
        self.c = np.asarray(c, dtype=float)
        self.f = sparse.csr_matrix(f)
        self.lower = np.asarray(lower, dtype=float)
        self.upper = np.asarray(upper, dtype=float)
        self.fixed = np.asarray(fixed, dtype=bool)
        self.free = ~self.fixed
        self.options = options
        self.n = self.a.shape[1]
        self.m = self.f.shape[0]
        # Aᵀ as a view (CSC, sharing A's arrays): a row-compressed copy would make its
        # products gather instead of scatter, but costs as much memory as A. F is small.
        self.a_t = self.a.T
        self.f_t = self.f.T.tocsr()
        self.half_bandwidth = _half_bandwidth(self.a, self.f)
        self._normal_factor = None
        if options.linear_solver != "qr":
            self._prepare_cholesky()
        self.route = self._choose_route(options.linear_solver)
        if self.route == "qr":
            self._prepare_qr()

    # -- routes -------------------------------------------------------------------------

    def _prepare_cholesky(self) -> None:
        """Band storage of AᵀA and, per pair of entries of each row of F, where D_i v_a v_b
        goes in the band, so that each Newton step assembles its band with one sparse
        product and a scatter."""
        u = self.half_bandwidth
        n = self.n
        width = u + 1
        # Fixed variables: their rows and columns zero, a unit diagonal.
        keep = np.ones((n, width), dtype=bool)
        for offset in range(width):
            keep[:, offset][self.fixed] = False                        # M[v + offset, v]
            keep[:n - offset, offset][self.fixed[offset:]] = False     # M[v, v − offset]
        # AᵀA is needed only as a band (the sparse product is dropped once it is stored: its
        # CSR form is ~1.4× A), and that band is kept in compressed form: a time-invariant
        # model gives every sample the same rows.
        normal_band = _gram_band(self.a, u)
        normal_band *= keep
        normal_band[self.fixed, 0] = 1.0
        self._normal_band = _RepeatingBand(normal_band)
        # One buffer for every Newton step's band (a fresh 25 MB array per step cost ~15 ms
        # in page faults at N = 10⁵).
        self._band_buffer = np.empty_like(normal_band)
        del normal_band
        f = self.f
        counts = np.diff(f.indptr)
        most = int(counts.max(initial=0))
        rows_all, flat_all, coef_all = [], [], []
        for first in range(most):
            for second in range(first, most):
                rows = np.flatnonzero(counts > second)
                col_a = f.indices[f.indptr[rows] + first]
                col_b = f.indices[f.indptr[rows] + second]
                value = f.data[f.indptr[rows] + first] * f.data[f.indptr[rows] + second]
                low, high = np.minimum(col_a, col_b), np.maximum(col_a, col_b)
                rows_all.append(rows)
                flat_all.append(low * width + (high - low))
                coef_all.append(value)
        pair_rows = np.concatenate(rows_all) if rows_all else np.zeros(0, dtype=int)
        pair_flat = np.concatenate(flat_all) if flat_all else np.zeros(0, dtype=int)
        pair_coef = np.concatenate(coef_all) if coef_all else np.zeros(0)
        # Entries that fall on a fixed row or column are dropped.
        on_kept = keep.ravel()[pair_flat]
        pair_rows, pair_flat, pair_coef = (pair_rows[on_kept], pair_flat[on_kept],
                                           pair_coef[on_kept])
        # Band positions touched by F (a few per sample) and the sparse map from the row
        # weights D to their entries: the band is assembled by one sparse product and a
        # scatter (a bincount over the whole band cost ~45 ms per step at N = 10⁵).
        touched = np.zeros(width * n, dtype=bool)
        touched[pair_flat] = True
        self.pair_positions = np.flatnonzero(touched)
        self.pair_map = sparse.csr_matrix(
            (pair_coef, (np.searchsorted(self.pair_positions, pair_flat), pair_rows)),
            shape=(self.pair_positions.size, self.m))

    @property
    def normal_band(self) -> np.ndarray:
        """Band storage of AᵀA with the fixed rows masked (a new array)."""
        return self._normal_band.expand(np.empty_like(self._band_buffer))

    def _band(self, weights) -> np.ndarray:
        """Band storage of AᵀA + Fᵀ diag(weights) F with the fixed rows masked, written into
        the one band buffer: the band, or the factor made from it, is valid until the next
        call."""
        self._normal_factor = None      # it lives in this buffer
        band = self._normal_band.expand(self._band_buffer)
        band.ravel()[self.pair_positions] += self.pair_map @ weights
        return band

    def _choose_route(self, requested: str) -> str:
        if requested != "auto":
            return requested
        try:
            # Factorised in the band buffer: valid until the next _band (the first Newton
            # step), which is after the solve without limits that reuses it.
            factor = cholesky_lower_band(self._band(np.zeros(self.m)), overwrite=True)
        except LinAlgError:
            return "qr"
        self._normal_factor = factor    # reused by the solve without limits
        pivots = np.abs(factor[:, 0])
        if not np.all(np.isfinite(pivots)) or pivots.min() <= 0.0:
            return "qr"
        ratio = (pivots.max() / pivots.min()) ** 2
        return "cholesky" if ratio < _CHOLESKY_CONDITION_LIMIT else "qr"

    def _prepare_qr(self) -> None:
        """Row windows for the sequential QR: each row's values in the 4-column-aligned window
        that starts at its first nonzero's block."""
        rows = sparse.vstack([self.a, self.f]).tocsr()
        rows.sort_indices()
        rows = rows[np.diff(rows.indptr) > 0]
        first = rows.indices[rows.indptr[:-1]]
        last = rows.indices[rows.indptr[1:] - 1]
        block = first // 4
        width = int(np.max(last - 4 * block)) + 1
        self.qr_width = 4 * math.ceil(width / 4)
        num_rows = rows.shape[0]
        window = np.zeros((num_rows, self.qr_width))
        row_of_entry = np.repeat(np.arange(num_rows), np.diff(rows.indptr))
        window[row_of_entry, rows.indices - 4 * block[row_of_entry]] = rows.data
        # Fixed variables: their columns dropped from every row; identity rows added per block.
        on_fixed = self.fixed[rows.indices]
        window[row_of_entry[on_fixed], (rows.indices - 4 * block[row_of_entry])[on_fixed]] = 0.0
        # Row i of the stack is row source[i] of A (is_f False) or of F (is_f True).
        a_nonempty = np.flatnonzero(np.diff(self.a.indptr) > 0)
        f_nonempty = np.flatnonzero(np.diff(self.f.indptr) > 0)
        is_f = np.arange(num_rows) >= a_nonempty.size
        source = np.concatenate([a_nonempty, f_nonempty])
        order = np.argsort(block, kind="stable")
        self.qr_window = window[order]
        self.qr_is_f = is_f[order]
        self.qr_a_row = np.where(is_f, -1, source)[order]
        self.qr_f_index = np.where(is_f, source, -1)[order]
        num_blocks = self.n // 4
        self.qr_starts = np.searchsorted(block[order], np.arange(num_blocks + 1))

    def factorize(self, weights, switch_to_qr: bool = True):
        """Factorises AᵀA + Fᵀ diag(weights) F; returns solve(rhs_a, rhs_f) → Δ (n,) with
        (AᵀA + Fᵀ D F) Δ = Aᵀ rhs_a + Fᵀ rhs_f on the free entries and Δ = 0 on the fixed.
        When the Cholesky route breaks down it tries a regularised factor and then goes on
        by the QR route; with ``switch_to_qr=False`` it raises LinAlgError at once."""
        if self.route == "cholesky":
            try:
                return self._cholesky_solver(weights, regularise=switch_to_qr)
            except LinAlgError:
                if not switch_to_qr:
                    raise
                self._switch_to_qr()
        return lambda rhs_a, rhs_f, at_rhs_a=None: self._solve_qr(weights, rhs_a, rhs_f)

    def _switch_to_qr(self) -> None:
        """Late in the iterations λ/s of the active rows grows without bound and the normal
        equations lose definiteness in floating point; the square-root route does not form
        them. The rest of the solve continues with it."""
        self.route = "cholesky+qr"
        self._prepare_qr()

    def _cholesky_solver(self, weights, regularise: bool = True):
        try:
            if self._normal_factor is not None and not np.any(weights):
                factor = self._normal_factor     # AᵀA alone, factorised by _choose_route
                self._normal_factor = None       # used once (the start); a band's memory
            else:
                factor = cholesky_lower_band(self._band(weights), overwrite=True)
            shifted = False
        except LinAlgError:
            if not regularise:
                raise
            # Static regularisation: factor M + εI, then conjugate gradients on M with that
            # factor as the preconditioner.
            band = self._band(weights)
            shift = 1e-12 * float(np.max(band[:, 0]))
            for _ in range(6):
                trial = band.copy()
                trial[self.free, 0] += shift
                try:
                    factor = cholesky_lower_band(trial, overwrite=True)
                    break
                except LinAlgError:
                    shift *= 100.0
            else:
                raise
            shifted = True

        def apply(v):
            out = self.normal @ v + self.f_t @ (weights * (self.f @ v))
            out[self.fixed] = 0.0
            return out

        def precondition(v):
            out = solve_lower_band(factor, v)
            out[self.fixed] = 0.0
            return out

        def solve(rhs_a, rhs_f, at_rhs_a=None):
            b = (self.a_t @ rhs_a if at_rhs_a is None else at_rhs_a) + self.f_t @ rhs_f
            b[self.fixed] = 0.0
            x = precondition(b)
            if not shifted:
                # No iterative refinement: every iteration measures its residuals from the
                # iterate itself, so an inexact step can slow the method but never make it
                # report a wrong point as converged. Measured with and without one step of
                # refinement (N = 2000 at Δt = 0.25, 0.1, 0.05 s, and N = 10⁵ at 0.25 s, both
                # modes): the same iteration counts, positions equal to 1e-9 rad, ~20 % less
                # time.
                return x
            residual = b - apply(x)
            norm_b = float(np.max(np.abs(b))) or 1.0
            direction = precondition(residual)
            rho = residual @ direction
            for _ in range(50):
                if np.max(np.abs(residual)) <= 1e-13 * norm_b:
                    return x
                product = apply(direction)
                curvature = direction @ product
                if not curvature > 0.0:
                    break
                step = rho / curvature
                x = x + step * direction
                residual = residual - step * product
                preconditioned = precondition(residual)
                rho, previous = residual @ preconditioned, rho
                direction = preconditioned + (rho / previous) * direction
            if np.max(np.abs(residual)) <= 1e-9 * norm_b:
                return x
            raise LinAlgError("regularised Cholesky + CG did not reach the Newton step")

        return solve

    def _solve_qr(self, weights, rhs_a, rhs_f):
        # Row i of F weighted by √D_i with right-hand side rhs_f,i / √D_i has the normal
        # equations of the Newton step; rows of A keep their weight.
        root = np.sqrt(weights)
        is_f = self.qr_is_f
        scale = np.ones(is_f.size)
        values = np.empty(is_f.size)
        values[~is_f] = rhs_a[self.qr_a_row[~is_f]]
        f_rows = self.qr_f_index[is_f]
        scale[is_f] = root[f_rows]
        with np.errstate(divide="ignore", invalid="ignore"):
            values[is_f] = np.where(root[f_rows] > 0.0, rhs_f[f_rows] / root[f_rows], 0.0)
        window = self.qr_window * scale[:, None]
        width = self.qr_width
        num_blocks = self.n // 4
        factor_rows = np.zeros((self.n, width))
        factor_rhs = np.zeros(self.n)
        carry = np.zeros((0, width + 1))
        for b in range(num_blocks):
            lo, hi = self.qr_starts[b], self.qr_starts[b + 1]
            new = np.hstack([window[lo:hi], values[lo:hi, None]])
            fixed_here = np.flatnonzero(self.fixed[4 * b: 4 * b + 4])
            identity = np.zeros((fixed_here.size, width + 1))
            identity[np.arange(fixed_here.size), fixed_here] = 1.0
            stacked = np.vstack([carry, new, identity])
            r = np.linalg.qr(stacked, mode="r")
            if r.shape[0] < 4:
                r = np.vstack([r, np.zeros((4 - r.shape[0], width + 1))])
            factor_rows[4 * b: 4 * b + 4] = r[:4, :width]
            factor_rhs[4 * b: 4 * b + 4] = r[:4, width]
            rest = r[4:width, 4:]
            carry = np.zeros((rest.shape[0], width + 1))
            carry[:, :width - 4] = rest[:, :width - 4]
            carry[:, width] = rest[:, width - 4]
        diagonal = factor_rows[np.arange(self.n), np.arange(self.n) % 4]
        if not np.all(np.isfinite(diagonal)) or np.min(np.abs(diagonal)) == 0.0:
            raise LinAlgError("the whitened rows are rank deficient")
        # Upper-triangular band: ab[u + i − j, j] = R[i, j], u = width − 1.
        u = width - 1
        band = np.zeros((u + 1, self.n))
        rows = np.repeat(np.arange(self.n), width)
        cols = (4 * (rows // 4)) + np.tile(np.arange(width), self.n)
        inside = (cols < self.n) & (cols >= rows)
        band[u + rows[inside] - cols[inside], cols[inside]] = factor_rows.ravel()[inside]
        return solve_banded((0, u), band, factor_rhs)

    # -- the interior-point method ----------------------------------------------------------

    def run(self, y0) -> BandedIpResult:
        opts = self.options
        y = np.array(y0, dtype=float)
        y[self.fixed] = 0.0
        m = self.m
        if m == 0:
            return self._unconstrained(y)
        fy = self.f @ y
        # Start: slacks at least 1 (the rows are normalised to ±1), multipliers 0.01. With
        # multipliers 1 the method took ~14 % more iterations (182 against 157 Newton steps
        # over 6 joints × 2 modes at N = 10⁴; 16–17 against 14–15 per joint at N = 10⁵).
        s_u = np.maximum(self.upper - fy, 1.0)
        s_l = np.maximum(fy - self.lower, 1.0)
        lam_u = np.full(m, _START_MULTIPLIER)
        lam_l = np.full(m, _START_MULTIPLIER)
        status, iteration = "max_iterations", 0
        measures = (math.inf, math.inf, math.inf)
        best_acceptable = None
        for iteration in range(1, opts.max_iterations + 1):
            fy = self.f @ y
            residual_a = self.a @ y - self.c
            r_pu = fy + s_u - self.upper
            r_pl = -fy + s_l + self.lower
            gradient = self.a_t @ residual_a
            r_d = gradient + self.f_t @ (lam_u - lam_l)
            r_d[self.fixed] = 0.0
            gap = (s_u @ lam_u + s_l @ lam_l) / (2 * m)
            primal = max(np.max(np.abs(r_pu)), np.max(np.abs(r_pl)))
            measures = (primal, gap, math.nan)
            # The primal round-off floor and the dual measure cost four matrix-vector
            # products: computed only once the gap is nearly met (the last few iterations).
            acceptable = False
            if gap <= _ACCEPTABLE_GAP_FACTOR * opts.gap_tolerance:
                measures = (primal, gap, self._dual_measure(y, r_d, lam_u, lam_l))
                if (primal <= max(opts.primal_tolerance, self._primal_floor(y))
                        and measures[2] <= opts.dual_tolerance):
                    if gap <= opts.gap_tolerance:
                        status = "converged"
                        iteration -= 1
                        break
                    acceptable = True
                    if best_acceptable is None or gap < best_acceptable[-1][1]:
                        best_acceptable = (y, s_u, s_l, lam_u, lam_l, iteration - 1, measures)
            weights = lam_u / s_u + lam_l / s_l
            # A Newton step solves its stationarity equation to about ε‖M‖‖Δy‖, M = AᵀA +
            # FᵀDF (measured on the offline-hard problems: 0.01–1.7 × this estimate): it is
            # refined (``_refine``) once that can reach 1 % of the dual residual it corrects
            # and that residual's round-off floor. Checking every step instead would cost
            # three more products (~20 % of the time at N = 10⁴); early steps' errors are
            # ~1e-9 of r_d.
            step_error_scale = np.finfo(float).eps * (
                self._norms[0] + float(np.max(self._f_squared_t @ weights)))
            refine_above = max(_REFINEMENT_RATIO * float(np.max(np.abs(r_d))),
                               self._dual_round_off(y, lam_u + lam_l))
            # Within 10× of the gap tolerance (``acceptable``): if the normal equations break
            # down now (λ/s of the active rows ~1e15), stop here rather than finish by the QR
            # route (a Python loop over the samples: 3.7 s instead of 0.6 s at N = 10⁴).
            stop_here = acceptable and self.route == "cholesky"
            try:
                solve = self.factorize(weights, switch_to_qr=not stop_here)

                def newton(rc_u, rc_l):
                    w_u = (lam_u * r_pu - rc_u) / s_u
                    w_l = (lam_l * r_pl - rc_l) / s_l
                    rhs_f = -(lam_u + w_u) + (lam_l + w_l)
                    try:
                        solver = solve
                        dy = solver(-residual_a, rhs_f, -gradient)
                    except LinAlgError:
                        if self.route == "qr" or stop_here:
                            raise   # stop_here: the iterate is accepted below
                        # The regularised factor could not reach this right-hand side (in
                        # the predictor, or again in the corrector of the same iteration,
                        # which shares the factor): the square-root route from here on.
                        if self.route == "cholesky":
                            self._switch_to_qr()
                        def solver(rhs_a, rhs_f, at_rhs_a=None):
                            return self._solve_qr(weights, rhs_a, rhs_f)

                        dy = solver(-residual_a, rhs_f)
                    dfy = self.f @ dy
                    ds_u = -r_pu - dfy
                    ds_l = -r_pl + dfy
                    dl_u = -(rc_u + lam_u * ds_u) / s_u
                    dl_l = -(rc_l + lam_l * ds_l) / s_l
                    if step_error_scale * float(np.max(np.abs(dy))) <= refine_above:
                        return dy, ds_u, ds_l, dl_u, dl_l
                    return self._refine(solver, (dy, ds_u, ds_l, dl_u, dl_l), residual_a,
                                        refine_above, lam_u - lam_l, (lam_u / s_u, lam_l / s_l))

                # Predictor (affine scaling).
                step = newton(s_u * lam_u, s_l * lam_l)
                alpha = _max_step((s_u, s_l, lam_u, lam_l), step[1:])
                gap_affine = ((s_u + alpha * step[1]) @ (lam_u + alpha * step[3])
                              + (s_l + alpha * step[2]) @ (lam_l + alpha * step[4])) / (2 * m)
                centering = (gap_affine / gap) ** 3 if gap > 0 else 0.0
                # Corrector with centring.
                step = newton(s_u * lam_u + step[1] * step[3] - centering * gap,
                              s_l * lam_l + step[2] * step[4] - centering * gap)
            except LinAlgError as error:
                if stop_here:     # the unregularised factorisation broke down: accept
                    status = "converged"
                    iteration -= 1
                else:
                    status = f"numerical_failure: {error}"
                break
            except ValueError as error:
                status = f"numerical_failure: {error}"
                break
            if not all(np.all(np.isfinite(part)) for part in step):
                status = "numerical_failure: non-finite Newton step"
                break
            alpha = min(1.0, _STEP_FRACTION * _max_step((s_u, s_l, lam_u, lam_l), step[1:]))
            y = y + alpha * step[0]
            s_u = s_u + alpha * step[1]
            s_l = s_l + alpha * step[2]
            lam_u = lam_u + alpha * step[3]
            lam_l = lam_l + alpha * step[4]
        if status != "converged" and best_acceptable is not None:
            # An iterate met every tolerance but the gap, which it met to 10×, and the steps
            # after it lost ground (seen on degenerate active sets, where the dual residual
            # grows again as the gap collapses): that iterate is the answer.
            y, s_u, s_l, lam_u, lam_l, iteration, measures = best_acceptable
            status = "converged"
        converged = status == "converged"
        if not converged:
            # The measures of the iterate returned (the loop's are one step older).
            fy = self.f @ y
            r_d = self.a_t @ (self.a @ y - self.c) + self.f_t @ (lam_u - lam_l)
            r_d[self.fixed] = 0.0
            measures = (max(np.max(np.abs(fy + s_u - self.upper)),
                            np.max(np.abs(-fy + s_l + self.lower))),
                        (s_u @ lam_u + s_l @ lam_l) / (2 * m),
                        self._dual_measure(y, r_d, lam_u, lam_l))
        return BandedIpResult(
            y=y if converged else np.full_like(y, np.nan), converged=converged, status=status,
            iterations=iteration, linear_solver=self.route, primal_residual=float(measures[0]),
            gap=float(measures[1]), dual_residual=float(measures[2]),
            multipliers=lam_u - lam_l)

    def _refine(self, solve, step, residual_a, target, multipliers, ratios):
        """Iterative refinement of a Newton step on the full system.

        The slack and multiplier parts of a step are recovered from Δy row by row
        (Δλ = −(r_c + λ Δs) / s), which multiplies the round-off of FΔy by λ/s. Late in the
        iterations λ/s of the active rows reaches 1e8–1e12 and the step no longer solves the
        stationarity equation Δy' + Fᵀ(Δλ_u − Δλ_l) = −r_d (Δy' = AᵀAΔy): its residual
        overtakes r_d itself, the dual residual grows again as the gap collapses, and the
        method stalls (BendedLine/2 at 4× the hand's speed: the dual measure rose from 1e-11
        to 1e-8 within three steps, and 1000 steps did not recover it). The residual of that
        equation is of the form Aᵀr_a + Fᵀr_f, so each route solves the correction with the
        factor it already has; the slack and multiplier parts follow from the corrected Δy
        exactly as above. Refined while the residual exceeds ``target`` (1 % of the dual
        residual) and each correction shrinks it, at most three times.
        """
        ratio_u, ratio_l = ratios

        def stationarity(candidate):
            dy, _, _, dl_u, dl_l = candidate
            rhs_a = -(residual_a + self.a @ dy)
            rhs_f = -multipliers - (dl_u - dl_l)
            at_rhs_a = self.a_t @ rhs_a
            residual = at_rhs_a + self.f_t @ rhs_f
            residual[self.fixed] = 0.0
            return rhs_a, rhs_f, at_rhs_a, float(np.max(np.abs(residual)))

        rhs_a, rhs_f, at_rhs_a, size = stationarity(step)
        for _ in range(_MAX_REFINEMENTS):
            if size <= target:
                break
            try:
                correction = solve(rhs_a, rhs_f, at_rhs_a)
            except LinAlgError:
                break
            dy, ds_u, ds_l, dl_u, dl_l = step
            d_fy = self.f @ correction
            candidate = (dy + correction, ds_u - d_fy, ds_l + d_fy,
                         dl_u + ratio_u * d_fy, dl_l - ratio_l * d_fy)
            rhs_a, rhs_f, at_rhs_a, candidate_size = stationarity(candidate)
            if not candidate_size < size:
                break                   # the factor is too inaccurate to refine with
            step, size = candidate, candidate_size
        return step

    @functools.cached_property
    def normal(self) -> sparse.csr_matrix:
        """AᵀA as a sparse matrix: formed only if a Newton step needs the regularised
        factorisation (conjugate gradients on it); the band is all the other steps use."""
        return (self.a.T.tocsr() @ self.a).tocsr()

    @functools.cached_property
    def abs_f(self) -> sparse.csr_matrix:
        return abs(self.f)

    def _primal_floor(self, y) -> float:
        """F y sums terms of size |F||y| (~5e5 for a jerk row at 100 Hz): its round-off,
        ~5e-16 of that, is a floor no iteration can go below."""
        return _PRIMAL_ROUND_OFF * float(np.max(self.abs_f @ np.abs(y)))

    @functools.cached_property
    def _norms(self):
        """(max diag AᵀA, ‖A‖₁, ‖A‖∞, ‖c‖∞, ‖F‖₁): column sums of A's squares, absolute
        column and row sums, chunk by chunk of A's rows (|A| is never stored whole)."""
        columns = np.zeros(self.n)
        squares = np.zeros(self.n)
        rows = 0.0
        for start in range(0, self.a.shape[0], _CHUNK_ROWS):
            chunk = abs(self.a[start:start + _CHUNK_ROWS])
            columns += np.asarray(chunk.sum(axis=0)).ravel()
            squares += np.asarray(chunk.multiply(chunk).sum(axis=0)).ravel()
            rows = max(rows, float(np.max(np.asarray(chunk.sum(axis=1)), initial=0.0)))
        f_columns = np.asarray(self.abs_f.sum(axis=0)).ravel()
        return (float(np.max(squares[self.free], initial=0.0)),
                float(np.max(columns, initial=0.0)), rows,
                float(np.max(np.abs(self.c), initial=0.0)),
                float(np.max(f_columns, initial=0.0)))

    def _dual_round_off(self, y, lam_sum) -> float:
        """ε (‖A‖₁(‖A‖∞‖y‖∞ + ‖c‖∞) + ‖F‖₁‖λ_u + λ_l‖∞): a bound on the terms each entry
        of r_d = Aᵀ(A y − c) + Fᵀ(λ_u − λ_l) sums, times ε, the floor of its round-off
        (measured r_d at that floor: 0.5× this at N = 10⁴, 4 Hz)."""
        _, a_cols, a_rows, c_max, f_cols = self._norms
        return np.finfo(float).eps * (a_cols * (a_rows * float(np.max(np.abs(y))) + c_max)
                                      + f_cols * float(np.max(lam_sum)))

    @functools.cached_property
    def _f_squared_t(self) -> sparse.csr_matrix:
        """(F∘F)ᵀ: diag(FᵀDF) = (F∘F)ᵀ D."""
        return self.f.multiply(self.f).T.tocsr()

    def _dual_measure(self, y, r_d, lam_u, lam_l) -> float:
        """‖r_d‖∞ relative to the size of the terms summed (round-off in Aᵀ(Ay − c) grows
        with |A|ᵀ(|A||y| + |c|), ~1e8 × |y| at Δt = 0.01 s)."""
        dual_scale = 1.0 + max(
            np.max(self._abs_a_products(np.abs(y), np.abs(self.c))[self.free], initial=0.0),
            np.max(self.abs_f.T @ (lam_u + lam_l)))
        return float(np.max(np.abs(r_d)) / dual_scale)

    def _abs_a_products(self, y_abs, c_abs) -> np.ndarray:
        """|A|ᵀ(|A| y_abs + c_abs), chunk by chunk of A's rows: |A| is never stored (it would
        be as large as A's values)."""
        indptr, indices, data = self.a.indptr, self.a.indices, self.a.data
        out = np.zeros(self.n)
        for start in range(0, self.a.shape[0], _CHUNK_ROWS):
            stop = min(self.a.shape[0], start + _CHUNK_ROWS)
            lo, hi = indptr[start], indptr[stop]
            # Copies of A's index slices: nothing done to the chunk can touch A.
            chunk = sparse.csr_matrix(
                (np.abs(data[lo:hi]), indices[lo:hi].copy(), indptr[start:stop + 1] - lo),
                shape=(stop - start, self.n))
            out += chunk.T @ (chunk @ y_abs + c_abs[start:stop])
        return out

    def unconstrained_optimum(self) -> np.ndarray:
        """argmin ½‖A y − c‖² with y[fixed] = 0, the limits ignored (n,): one factorisation of
        AᵀA by the same route as the Newton steps (for Offline-CKS, the RTS smoother's
        solution). Raises LinAlgError when AᵀA is singular."""
        y = np.zeros(self.n)
        return y + self.factorize(np.zeros(self.m))(self.c, np.zeros(self.m))

    def _unconstrained(self, y) -> BandedIpResult:
        try:
            dy = self.factorize(np.zeros(0))(-(self.a @ y - self.c), np.zeros(0))
        except (LinAlgError, ValueError) as error:
            return BandedIpResult(np.full_like(y, np.nan), False, f"numerical_failure: {error}",
                                  1, self.route, math.nan, math.nan, math.nan, np.zeros(0))
        return BandedIpResult(y + dy, True, "converged", 1, self.route, 0.0, 0.0, 0.0,
                              np.zeros(0))


class _RepeatingBand:
    """A band matrix stored as its repeating 4-row block and the blocks that differ.

    AᵀA of a time-invariant model (same measurement, process and limit rows at every sample)
    has the same four band rows for every sample but those next to the prior, the last
    sample and fixed entries: storing them once instead of N times saves a whole band
    (42 MB per joint at N = 10⁵ with half-bandwidth 12). Any other band is stored as it is
    (every block an exception); :meth:`expand` gives the same array either way.
    """

    def __init__(self, band: np.ndarray):
        n, width = band.shape
        self.shape = band.shape
        if n % 4 or n < 8:
            self.block, self.rows, self.values = None, None, band.copy()
            return
        blocks = band.reshape(n // 4, 4, width)
        # The most common block: the one of sample 1 unless it is itself an exception.
        reference = blocks[n // 8]
        differs = np.any(blocks != reference, axis=(1, 2))
        self.block = reference.copy()
        self.rows = np.flatnonzero(differs)
        self.values = blocks[self.rows].copy()

    def expand(self, out: np.ndarray) -> np.ndarray:
        """Writes the band into ``out`` (shape :attr:`shape`) and returns it."""
        if self.block is None:
            np.copyto(out, self.values)
            return out
        blocks = out.reshape(-1, 4, self.shape[1])
        blocks[:] = self.block
        blocks[self.rows] = self.values
        return out


def _max_step(values, steps) -> float:
    """Largest α with every v + α Δv ≥ 0 (v > 0); inf when no Δv is negative."""
    alpha = math.inf
    for v, dv in zip(values, steps):
        if v.size:
            # A Δv < 0 so small that v / −Δv overflows does not limit the step: inf is right.
            with np.errstate(over="ignore"):
                ratio = np.divide(v, -dv, out=np.full_like(v, math.inf), where=dv < 0)
            alpha = min(alpha, float(ratio.min()))
    return alpha


def solve_banded_qp(a, c, f, lower, upper, fixed, y0, options: BandedIpOptions = BandedIpOptions()
                    ) -> BandedIpResult:
    """minimise ½‖A y − c‖² s.t. lower ≤ F y ≤ upper, y[fixed] = 0, by the banded IP method.

    Args:
        a: (rows, n) sparse, n a multiple of 4 (4 states per sample), banded by sample.
        c: (rows,).
        f: (m, n) sparse limit rows, banded by sample; lower/upper (m,), lower < upper.
        fixed: (n,) bool, entries held at 0.
        y0: starting point (n,), e.g. the unconstrained optimum.
        options: tolerances and the linear-algebra route.
    """
    return BandedQp(a, c, f, lower, upper, fixed, options).run(y0)
