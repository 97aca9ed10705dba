"""Oracle tests of BMFLS: dense superstate Kalman filter, RTS on z_0..z_k, both methods."""

import numpy as np
import pytest
from core_fixtures import operator_recording

from telesmooth.smoothing.fixed_lag import FixedLagSmoother
from telesmooth.smoothing.kalman import GaussianPrior, kalman_filter, rts_smoother
from telesmooth.smoothing.model import JerkModel, process_covariance, transition_matrix

DT = 0.25


def _schedule(num_samples, num_joints, seed=5):
    rng = np.random.default_rng(seed)
    return np.exp(rng.uniform(np.log(1e-6), np.log(1e-2), size=(num_samples, num_joints)))


def _dense_superstate_filter(z, dt, schedule, r, lag, q0):
    """Independent oracle: the literal superstate KF of docs/method.md §3.1 with explicit
    Φ_BM, Q_BM."""
    n, m = 4, 4 * (lag + 1)
    phi_bm = np.zeros((m, m))
    phi_bm[:n, :n] = transition_matrix(dt)
    phi_bm[n:, :-n] = np.eye(m - n)
    h_bm = np.zeros((1, m))
    h_bm[0, 0] = 1.0
    x = np.tile([q0, 0.0, 0.0, 0.0], lag + 1)
    p = np.zeros((m, m))
    outputs = []
    for k in range(len(z)):
        q_bm = np.zeros((m, m))
        q_bm[:n, :n] = process_covariance(dt, schedule[k])
        x = phi_bm @ x
        p = phi_bm @ p @ phi_bm.T + q_bm
        s = (h_bm @ p @ h_bm.T).item() + r
        gain = (p @ h_bm.T)[:, 0] / s
        x = x + gain * (z[k] - x[0])
        p = p - s * np.outer(gain, gain)
        outputs.append(x.reshape(lag + 1, n).copy())
    return np.array(outputs)  # (N, L+1, 4): block i = x̂_{k−i|k}


@pytest.mark.parametrize("method", ["recursion", "superstate"])
@pytest.mark.parametrize("lag", [0, 1, 3, 6])
def test_every_block_equals_dense_superstate_filter(method, lag):
    z = operator_recording(num_samples=40, num_joints=2, seed=7)
    schedule = _schedule(40, 2)
    model = JerkModel.make(DT, 4e-4, [1e-6, 5e-6], num_joints=2)
    dut = FixedLagSmoother(model, lag=lag, method=method)
    state = dut.initial_state(z[0])
    blocks = []
    for k in range(len(z)):
        state = dut.step(state, z[k], schedule[k])
        blocks.append(dut.blocks(state))
    blocks = np.array(blocks)
    for j in range(2):
        dense = _dense_superstate_filter(z[:, j], DT, schedule[:, j], model.r[j], lag, z[0, j])
        scale = np.abs(dense).max(axis=(0, 1))
        np.testing.assert_allclose(blocks[:, j] / scale, dense / scale, rtol=0, atol=1e-11)


@pytest.mark.parametrize("lag", [1, 3, 8])
def test_output_at_k_minus_lag_equals_rts_on_data_so_far(lag):
    z = operator_recording(num_samples=30, num_joints=2, seed=8)
    schedule = _schedule(30, 2, seed=9)
    model = JerkModel.make(DT, 4e-4, 1e-6, num_joints=2)
    outputs = FixedLagSmoother(model, lag=lag).run(z, sigma_schedule=schedule)
    # Rest start I1 with P_rest = 0: x_{−1} = [z_0, 0, 0, 0] exactly, so x_0 ~ N(x_{−1}, Q(σ_0)).
    prior = GaussianPrior(
        mean=np.column_stack([z[0], np.zeros((2, 3))]),
        cov=process_covariance(DT, schedule[0]),
    )
    for k in range(lag, len(z)):
        rts = rts_smoother(z[: k + 1], model, prior, sigma_schedule=schedule[: k + 1]).mean
        scale = np.abs(rts).max(axis=0)
        np.testing.assert_allclose(outputs[k] / scale, rts[k - lag] / scale, rtol=0, atol=1e-11)
    # Before the FIFO has filled, the output is the rest pose
    # (FIFO pre-filled, docs/method.md §3.1).
    for k in range(lag):
        np.testing.assert_allclose(outputs[k, :, 0], z[0], rtol=0, atol=1e-15)
        np.testing.assert_allclose(outputs[k, :, 1:], 0.0, rtol=0, atol=1e-15)


def test_lag_zero_is_the_kalman_filter():
    z = operator_recording(num_samples=25, num_joints=1, seed=10)
    model = JerkModel.make(DT, 1e-3, 1e-6, num_joints=1)
    outputs = FixedLagSmoother(model, lag=0).run(z)
    prior = GaussianPrior(mean=np.array([[z[0, 0], 0, 0, 0]]),
                          cov=process_covariance(DT, model.sigma))
    filtered = kalman_filter(z, model, prior).filtered_mean
    np.testing.assert_allclose(outputs, filtered, rtol=1e-10, atol=1e-13)


def test_recursion_and_superstate_agree_at_long_lag():
    z = operator_recording(num_samples=120, num_joints=3, seed=11)
    schedule = _schedule(120, 3, seed=12)
    model = JerkModel.make(DT, 4e-4, 1e-6, num_joints=3)
    a = FixedLagSmoother(model, lag=75, method="recursion").run(z, sigma_schedule=schedule)
    b = FixedLagSmoother(model, lag=75, method="superstate").run(z, sigma_schedule=schedule)
    scale = np.abs(a).max(axis=0)
    np.testing.assert_allclose(a / scale, b / scale, rtol=0, atol=1e-11)


def test_validation_messages():
    model = JerkModel.make(DT, 4e-4, 1e-6, num_joints=2)
    with pytest.raises(ValueError, match="method = 'dense' must be one of"):
        FixedLagSmoother(model, method="dense")
    with pytest.raises(ValueError, match="lag = -1 must be an integer >= 0"):
        FixedLagSmoother(model, lag=-1)
    dut = FixedLagSmoother(model)
    state = dut.initial_state([0.0, 0.0])
    with pytest.raises(ValueError, match=r"^measurement\[1\] = inf for joint 1 must be finite$"):
        dut.step(state, [0.0, np.inf])
    with pytest.raises(ValueError, match=r"^start_position = \[0.0\] has shape \(1,\); "
                                         r"expected \(2,\), one per joint$"):
        dut.initial_state([0.0])
