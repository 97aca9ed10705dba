"""The fixed-lag recursion and one Online-CKS cycle, compiled (numba).

:func:`recursion_step` is one step of the ``"recursion"`` form of the fixed-lag smoother
(:class:`~telesmooth.smoothing.fixed_lag.FixedLagSmoother`); :func:`online_cks_tick` is one cycle
of :meth:`telesmooth.smoothing.reduced_q.OnlineCks.step` for its default settings (variant "A":
that step, its output block, the trigger and σ's update, in one call). For 6 joints and L = 3
the NumPy form costs ~100 µs of per-call overhead for a few hundred flops; compiled, a few µs
(``telesmooth bench``). Both use the same per-joint routine, so Online-CKS without triggers
equals the fixed-lag smoother bit for bit, as before.

The arithmetic is the NumPy form's (:meth:`FixedLagSmoother._step_recursion`,
``JerkModel.scaled_process_covariance``, ``from_scaled``, ``OnlineCks._violation``,
``decrease_sigma``), written per joint:

    x̂_{k|k−1} = Φ̃ x̂_{k−1|k−1},  x̂_{k−i|k−1} = block i−1 (i = 1 … L)
    Σ^{(0)} = (Φ̃ C^{(0)}) Φ̃ᵀ + σ Δt⁷ Q1,  Σ^{(i)} = C^{(i−1)} Φ̃ᵀ
    S = Σ^{(0)}_{00} + r,  ν = z − x̂_{k|k−1}[0]
    x̂_{k−i|k} = x̂_{k−i|k−1} + Σ^{(i)}_{:,0} (ν / S)
    C^{(i)} = Σ^{(i)} − Σ^{(i)}_{:,0} Σ^{(0)}_{0,:} / S
    C^{(0)} ← (C^{(0)} + C^{(0)ᵀ}) / 2

Element-wise operations are the same floats as NumPy's. The 4×4 products sum their four terms
in index order (((t₀ + t₁) + t₂) + t₃), NumPy's go through BLAS, whose order (and use of fused
multiply-add) depends on the BLAS build and the processor: the two agree to round-off (tested
against the NumPy form to 1e-12 relative), and the compiled form no longer depends on the BLAS
build.
"""

from __future__ import annotations

import numpy as np
from numba import njit, types

from telesmooth.compiled import compile_kernel, readonly_array

__all__ = ["TRIGGER_FD", "TRIGGER_STATE", "online_cks_tick", "recursion_step"]

TRIGGER_STATE, TRIGGER_FD = 0, 1
"""The violation triggers of ``ReducedQConfig.trigger`` ("state", "fd")."""

_F8 = types.float64
_B1 = types.Array(types.boolean, 1, "C")


@njit(inline="always")
def _joint_step(means, cross, z, sigma, r, phi, unit_q, dt7, j, new_means, new_cross, scratch):
    """The recursion (module docstring) for joint j: writes new_means[j], new_cross[j]."""
    prior0 = scratch[0, 0]
    temp = scratch[1]
    sigma0 = scratch[2]
    sigma_i = scratch[3]
    blocks = means.shape[1]
    # Prior block 0: Φ̃ x̂_{k−1|k−1}.
    for a in range(4):
        prior0[a] = (((means[j, 0, 0] * phi[a, 0] + means[j, 0, 1] * phi[a, 1])
                      + means[j, 0, 2] * phi[a, 2]) + means[j, 0, 3] * phi[a, 3])
    # Σ^{(0)} = (Φ̃ C^{(0)}) Φ̃ᵀ + Q̃,  Q̃ = (σ Δt⁷) Q1.
    q_scale = sigma * dt7
    for a in range(4):
        for b in range(4):
            temp[a, b] = (((phi[a, 0] * cross[j, 0, 0, b] + phi[a, 1] * cross[j, 0, 1, b])
                           + phi[a, 2] * cross[j, 0, 2, b]) + phi[a, 3] * cross[j, 0, 3, b])
    for a in range(4):
        for b in range(4):
            sigma0[a, b] = ((((temp[a, 0] * phi[b, 0] + temp[a, 1] * phi[b, 1])
                              + temp[a, 2] * phi[b, 2]) + temp[a, 3] * phi[b, 3])
                            + q_scale * unit_q[a, b])
    s = sigma0[0, 0] + r
    gain = (z - prior0[0]) / s
    # Blocks 1 … L, each Σ^{(i)} = C^{(i−1)} Φ̃ᵀ from the old C^{(i−1)}.
    for i in range(1, blocks):
        for a in range(4):
            for b in range(4):
                sigma_i[a, b] = (((cross[j, i - 1, a, 0] * phi[b, 0]
                                   + cross[j, i - 1, a, 1] * phi[b, 1])
                                  + cross[j, i - 1, a, 2] * phi[b, 2])
                                 + cross[j, i - 1, a, 3] * phi[b, 3])
        for a in range(4):
            new_means[j, i, a] = means[j, i - 1, a] + sigma_i[a, 0] * gain
            for b in range(4):
                new_cross[j, i, a, b] = sigma_i[a, b] - sigma_i[a, 0] * sigma0[0, b] / s
    for a in range(4):
        new_means[j, 0, a] = prior0[a] + sigma0[a, 0] * gain
        for b in range(4):
            temp[a, b] = sigma0[a, b] - sigma0[a, 0] * sigma0[0, b] / s
    for a in range(4):
        for b in range(4):
            new_cross[j, 0, a, b] = 0.5 * (temp[a, b] + temp[b, a])


