"""Oracle tests of the jerk model (docs/method.md §1): Φ, exact Q, scaling identities,
validation."""

from fractions import Fraction
from math import factorial

import numpy as np
import pytest
from scipy.integrate import quad_vec
from scipy.linalg import expm

from telesmooth.smoothing.model import (
    SCALED_TRANSITION,
    UNIT_PROCESS_COVARIANCE,
    UNIT_PROCESS_PRECISION,
    JerkModel,
    process_covariance,
    sigma_from_bandwidth,
    state_scaling,
    transition_matrix,
)

A = np.diag(np.ones(3), k=1)
G = np.array([0.0, 0.0, 0.0, 1.0])
CASES = [(dt, sigma) for dt in (0.01, 0.25, 1.0, 2.0) for sigma in (1e-4, 1.0, 37.0)]


@pytest.mark.parametrize("dt", [0.01, 0.25, 1.0, 2.0])
def test_transition_is_matrix_exponential(dt):
    np.testing.assert_allclose(transition_matrix(dt), expm(A * dt), rtol=0, atol=1e-14)


@pytest.mark.parametrize("dt,sigma", CASES)
def test_q_closed_form_equals_quadrature(dt, sigma):
    def integrand(s):
        column = expm(A * s) @ G
        return sigma * np.outer(column, column)

    integral, _ = quad_vec(integrand, 0.0, dt, epsabs=0.0, epsrel=1e-13)
    q = process_covariance(dt, sigma)
    np.testing.assert_allclose(q, integral, rtol=1e-12, atol=0)


# Van Loan's Φ⁻¹Q product cancels catastrophically in the tiny (0, 0) entry at Δt = 0.01, so
# it is an oracle only for Δt ≥ 0.25 (quadrature above covers every Δt).
@pytest.mark.parametrize("dt,sigma", [case for case in CASES if case[0] >= 0.25])
def test_q_closed_form_equals_van_loan(dt, sigma):
    # Van Loan: expm([[−A, G σ Gᵀ], [0, Aᵀ]] Δt) = [[·, Φ⁻¹ Q], [0, Φᵀ]].
    block = np.zeros((8, 8))
    block[:4, :4] = -A
    block[:4, 4:] = sigma * np.outer(G, G)
    block[4:, 4:] = A.T
    e = expm(block * dt)
    phi = e[4:, 4:].T
    q = phi @ e[:4, 4:]
    np.testing.assert_allclose(process_covariance(dt, sigma), q, rtol=1e-9, atol=0)


def test_unit_precision_is_exact_inverse_in_rational_arithmetic():
    q1 = [[Fraction(1, (7 - a - b) * factorial(3 - a) * factorial(3 - b)) for b in range(4)]
          for a in range(4)]
    inv = [[Fraction(int(v)) for v in row] for row in UNIT_PROCESS_PRECISION]
    product = [[sum(q1[i][k] * inv[k][j] for k in range(4)) for j in range(4)] for i in range(4)]
    assert product == [[Fraction(int(i == j)) for j in range(4)] for i in range(4)]
    np.testing.assert_allclose(UNIT_PROCESS_COVARIANCE, np.array(q1, dtype=float), rtol=1e-15)


@pytest.mark.parametrize("dt,sigma", CASES)
def test_scaling_identities(dt, sigma):
    t = np.diag(state_scaling(dt))
    np.testing.assert_allclose(t @ transition_matrix(dt) @ np.linalg.inv(t), SCALED_TRANSITION,
                               rtol=0, atol=1e-14)
    np.testing.assert_allclose(t @ process_covariance(dt, sigma) @ t,
                               sigma * dt**7 * UNIT_PROCESS_COVARIANCE, rtol=1e-14)
    model = JerkModel.make(dt, sigma, 1e-6, num_joints=1)
    np.testing.assert_allclose(model.scaled_process_covariance()[0],
                               sigma * dt**7 * UNIT_PROCESS_COVARIANCE, rtol=1e-15)
    x = np.array([0.3, -0.2, 0.1, 0.05])
    np.testing.assert_allclose(model.from_scaled(model.to_scaled(x)), x, rtol=1e-15)


def test_process_covariance_broadcasts_over_joints():
    q = process_covariance(0.25, np.array([1.0, 2.0, 3.0]))
    assert q.shape == (3, 4, 4)
    np.testing.assert_allclose(q[2], 3.0 * q[0], rtol=1e-15)


def test_sigma_from_bandwidth_matches_spec_default():
    # docs/method.md §8: σ_0 ≈ 4e-4 for f_c ≈ 0.36 Hz at Δt = 0.25 s, r = 1e-6.
    sigma = sigma_from_bandwidth(0.36, r=1e-6, dt_s=0.25)
    assert 3e-4 < sigma < 5e-4
    # Bandwidth scales as σ^(1/8): doubling f_c multiplies σ by 256.
    assert sigma_from_bandwidth(0.72, r=1e-6, dt_s=0.25) == pytest.approx(256 * sigma)


@pytest.mark.parametrize(
    "kwargs,message",
    [
        (dict(dt_s=0.0, sigma=1.0, r=1.0), "dt_s = 0.0 must be finite and > 0"),
        (dict(dt_s=float("nan"), sigma=1.0, r=1.0), "dt_s = nan"),
        (dict(dt_s=0.25, sigma=[1.0, -2.0], r=1.0), "sigma[1] = -2.0 for joint 1 ('elbow')"),
        (dict(dt_s=0.25, sigma=1.0, r=[1.0, 2.0, 3.0]), "r has 3 value(s)"),
        (dict(dt_s=0.25, sigma={"wrist": 1.0}, r=1.0), "unknown joint name(s) ['wrist']"),
        (dict(dt_s=0.25, sigma=1.0, r=float("inf")), "r[0] = inf for joint 0 ('shoulder')"),
    ],
)
def test_model_validation_names_field_value_and_joint(kwargs, message):
    with pytest.raises(ValueError) as error:
        JerkModel.make(**kwargs, num_joints=2, joint_names=("shoulder", "elbow"))
    assert message in str(error.value)
