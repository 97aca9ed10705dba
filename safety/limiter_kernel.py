"""The hard limiter's tick, compiled (numba): :func:`limiter_step`'s per-tick path.

For 1–6 joints, NumPy's per-call overhead dominates a tick of the array form
(``telesmooth.safety.limiter._step_arrays``, a few hundred µs) and Python floats still cost
~150 µs; this kernel does the same arithmetic compiled (a few µs, ``telesmooth bench``).

Every expression is the one of the array form (``_step_arrays``, ``stop_position``,
``_projected``, ``_interval``, ``_band``) in the same order, and numba compiles it without
fastmath (no fused multiply-add, no reassociation; :mod:`telesmooth.compiled`), so the results
are the same floats bit for bit (tests/test_limiter_kernel.py compares them on random and
adversarial ticks). Maxima and minima follow NumPy's np.maximum / np.minimum (the second
argument on ties, NaN in the first propagated). The braking band's 65-point grid and its secant
step are evaluated only for the joints whose next stop point misses the band (as in
``_band``), once for both walls. A tick with a non-finite target (a braking joint), a non-finite
input state or a non-finite result is left to the array form: the kernel then returns
``LEFT_TO_ARRAYS`` and no values.

The parameters come as plain arrays (``LimiterParams._kernel_arguments``): per joint, the facet
rows of its stoppable set S in three groups (all rows for the gauge, the rows bounding the jerk
from above, from below), each row (g_v, g_a, 1/(g·b)), padded to a common count, the counts, and
the internal (a_max, j_max).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, types

from telesmooth.compiled import compile_kernel, readonly_array

__all__ = ["BAND_TOLERANCE", "GAUGE_ROWS", "LOWER_ROWS", "UPPER_ROWS", "limiter_tick",
           "stop_point"]

GAUGE_ROWS, UPPER_ROWS, LOWER_ROWS = 0, 1, 2
"""The three row groups of the facet table (its axis 1)."""

BAND_TOLERANCE = 1e-9
"""Relative slack when accepting u_hit inside the braking band (``limiter._BAND_TOLERANCE``,
the same value; a test checks)."""

_F8 = types.float64


@njit(inline="always")
def stop_point(position, velocity, acceleration, a_max, j_max):
    """``stop_position`` of one joint (the same operations in the same order); inlined into
    the tick (numba IR), so that the band's grid loop is one loop without calls."""
    x = velocity + acceleration * abs(acceleration) / (2.0 * j_max)
    sign = 1.0 if x >= 0.0 else -1.0
    v = sign * velocity
    a = sign * acceleration
    x = j_max * v + 0.5 * a * a
    peak_sq = x if x > 0.0 or x != x else 0.0
    x = math.sqrt(peak_sq)
    peak = x if x < a_max or x != x else a_max
    x = (a + peak) / j_max
    t1 = x if x > 0.0 or x != x else 0.0
    x = (peak_sq - peak * peak) / (j_max * a_max)
    t2 = x if x > 0.0 or x != x else 0.0
    t3 = peak / j_max
    jt1 = j_max * t1
    d1 = t1 * (v + t1 * (0.5 * a - jt1 / 6.0))
    v1 = v + t1 * (a - 0.5 * jt1)
    d23 = v1 * (t2 + t3) - peak * (0.5 * t2 * t2 + t2 * t3 + t3 * t3 / 3.0)
    return position + sign * (d1 + d23)


_SIGNATURE = types.int64(
    _F8, _F8, types.boolean, readonly_array(1, "C"), readonly_array(4, "C"),
    types.Array(types.int64, 2, "C", readonly=True), readonly_array(2, "C"),
    readonly_array(1), readonly_array(1), readonly_array(1), readonly_array(2),
    readonly_array(2), readonly_array(1), readonly_array(2), _F8[:, ::1],
)

LEFT_TO_ARRAYS, EXACT, LIMITED = 0, 1, 2
"""What :func:`limiter_tick` returns."""

ROW_COMMAND, ROW_VELOCITY, ROW_ACCELERATION, ROW_SENT = 0, 1, 2, 3
"""The rows of its output array (the new state): command, velocity, acceleration, then the
sent history (H rows, oldest first) and the two targets (rows 3 + H, 4 + H)."""


