"""PlannedPathSource: the offline playback's 4 Hz source (row k on [t_k, t_{k+1}), then rest)."""

import numpy as np
import pytest

from telesmooth.systems.planned_path_source import PlannedPathSource

TICK = 0.25


def _outputs_at(dut, t):
    context = dut.CreateDefaultContext()
    context.SetTime(t)
    return (dut.get_q_planned_output_port().Eval(context),
            dut.get_state_planned_output_port().Eval(context))


def _path(num_samples=4, num_joints=2):
    q = np.arange(num_samples * num_joints, dtype=float).reshape(num_samples, num_joints)
    states = np.random.default_rng(0).normal(size=(num_samples, num_joints, 4))
    states[:, :, 0] = q
    return q, states


def test_port_contract():
    q, _ = _path()
    dut = PlannedPathSource(q, period_s=TICK)
    assert dut.num_input_ports() == 0
    assert [dut.get_output_port(i).get_name() for i in range(dut.num_output_ports())] == [
        "q_planned", "state_planned"]
    assert dut.get_q_planned_output_port().size() == 2
    assert dut.get_state_planned_output_port().size() == 8
    context = dut.CreateDefaultContext()
    assert context.num_continuous_states() == 0 and context.num_discrete_state_groups() == 0


def test_row_k_is_held_over_its_tick_and_the_last_row_rests():
    q, states = _path()
    dut = PlannedPathSource(q, period_s=TICK, states=states)
    # A tick time a few ulps below k·Δt (as the simulator may compute it) still selects row k.
    for t, k in [(-1.0, 0), (0.0, 0), (0.2499, 0), (TICK, 1), (1.5 * TICK, 1), (2 * TICK, 2),
                 (3 * TICK * (1 - 1e-12), 3), (3 * TICK, 3)]:
        position, state = _outputs_at(dut, t)
        np.testing.assert_array_equal(position, q[k], err_msg=f"t = {t}")
        # Uplink layout: [q (J), q̇ (J), q̈ (J), q⃛ (J)].
        np.testing.assert_array_equal(state, states[k].T.reshape(-1), err_msg=f"t = {t}")
    for t in (4 * TICK, 100.0):
        position, state = _outputs_at(dut, t)
        np.testing.assert_array_equal(position, q[-1])
        np.testing.assert_array_equal(state, np.concatenate([q[-1], np.zeros(6)]))


def test_without_states_the_derivatives_are_zero():
    q, _ = _path()
    position, state = _outputs_at(PlannedPathSource(q, period_s=TICK), 2 * TICK)
    np.testing.assert_array_equal(position, q[2])
    np.testing.assert_array_equal(state, np.concatenate([q[2], np.zeros(6)]))


@pytest.mark.parametrize("positions, states, match", [
    (np.zeros(3), None, r"positions must be finite with shape \(N, J\); got \(3,\)"),
    (np.zeros((0, 2)), None, r"got \(0, 2\)"),
    (np.array([[0.0, np.nan]]), None, r"positions must be finite"),
    (np.zeros((3, 2)), np.zeros((3, 2, 3)), r"states must be finite with shape \(3, 2, 4\); "
                                            r"got \(3, 2, 3\)"),
])
def test_invalid_input_raises(positions, states, match):
    with pytest.raises(ValueError, match=match):
        PlannedPathSource(positions, period_s=TICK, states=states)
