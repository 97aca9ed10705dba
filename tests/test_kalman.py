"""Oracle tests of the Kalman filter and the RTS smoother (Offline-KS)."""

import numpy as np
import pytest
from core_fixtures import dense_smoother_normal_equations, operator_recording

from telesmooth.smoothing.kalman import GaussianPrior, kalman_filter, rest_prior, rts_smoother
from telesmooth.smoothing.model import JerkModel, process_covariance, transition_matrix


def _schedule(num_samples, num_joints, seed=3):
    rng = np.random.default_rng(seed)
    return np.exp(rng.uniform(np.log(1e-6), np.log(1e-2), size=(num_samples, num_joints)))


@pytest.mark.parametrize("dt", [0.01, 0.25, 1.0])
def test_rts_equals_dense_normal_equations(dt):
    # Time-varying σ spanning σΔt⁷/r ∈ [1e-6, 1] (4e-4 at Δt = 0.25 gives 0.024).
    z = operator_recording(num_samples=24, num_joints=2, dt=dt, seed=1)
    r = np.array([1e-6, 4e-6])
    rng = np.random.default_rng(3)
    schedule = r * 10.0 ** rng.uniform(-6.0, 0.0, size=(24, 2)) / dt**7
    model = JerkModel.make(dt, schedule[1], r, num_joints=2)
    prior = rest_prior(z[0], model)
    smoothed = rts_smoother(z, model, prior, sigma_schedule=schedule).mean
    for j in range(2):
        dense = dense_smoother_normal_equations(
            z[:, j], dt, schedule[:, j], model.r[j], prior.mean[j], prior.cov[j])
        scale = np.abs(dense).max(axis=0)
        np.testing.assert_allclose(smoothed[:, j] / scale, dense / scale, rtol=0, atol=1e-11)


def test_kalman_filter_equals_textbook_loop_in_physical_units():
    dt, sigma, r = 0.25, 2e-3, 1e-6
    z = operator_recording(num_samples=50, num_joints=1, dt=dt, seed=2)
    model = JerkModel.make(dt, sigma, r, num_joints=1)
    prior = rest_prior(z[0], model)
    result = kalman_filter(z, model, prior)
    phi, q = transition_matrix(dt), process_covariance(dt, sigma)
    h = np.array([[1.0, 0.0, 0.0, 0.0]])
    x, p = prior.mean[0], prior.cov[0]
    for k in range(len(z)):
        if k:
            x, p = phi @ x, phi @ p @ phi.T + q
        np.testing.assert_allclose(result.predicted_mean[k, 0], x, rtol=1e-9, atol=1e-14)
        s = (h @ p @ h.T).item() + r
        gain = (p @ h.T)[:, 0] / s
        x = x + gain * (z[k, 0] - x[0])
        p = (np.eye(4) - np.outer(gain, h)) @ p
        np.testing.assert_allclose(result.filtered_mean[k, 0], x, rtol=1e-9, atol=1e-14)
        np.testing.assert_allclose(result.filtered_cov[k, 0], p, rtol=1e-7, atol=1e-18)


def test_joints_are_independent():
    z = operator_recording(num_samples=30, num_joints=3, seed=4)
    model = JerkModel.make(0.25, [1e-4, 1e-3, 1e-2], [1e-6, 2e-6, 3e-6], num_joints=3)
    both = rts_smoother(z, model, rest_prior(z[0], model)).mean
    for j in range(3):
        single = JerkModel.make(0.25, model.sigma[j], model.r[j], num_joints=1)
        alone = rts_smoother(z[:, j:j + 1], single, rest_prior(z[0, j:j + 1], single)).mean
        # To round-off of each state's scale: three joints' products go through BLAS's
        # matrix-matrix kernel, one joint's through its matrix-vector one.
        scale = np.abs(alone[:, 0]).max(axis=0)      # per state: q, its 1st..3rd derivative
        assert np.all(np.abs(both[:, j] - alone[:, 0]) <= 1e-12 * scale), j


def test_smoother_follows_a_constant_exactly():
    z = np.full((20, 1), 0.7)
    model = JerkModel.make(0.25, 4e-4, 1e-6, num_joints=1)
    prior = GaussianPrior(mean=np.array([[0.7, 0, 0, 0]]), cov=np.eye(4)[None] * 1e-3)
    smoothed = rts_smoother(z, model, prior).mean
    np.testing.assert_allclose(smoothed[:, 0, 0], 0.7, rtol=0, atol=1e-12)
    np.testing.assert_allclose(smoothed[:, 0, 1:], 0.0, rtol=0, atol=1e-10)


def test_bad_input_is_named():
    model = JerkModel.make(0.25, 4e-4, 1e-6, num_joints=2, joint_names=("a", "b"))
    z = np.zeros((5, 2))
    z[3, 1] = np.nan
    with pytest.raises(ValueError, match=r"measurements\[3, 1\] = nan .* at sample 3"):
        kalman_filter(z, model, rest_prior(np.zeros(2), model))
    with pytest.raises(ValueError, match="has 3 joint column\\(s\\) but 2 were expected"):
        rts_smoother(np.zeros((5, 3)), model, rest_prior(np.zeros(2), model))
    with pytest.raises(ValueError, match=r"sigma_schedule\[2, 0\] = -1.0 for joint 0"):
        schedule = np.ones((5, 2))
        schedule[2, 0] = -1.0
        rts_smoother(np.zeros((5, 2)), model, rest_prior(np.zeros(2), model),
                     sigma_schedule=schedule)