@njit(inline="always")
def _shapes_fit(means, cross, z, sigma, r, phi, unit_q, new_means, new_cross):
    n = means.shape[0]
    blocks = means.shape[1]
    return not (blocks < 1 or means.shape[2] != 4 or cross.shape != (n, blocks, 4, 4)
                or z.shape[0] != n or sigma.shape[0] != n or r.shape[0] != n
                or phi.shape != (4, 4) or unit_q.shape != (4, 4)
                or new_means.shape != means.shape or new_cross.shape != cross.shape)


@compile_kernel(types.boolean(
    readonly_array(3), readonly_array(4), readonly_array(1), readonly_array(1),
    readonly_array(1), readonly_array(2, "C"), readonly_array(2, "C"), _F8,
    _F8[:, :, ::1], _F8[:, :, :, ::1],
))
def recursion_step(means, cross, z, sigma, r, phi, unit_q, dt7, new_means, new_cross):
    """One step of the recursion form for all joints.

    Args:
        means: x̃_{k−1−i|k−1}, (J, L+1, 4); cross: C^{(i)}, (J, L+1, 4, 4) (scaled units).
        z: the measurement (J,); sigma: σ_k (J,); r: the measurement variance (J,).
        phi: Φ̃ (4, 4); unit_q: Q1 (4, 4); dt7: Δt⁷ (Python's ``dt**7``).
        new_means, new_cross: written.

    Returns:
        False (nothing written) when z is not finite or a shape does not fit: the caller
        takes the NumPy form, which names the field and the joint in its error.
    """
    if not _shapes_fit(means, cross, z, sigma, r, phi, unit_q, new_means, new_cross):
        return False
    for j in range(means.shape[0]):
        if not np.isfinite(z[j]):
            return False
    scratch = np.empty((4, 4, 4))
    for j in range(means.shape[0]):
        _joint_step(means, cross, z[j], sigma[j], r[j], phi, unit_q, dt7, j, new_means,
                    new_cross, scratch)
    return True


_SIGNATURE = types.boolean(
    readonly_array(3), readonly_array(4), readonly_array(1), readonly_array(1),
    readonly_array(1), readonly_array(2, "C"), readonly_array(2, "C"), readonly_array(1, "C"),
    readonly_array(1), readonly_array(1), readonly_array(1), readonly_array(1),
    readonly_array(2), _F8, _F8, _F8, _F8, types.boolean, types.int64,
    _F8[:, :, ::1], _F8[:, :, :, ::1], _F8[:, ::1], _B1, _F8[::1], _F8[:, ::1],
)


@compile_kernel(_SIGNATURE)
def online_cks_tick(means, cross, z, sigma, r, phi, unit_q, scaling, max_acceleration,
                    max_jerk, sigma_min, delta_sigma, sent, dt7, dt2, dt3, rho,
                    multiplicative, trigger, new_means, new_cross, output, triggered,
                    new_sigma, new_sent):
    """One Online-CKS cycle (variant A, recursion form) for all joints.

    Args:
        means, cross, z, sigma, r, phi, unit_q, dt7: as :func:`recursion_step` (σ: this
            cycle's).
        scaling: diag(T) (4,).
        max_acceleration, max_jerk: the trigger's limits (J,); sigma_min (J,).
        delta_sigma: the additive step Δσ (J,) (unused by the multiplicative rule).
        sent: the last three sent positions (3, J), oldest first.
        dt2, dt3: Δt², Δt³ (Python's ``dt**k``).
        rho, multiplicative: the step rule; trigger: ``TRIGGER_STATE`` or ``TRIGGER_FD``.
        new_means, new_cross, output (J, 4), triggered (J,), new_sigma (J,), new_sent (3, J):
            written.

    Returns:
        False (nothing of use written) when z is not finite or a shape does not fit: the
        caller takes the NumPy form, which names the field and the joint in its error.
    """
    n = means.shape[0]
    lag = means.shape[1] - 1
    if not _shapes_fit(means, cross, z, sigma, r, phi, unit_q, new_means, new_cross):
        return False
    if (scaling.shape[0] != 4 or max_acceleration.shape[0] != n or max_jerk.shape[0] != n
            or sigma_min.shape[0] != n or delta_sigma.shape[0] != n or sent.shape != (3, n)
            or output.shape != (n, 4) or triggered.shape[0] != n or new_sigma.shape[0] != n
            or new_sent.shape != (3, n)):
        return False
    for j in range(n):
        if not np.isfinite(z[j]):
            return False
    scratch = np.empty((4, 4, 4))
    for j in range(n):
        _joint_step(means, cross, z[j], sigma[j], r[j], phi, unit_q, dt7, j, new_means,
                    new_cross, scratch)
        # The output block x̂_{k−L|k} in physical units, the trigger, σ, the sent positions.
        for a in range(4):
            output[j, a] = new_means[j, lag, a] / scaling[a]
        if trigger == TRIGGER_STATE:
            acc = output[j, 2]
            jerk = output[j, 3]
        else:
            p3 = output[j, 0]
            acc = (p3 - 2.0 * sent[2, j] + sent[1, j]) / dt2
            jerk = (p3 - 3.0 * sent[2, j] + 3.0 * sent[1, j] - sent[0, j]) / dt3
        violated = abs(acc) > max_acceleration[j] or abs(jerk) > max_jerk[j]
        triggered[j] = violated
        value = sigma[j]
        if violated:
            reduced = rho * value if multiplicative else value - delta_sigma[j]
            bound = sigma_min[j]
            x = reduced if reduced > bound or reduced != reduced else bound
            value = value if value < x or value != value else x
        new_sigma[j] = value
        new_sent[0, j] = sent[1, j]
        new_sent[1, j] = sent[2, j]
        new_sent[2, j] = output[j, 0]
    return True
