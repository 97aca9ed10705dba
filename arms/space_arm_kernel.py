"""The 6-DOF arm's Newton iterations, compiled (numba): the per-update path of the IK.

The ground station solves the space arm's inverse kinematics at 100 Hz
(:func:`telesmooth.arms.space_arm_ik.solve_space_arm_ik`). Through Drake, each Newton
iteration (forward kinematics, angle-axis error, Jacobian, a 6×6 solve) costs ~100 µs of
binding and NumPy overhead on a handful of numbers; compiled, an iteration costs a few
microseconds (the kinematics about 2 µs).

Kinematics (the conventions of :mod:`telesmooth.arms.description`): the base is the world
frame; at zero angles every link frame is parallel to it, link i's frame sits at its joint's
origin o_i and turns about the unit axis a_i; the tool point is o_{n-1} + the last link's
segment, and the tool frame is parallel to the last link's frame. So, with R_{-1} = I,
p_{-1} = 0 and o_{-1} = 0:

    R_i = R_{i-1} Rot(a_i, q_i),       p_i = p_{i-1} + R_{i-1} (o_i - o_{i-1})
    R_T = R_{n-1},                      p_T = p_{n-1} + R_{n-1} s_{n-1}

and column i of the tool point's spatial-velocity Jacobian in the world ([ω; v], the rows of
Drake's ``CalcJacobianSpatialVelocity``) is w_i = R_i a_i, w_i × (p_T - p_i).

The iteration is the Gauss–Newton branch of ``space_arm_ik._newton`` exactly: the error
e = [θ u; p_d - p] with θ u the angle-axis of R_d R_Tᵀ (through a unit quaternion, as Drake's
``ToAngleAxis``), stop when both residuals are below the convergence fractions or after
``max_iterations`` steps, else step by J⁻¹e (LU with partial pivoting). When that step is not
defined (J exactly singular, a non-finite step) or would leave the box, the kernel stops and
says so: the caller continues from the same iterate with Drake's differential-IK QP, so the
answers are those of the Drake path (to round-off; tests/test_space_arm_kernel.py compares
them, and the kinematics against Drake's at random joint angles).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, types

from telesmooth.compiled import compile_kernel, readonly_array

__all__ = ["DONE", "NEEDS_QP", "newton_kernel", "tool_kinematics"]

DONE, NEEDS_QP = 0, 1
"""Outcomes of :func:`newton_kernel`: stopped by the convergence test or the iteration count;
stopped where the Gauss–Newton step is undefined or leaves the box (the QP takes over)."""


@njit
def _rotation_about(axis, angle, out):
    """out ← Rot(axis, angle) (Rodrigues; ``axis`` a unit vector)."""
    c, s = math.cos(angle), math.sin(angle)
    t = 1.0 - c
    x, y, z = axis[0], axis[1], axis[2]
    out[0, 0] = t * x * x + c
    out[0, 1] = t * x * y - s * z
    out[0, 2] = t * x * z + s * y
    out[1, 0] = t * x * y + s * z
    out[1, 1] = t * y * y + c
    out[1, 2] = t * y * z - s * x
    out[2, 0] = t * x * z - s * y
    out[2, 1] = t * y * z + s * x
    out[2, 2] = t * z * z + c


@njit
def tool_kinematics(q, axes, origins, tool, rotation, position, jacobian):
    """rotation, position ← R_WT(q), p_WT(q); jacobian ← J_WT(q) (6 × n, [ω; v] rows).

    Compiled with its caller (:func:`newton_kernel`, at import), or on its first call from
    Python (the tests)."""
    n = q.shape[0]
    step = np.empty((3, 3))
    product = np.empty((3, 3))
    joint_points = np.empty((n, 3))
    world_axes = np.empty((n, 3))
    for r in range(3):
        position[r] = 0.0
        for c in range(3):
            rotation[r, c] = 1.0 if r == c else 0.0
    for i in range(n):
        for r in range(3):
            offset = 0.0
            for c in range(3):
                previous = origins[i - 1, c] if i > 0 else 0.0
                offset += rotation[r, c] * (origins[i, c] - previous)
            position[r] += offset
        _rotation_about(axes[i], q[i], step)
        for r in range(3):
            for c in range(3):
                product[r, c] = (rotation[r, 0] * step[0, c] + rotation[r, 1] * step[1, c]
                                 + rotation[r, 2] * step[2, c])
        for r in range(3):
            joint_points[i, r] = position[r]
            for c in range(3):
                rotation[r, c] = product[r, c]
        for r in range(3):
            world_axes[i, r] = (rotation[r, 0] * axes[i, 0] + rotation[r, 1] * axes[i, 1]
                                + rotation[r, 2] * axes[i, 2])
    for r in range(3):
        position[r] += (rotation[r, 0] * tool[0] + rotation[r, 1] * tool[1]
                        + rotation[r, 2] * tool[2])
    for i in range(n):
        w = world_axes[i]
        dx = position[0] - joint_points[i, 0]
        dy = position[1] - joint_points[i, 1]
        dz = position[2] - joint_points[i, 2]
        jacobian[0, i], jacobian[1, i], jacobian[2, i] = w[0], w[1], w[2]
        jacobian[3, i] = w[1] * dz - w[2] * dy
        jacobian[4, i] = w[2] * dx - w[0] * dz
        jacobian[5, i] = w[0] * dy - w[1] * dx


@njit
def _angle_axis(m, out):
    """out ← θ u of the rotation matrix ``m`` (θ in [0, π]); returns θ.

    Through the unit quaternion (the larger-diagonal branch, as Eigen's), then
    θ = 2 atan2(|v|, |w|) and u = sign(w) v / |v| (Eigen's AngleAxis of a quaternion)."""
    trace = m[0, 0] + m[1, 1] + m[2, 2]
    if trace > 0.0:
        t = math.sqrt(trace + 1.0)
        w = 0.5 * t
        t = 0.5 / t
        x = (m[2, 1] - m[1, 2]) * t
        y = (m[0, 2] - m[2, 0]) * t
        z = (m[1, 0] - m[0, 1]) * t
    else:
        i = 0
        if m[1, 1] > m[0, 0]:
            i = 1
        if m[2, 2] > m[i, i]:
            i = 2
        j = (i + 1) % 3
        k = (j + 1) % 3
        t = math.sqrt(m[i, i] - m[j, j] - m[k, k] + 1.0)
        v = np.empty(3)
        v[i] = 0.5 * t
        t = 0.5 / t
        w = (m[k, j] - m[j, k]) * t
        v[j] = (m[j, i] + m[i, j]) * t
        v[k] = (m[k, i] + m[i, k]) * t
        x, y, z = v[0], v[1], v[2]
    norm = math.sqrt(x * x + y * y + z * z)
    if norm == 0.0:
        out[0] = out[1] = out[2] = 0.0
        return 0.0
    angle = 2.0 * math.atan2(norm, abs(w))
    scale = angle / norm if w >= 0.0 else -angle / norm
    out[0], out[1], out[2] = x * scale, y * scale, z * scale
    return angle


@njit
def _solve_in_place(a, b):
    """b ← a⁻¹ b by LU with partial pivoting (a is overwritten); False if a pivot is 0."""
    n = b.shape[0]
    for col in range(n):
        pivot = col
        for r in range(col + 1, n):
            if abs(a[r, col]) > abs(a[pivot, col]):
                pivot = r
        if a[pivot, col] == 0.0:
            return False
        if pivot != col:
            for c in range(n):
                a[col, c], a[pivot, c] = a[pivot, c], a[col, c]
            b[col], b[pivot] = b[pivot], b[col]
        for r in range(col + 1, n):
            factor = a[r, col] / a[col, col]
            if factor != 0.0:
                for c in range(col, n):
                    a[r, c] -= factor * a[col, c]
                b[r] -= factor * b[col]
    for r in range(n - 1, -1, -1):
        total = b[r]
        for c in range(r + 1, n):
            total -= a[r, c] * b[c]
        b[r] = total / a[r, r]
    return True


_SIGNATURE_NEWTON = types.Tuple((types.int64, types.float64, types.float64, types.int64))(
    readonly_array(2), readonly_array(1), readonly_array(1), readonly_array(1),
    readonly_array(2), readonly_array(2), readonly_array(1),
    types.float64, types.float64, types.int64, types.float64[::1])


@compile_kernel(_SIGNATURE_NEWTON)
def newton_kernel(rotation_desired, translation_desired, box_lower, box_upper, axes, origins,
                  tool, position_stop_m, orientation_stop_rad, max_iterations, q):
    """Gauss–Newton iterations from ``q`` (updated in place) inside [box_lower, box_upper].

    Returns (outcome, position error m, orientation error rad, iterations), the errors at
    the final ``q``; outcome :data:`DONE` or :data:`NEEDS_QP` (then ``q`` is the iterate the
    QP must continue from, and the errors are its own)."""
    n = q.shape[0]
    rotation = np.empty((3, 3))
    position = np.empty(3)
    jacobian = np.empty((6, n))
    relative = np.empty((3, 3))
    step = np.empty(6)
    iterations = 0
    while True:
        tool_kinematics(q, axes, origins, tool, rotation, position, jacobian)
        for r in range(3):                       # R_d R_Tᵀ
            for c in range(3):
                relative[r, c] = (rotation_desired[r, 0] * rotation[c, 0]
                                  + rotation_desired[r, 1] * rotation[c, 1]
                                  + rotation_desired[r, 2] * rotation[c, 2])
        orientation_rad = _angle_axis(relative, step[:3])
        for r in range(3):
            step[3 + r] = translation_desired[r] - position[r]
        position_m = math.sqrt(step[3] * step[3] + step[4] * step[4] + step[5] * step[5])
        if position_m <= position_stop_m and orientation_rad <= orientation_stop_rad:
            return DONE, position_m, orientation_rad, iterations
        if iterations >= max_iterations:
            return DONE, position_m, orientation_rad, iterations
        if n != 6 or not _solve_in_place(jacobian, step):
            return NEEDS_QP, position_m, orientation_rad, iterations
        for i in range(n):
            target = q[i] + step[i]
            if not (math.isfinite(step[i]) and box_lower[i] <= target <= box_upper[i]):
                return NEEDS_QP, position_m, orientation_rad, iterations
        iterations += 1
        for i in range(n):
            q[i] = q[i] + step[i]
