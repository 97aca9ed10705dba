"""Shared test data: seeded operator-like recordings (tests import it as a plain module)."""

import numpy as np

from telesmooth.datasets.synthetic import minimum_jerk, synthetic_joint_motion

__all__ = ["dense_smoother_normal_equations", "minimum_jerk", "operator_recording"]


def operator_recording(num_samples=60, num_joints=2, dt=0.25, noise=1e-3, seed=0):
    """A few minimum-jerk reaches per joint plus white position noise, shape (N, J).

    Joint j starts at 0.1 j rad; targets are not clipped (see ``synthetic_joint_motion``)."""
    return synthetic_joint_motion(num_samples, num_joints, dt_s=dt, noise_rad=noise, seed=seed,
                                  joint_offset_step_rad=0.1)


def dense_smoother_normal_equations(z, dt, sigma_schedule, r, prior_mean, prior_cov, dps=40):
    """Independent oracle: the IPLM objective's normal equations C y = −d (docs/method.md §2.3) for
    one joint, assembled densely and solved in 40-digit arithmetic (mpmath). Returns (N, 4).

    Double precision is not enough for a dense oracle here: cond(C) grows like r/(σΔt⁷), and
    numpy's dense solve loses ~1e-7 where the Kalman recursions stay at 1e-15. The unit-time
    Q1 is the rational closed form, inverted in mpmath; the model is assembled in the scaled
    basis y = T x (Φ̃ = expm(A), Q̃ = σΔt⁷ Q1)."""
    from fractions import Fraction
    from math import factorial

    import mpmath

    mpmath.mp.dps = dps
    mpf = mpmath.mpf
    n = len(z)
    q1 = mpmath.matrix([[mpf(Fraction(1, (7 - a - b) * factorial(3 - a) * factorial(3 - b)))
                         for b in range(4)] for a in range(4)])
    q1_inv = q1**-1
    phi = mpmath.matrix([[1 if i == j else 0 for j in range(4)] for i in range(4)])
    for i in range(4):
        for j in range(i + 1, 4):
            phi[i, j] = mpf(1) / factorial(j - i)
    d = mpmath.zeros(4, 8)  # y_k − Φ̃ y_{k−1} on (y_{k−1}, y_k)
    for i in range(4):
        for j in range(4):
            d[i, j] = -phi[i, j]
        d[i, 4 + i] = 1
    t = [mpf(dt) ** i for i in range(4)]
    hessian = mpmath.zeros(4 * n, 4 * n)
    gradient = mpmath.zeros(4 * n, 1)
    p0 = mpmath.matrix([[mpf(prior_cov[i, j]) * t[i] * t[j] for j in range(4)] for i in range(4)])
    p0_inv = p0**-1
    m0 = mpmath.matrix([mpf(prior_mean[i]) * t[i] for i in range(4)])
    g0 = p0_inv * m0
    for i in range(4):
        gradient[i] -= g0[i]
        for j in range(4):
            hessian[i, j] += p0_inv[i, j]
    for k in range(n):
        hessian[4 * k, 4 * k] += 1 / mpf(r)
        gradient[4 * k] -= mpf(z[k]) / mpf(r)
        if k:
            block = d.T * (q1_inv / (mpf(sigma_schedule[k]) * mpf(dt) ** 7)) * d
            for i in range(8):
                for j in range(8):
                    hessian[4 * (k - 1) + i, 4 * (k - 1) + j] += block[i, j]
    y = mpmath.lu_solve(hessian, -gradient)
    scaled = np.array([float(y[i]) for i in range(4 * n)]).reshape(n, 4)
    return scaled / (dt ** np.arange(4.0))