@compile_kernel(_SIGNATURE)
def limiter_tick(dt, dt2, braking, grid, rows, counts, limits, position, velocity,
                 acceleration, targets, sent, target, lookahead, out):
    """One tick of ``limiter_step`` for a finite target.

    Args:
        dt, dt2: Δt and Δt² (the latter as Python's ``dt**2``).
        braking: the "braking" rule (else "greedy").
        grid: the band's grid on [0, 1] (65 points).
        rows: (J, 3, m, 3) facet table; counts (J, 3); limits (J, 2) = internal (a_max, j_max).
        position, velocity, acceleration: the state's nominal (p̂, v̂, â), (J,).
        targets: the state's (r_{k−1}, r_k), (2, J); sent: p_{k−3} … p_k, (4, J).
        target: r, (J,). lookahead: (L, J), or (0, J) for none.
        out: (H + 5, J) for an H-row ``sent``, written: the new state (rows ``ROW_…``); one
            array instead of five, as returning arrays to Python costs more than the tick.

    Returns:
        ``EXACT`` (every joint's command is its target bit for bit), ``LIMITED``, or
        ``LEFT_TO_ARRAYS`` (``out`` then holds nothing of use).
    """
    n = target.shape[0]
    history = sent.shape[0]
    # Shapes that do not fit (a malformed state) go to the array form, which reports them;
    # the loops below read and write without bounds checks.
    if (rows.shape[0] != n or rows.shape[1] != 3 or rows.shape[3] != 3
            or counts.shape != (n, 3) or limits.shape != (n, 2) or position.shape[0] != n
            or velocity.shape[0] != n or acceleration.shape[0] != n
            or targets.shape != (2, n) or history < 1 or sent.shape[1] != n
            or (lookahead.shape[0] > 0 and lookahead.shape[1] != n)
            or out.shape != (history + 5, n) or grid.shape[0] < 2):
        return LEFT_TO_ARRAYS
    for j in range(n):
        for g in range(3):
            if counts[j, g] < 0 or counts[j, g] > rows.shape[2]:
                return LEFT_TO_ARRAYS
    # Any non-finite input leaves the tick to the array form.
    for j in range(n):
        if not (math.isfinite(target[j]) and math.isfinite(position[j])
                and math.isfinite(velocity[j]) and math.isfinite(acceleration[j])):
            return LEFT_TO_ARRAYS
        if braking and not (math.isfinite(targets[0, j]) and math.isfinite(targets[1, j])):
            return LEFT_TO_ARRAYS
    ahead = braking and lookahead.shape[0] > 0
    num_ahead = lookahead.shape[0]
    num_grid = grid.shape[0]
    stops = np.empty(num_grid)
    command = out[ROW_COMMAND]
    new_velocity = out[ROW_VELOCITY]
    new_acceleration = out[ROW_ACCELERATION]
    all_exact = True
    for joint in range(n):
        a_lim = limits[joint, 0]
        j_lim = limits[joint, 1]
        p = position[joint]
        vel = velocity[joint]
        acc = acceleration[joint]
        # _projected
        gauge = -math.inf
        for i in range(counts[joint, GAUGE_ROWS]):
            x = rows[joint, GAUGE_ROWS, i, 0] * vel + rows[joint, GAUGE_ROWS, i, 1] * acc
            gauge = x if x > gauge or x != x else gauge
        if gauge > 1.0:
            scale = 1.0 / gauge
            vel = vel * scale
            acc = acc * scale
        # _interval
        moved = vel + acc * dt
        hi = math.inf
        for i in range(counts[joint, UPPER_ROWS]):
            x = (1.0 - (rows[joint, UPPER_ROWS, i, 0] * moved
                        + rows[joint, UPPER_ROWS, i, 1] * acc)) * rows[joint, UPPER_ROWS, i, 2]
            hi = x if x < hi or x != x else hi
        hi = hi if hi < j_lim or hi != hi else j_lim
        lo = -math.inf
        for i in range(counts[joint, LOWER_ROWS]):
            x = (1.0 - (rows[joint, LOWER_ROWS, i, 0] * moved
                        + rows[joint, LOWER_ROWS, i, 1] * acc)) * rows[joint, LOWER_ROWS, i, 2]
            lo = x if x > lo or x != x else lo
        lo = lo if lo > -j_lim or lo != lo else -j_lim
        r = target[joint]
        u_hit = ((r - p) / dt - vel - acc * dt) / dt2
        lower_band = lo
        upper_band = hi
        if braking:
            r1 = targets[1, joint]
            r2 = targets[0, joint]
            target_stop = stop_point(r, (r - r1) / dt, (r - 2.0 * r1 + r2) / dt2, a_lim, j_lim)
            wall_hi = r if r > target_stop else target_stop      # r is finite
            wall_lo = r if r < target_stop else target_stop
            if ahead:
                usable = True
                for i in range(num_ahead):
                    if not math.isfinite(lookahead[i, joint]):
                        usable = False
                if usable:
                    # seq = (r2, r1, r, r_{k+1} … r_{k+L}); its last three give the end state.
                    last = lookahead[num_ahead - 1, joint]
                    before = lookahead[num_ahead - 2, joint] if num_ahead >= 2 else r
                    if num_ahead >= 3:
                        third = lookahead[num_ahead - 3, joint]
                    elif num_ahead == 2:
                        third = r
                    else:
                        third = r1
                    end_stop = stop_point(last, (last - before) / dt,
                                          (last - 2.0 * before + third) / dt2, a_lim, j_lim)
                    # max / min of (r, r_{k+1}, …) as Python's max / min: the first extreme.
                    top = r
                    bottom = r
                    for i in range(num_ahead):
                        x = lookahead[i, joint]
                        if x > top:
                            top = x
                        if x < bottom:
                            bottom = x
                    x = top if top > end_stop or top != top else end_stop
                    wall_hi = wall_hi if wall_hi > x or wall_hi != wall_hi else x
                    x = bottom if bottom < end_stop or bottom != bottom else end_stop
                    wall_lo = wall_lo if wall_lo < x or wall_lo != wall_lo else x
            # _band, its first part: the stop point after clip(u_hit, lo, hi).
            x = u_hit if u_hit > lo or u_hit != u_hit else lo
            hit = x if x < hi or x != x else hi
            acc_next = acc + hit * dt
            vel_next = vel + acc_next * dt
            f_hit = stop_point(p + vel_next * dt, vel_next, acc_next, a_lim, j_lim)
            x = abs(wall_lo)
            tolerance_lo = (x if x > 1.0 or x != x else 1.0) * BAND_TOLERANCE
            x = abs(wall_hi)
            tolerance_hi = (x if x > 1.0 or x != x else 1.0) * BAND_TOLERANCE
            if not (f_hit - wall_lo >= -tolerance_lo and f_hit - wall_hi <= tolerance_hi):
                # The band: the stop points of the grid over [lo, hi] (once for both walls),
                # the bracketing cell of each wall, a secant step inside it.
                width = hi - lo
                for g in range(num_grid):
                    u = width * grid[g] + lo
                    acc_g = u * dt + acc
                    vel_g = acc_g * dt + vel
                    stops[g] = stop_point(vel_g * dt + p, vel_g, acc_g, a_lim, j_lim)
                ends_0 = 0.0
                ends_1 = 0.0
                for side in range(2):
                    wall = wall_lo if side == 0 else wall_hi
                    if stops[num_grid - 1] - wall <= 0.0:          # all below
                        end = hi
                    elif stops[0] - wall > 0.0:                    # none below
                        end = lo
                    else:
                        count = 0
                        for g in range(num_grid):
                            if stops[g] - wall <= 0.0:
                                count += 1
                        index = min(max(count - 1, 0), num_grid - 2)
                        low = lo + width * grid[index]
                        high = lo + width * grid[index + 1]
                        f_low = stops[index] - wall
                        f_high = stops[index + 1] - wall
                        denom = f_high - f_low
                        root = low - f_low * (high - low) / denom if denom > 0.0 else low
                        x = root if root > low or root != root else low
                        end = x if x < high or x != x else high
                    if side == 0:
                        ends_0 = end
                    else:
                        ends_1 = end
                lower_band = ends_0 if ends_0 < ends_1 or ends_0 != ends_0 else ends_1
                upper_band = ends_1
        u = u_hit if u_hit > lower_band or u_hit != u_hit else lower_band
        u = u if u < upper_band or u != u else upper_band
        u = u if u > lo or u != u else lo
        u = u if u < hi or u != u else hi
        if lo > hi:
            u = 0.5 * (lo + hi)
        acc = acc + u * dt
        vel = vel + acc * dt
        if u == u_hit:
            command[joint] = r
        else:
            command[joint] = p + vel * dt
            all_exact = False
        new_velocity[joint] = vel
        new_acceleration[joint] = acc
    for j in range(n):
        if not (math.isfinite(command[j]) and math.isfinite(new_velocity[j])
                and math.isfinite(new_acceleration[j])):
            return LEFT_TO_ARRAYS
    for i in range(history - 1):
        for j in range(n):
            out[ROW_SENT + i, j] = sent[i + 1, j]
    for j in range(n):
        out[ROW_SENT + history - 1, j] = command[j]
        out[ROW_SENT + history, j] = targets[1, j]
        out[ROW_SENT + history + 1, j] = target[j]
    return EXACT if all_exact else LIMITED
