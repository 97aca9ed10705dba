"""The 4 Hz ground-station stages: delay FIFO, reduced-Q smoother, uplink, period mean.

Latency is counted in samples: packet k (sequence number k, sent at t_k = k·Δt) must carry
the estimate of the sample taken at t_{k−L}. Loggers sample at t_k *before* the tick's update
(Drake's publish convention), so a row logged at t_k shows packet k−1; the helpers below key
everything by the logged sequence number instead of by time.
"""

import numpy as np
import pytest
from core_fixtures import operator_recording
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder, LeafSystem
from pydrake.systems.primitives import LogVectorOutput

from telesmooth.smoothing.fixed_lag import FixedLagSmoother
from telesmooth.smoothing.model import JerkModel
from telesmooth.smoothing.online_hard import online_hard_run
from telesmooth.smoothing.reduced_q import OnlineCks, ReducedQConfig
from telesmooth.smoothing.state_vector import OnlineCksStateVector
from telesmooth.systems.delay_fifo import DelayFifo, DelayFifoConfig
from telesmooth.systems.period_mean import PeriodMean, PeriodMeanConfig
from telesmooth.systems.reduced_q_smoother import ReducedQSmoother, ReducedQSmootherConfig
from telesmooth.systems.uplink import Uplink, UplinkConfig

DT = 0.25
LAG = 3
JOINTS = ("shoulder", "elbow")


class TickTable(LeafSystem):
    """Test source: row k of ``table`` for t in [t_k, t_{k+1}); last row after the end."""

    def __init__(self, table, period_s=DT):
        super().__init__()
        self._table = np.asarray(table, dtype=float)
        self._period = period_s
        self.DeclareVectorOutputPort("y", self._table.shape[1], self._calc)

    def _calc(self, context, output):
        k = int(np.floor(context.get_time() / self._period + 1e-9))
        output.SetFromVector(self._table[min(k, len(self._table) - 1)])


def run_chain(z, *, method="online-cks", collision=None, enable=None, fifo_config=None,
              smoother_config=None, q0=None):
    """Source → FIFO → smoother → uplink (q_sent fed back); returns per-packet records."""
    z = np.asarray(z, dtype=float)
    num_ticks, n = z.shape
    q0 = z[0] if q0 is None else q0
    builder = DiagramBuilder()
    source = builder.AddSystem(TickTable(z))
    fifo = builder.AddSystem(DelayFifo(fifo_config or DelayFifoConfig(), num_joints=n,
                                       initial_position_rad=q0))
    smoother = builder.AddSystem(ReducedQSmoother(
        smoother_config or ReducedQSmootherConfig(method=method),
        joint_names=JOINTS[:n], initial_position_rad=q0))
    uplink = builder.AddSystem(Uplink(num_joints=n, initial_position_rad=q0))
    builder.Connect(source.get_output_port(), fifo.get_q_target_input_port())
    builder.Connect(fifo.get_q_newest_output_port(), smoother.get_q_sample_input_port())
    builder.Connect(fifo.get_reset_output_port(), smoother.get_reset_input_port())
    builder.Connect(smoother.get_q_smoothed_output_port(), uplink.get_q_smoothed_input_port())
    builder.Connect(uplink.get_q_sent_output_port(), fifo.get_q_sent_input_port())
    if collision is not None:
        flags = builder.AddSystem(TickTable(np.asarray(collision, float)[:, None]))
        builder.Connect(flags.get_output_port(), fifo.get_collision_detected_input_port())
    if enable is not None:
        clutch = builder.AddSystem(TickTable(np.asarray(enable, float)[:, None]))
        builder.Connect(clutch.get_output_port(), fifo.get_enable_input_port())
    logs = {
        "seq": LogVectorOutput(uplink.get_sequence_number_output_port(), builder, DT),
        "time": LogVectorOutput(uplink.get_send_time_output_port(), builder, DT),
        "q_sent": LogVectorOutput(uplink.get_q_sent_output_port(), builder, DT),
    }
    diagram = builder.Build()
    simulator = Simulator(diagram)
    # Ticks 0..num_ticks−1 run; the logger at t_{num_ticks} shows the last packet.
    simulator.AdvanceTo(num_ticks * DT + 1e-6)
    context = simulator.get_context()
    seq = logs["seq"].FindLog(context).data()[0]
    keep = seq >= 0
    records = {
        "seq": seq[keep].astype(int),
        "send_time": logs["time"].FindLog(context).data()[0][keep],
        "q_sent": logs["q_sent"].FindLog(context).data().T[keep],
    }
    return records, smoother


def test_fifo_port_contract_and_first_outputs():
    dut = DelayFifo(num_joints=2, initial_position_rad=[0.1, 0.2])
    names = [dut.get_input_port(i).get_name() for i in range(dut.num_input_ports())]
    assert names == ["q_target", "collision_detected", "q_sent", "enable", "stop_requested"]
    outputs = {dut.get_output_port(i).get_name(): dut.get_output_port(i).size()
               for i in range(dut.num_output_ports())}
    assert outputs == {"q_newest": 2, "q_delayed": 2, "window": 8, "reset": 1, "holding": 1}
    context = dut.CreateDefaultContext()
    dut.get_q_target_input_port().FixValue(context, [1.0, 2.0])
    np.testing.assert_array_equal(dut.get_window_output_port().Eval(context),
                                  [0.1, 0.2] * 3 + [1.0, 2.0])
    np.testing.assert_array_equal(dut.get_q_delayed_output_port().Eval(context), [0.1, 0.2])
    np.testing.assert_array_equal(dut.get_q_newest_output_port().Eval(context), [1.0, 2.0])
    assert dut.get_reset_output_port().Eval(context)[0] == 0.0
    dut.get_collision_detected_input_port().FixValue(context, [1.0])
    dut.get_q_sent_input_port().FixValue(context, [0.5, 0.6])
    np.testing.assert_array_equal(dut.get_window_output_port().Eval(context), [0.5, 0.6] * 4)
    assert dut.get_reset_output_port().Eval(context)[0] == 1.0


def test_pass_through_latency_is_exactly_lag_samples():
    rng = np.random.default_rng(3)
    z = np.cumsum(rng.normal(0.0, 0.01, (40, 2)), axis=0)
    records, _ = run_chain(z, method="pass-through")
    assert list(records["seq"]) == list(range(40))
    np.testing.assert_allclose(records["send_time"], DT * np.arange(40), atol=1e-12)
    for k, q in zip(records["seq"], records["q_sent"]):
        expected = z[k - LAG] if k >= LAG else z[0]
        np.testing.assert_array_equal(q, expected)


def test_step_reaches_the_uplink_after_three_ticks():
    z = np.zeros((20, 1))
    z[5:] = 0.2
    records, _ = run_chain(z, method="pass-through")
    first = records["seq"][np.argmax(records["q_sent"][:, 0] > 0.1)]
    assert first == 5 + LAG
    assert records["send_time"][first] == pytest.approx((5 + LAG) * DT)


@pytest.mark.parametrize("variant", ["A", "B1", "B2"])
def test_online_cks_system_equals_the_core_on_the_same_samples(variant):
    z = operator_recording(num_samples=60, num_joints=2, seed=4)
    config = ReducedQSmootherConfig(method="online-cks", reduced_q=ReducedQConfig(variant=variant),
                                    max_acceleration_rad_per_s2=0.02, max_jerk_rad_per_s3=0.05)
    records, smoother = run_chain(z, smoother_config=config)
    core = smoother.online.run(z, start_position=z[0])
    assert core.triggered.any(), "limits must bind for this test to mean something"
    np.testing.assert_allclose(records["q_sent"], core.outputs[:, :, 0], rtol=0, atol=1e-13)


def test_online_hard_system_equals_the_core_and_meets_the_limits():
    z = operator_recording(num_samples=60, num_joints=2, seed=4)
    config = ReducedQSmootherConfig(method="online-hard", max_acceleration_rad_per_s2=0.02,
                                    max_jerk_rad_per_s3=0.05)
    records, smoother = run_chain(z, smoother_config=config)
    online = smoother.online.run(z, start_position=z[0]).outputs[:, :, 0]
    expected = online_hard_run(online, DT, max_acceleration=0.02, max_jerk=0.05, q_start=z[0])
    assert np.abs(expected - online).max() > 1e-3, "the limiter must act for this test to mean"
    np.testing.assert_allclose(records["q_sent"], expected, rtol=0, atol=1e-13)
    sent = np.vstack([np.repeat(z[:1], 3, axis=0), records["q_sent"]])
    assert np.abs(np.diff(sent, 2, axis=0)).max() / DT**2 <= 0.02 * (1 + 1e-9)
    assert np.abs(np.diff(sent, 3, axis=0)).max() / DT**3 <= 0.05 * (1 + 1e-9)


def test_online_hard_needs_finite_limits():
    with pytest.raises(ValueError, match=r"max_jerk_rad_per_s3\[0\] = inf"):
        ReducedQSmoother(ReducedQSmootherConfig(method="online-hard", max_jerk_rad_per_s3=np.inf),
                         joint_names=JOINTS, initial_position_rad=[0.0, 0.0])


def test_bmfls_system_equals_fixed_lag_core():
    z = operator_recording(num_samples=50, num_joints=2, seed=5)
    records, smoother = run_chain(z, method="bmfls")
    model = JerkModel.make(DT, 4e-4, 1e-6, num_joints=2)
    core = FixedLagSmoother(model, lag=LAG).run(z, start_position=z[0])
    np.testing.assert_allclose(records["q_sent"], core[:, :, 0], rtol=0, atol=1e-13)


def test_sigma_output_tracks_the_core_and_never_increases():
    z = operator_recording(num_samples=60, num_joints=2, seed=6)
    config = ReducedQSmootherConfig(max_acceleration_rad_per_s2=0.02, max_jerk_rad_per_s3=0.05)
    dut = ReducedQSmoother(config, joint_names=JOINTS, initial_position_rad=z[0])
    context = dut.CreateDefaultContext()
    core = dut.online.run(z, start_position=z[0])
    sigmas = []
    for k in range(len(z)):
        context.SetTime(k * DT)
        dut.get_q_sample_input_port().FixValue(context, z[k])
        sigmas.append(dut.get_sigma_output_port().Eval(context).copy())
        np.testing.assert_allclose(dut.get_q_smoothed_output_port().Eval(context),
                                   core.outputs[k, :, 0], atol=1e-13)
        state = dut.get_state_smoothed_output_port().Eval(context)
        np.testing.assert_allclose(state.reshape(4, 2).T, core.outputs[k], atol=1e-12)
        np.testing.assert_array_equal(dut.get_triggered_output_port().Eval(context),
                                      core.triggered[k].astype(float))
        dut.CalcForcedDiscreteVariableUpdate(context, context.get_mutable_discrete_state())
    sigmas = np.array(sigmas)
    np.testing.assert_allclose(sigmas, core.sigma, rtol=1e-15)
    assert np.all(np.diff(sigmas, axis=0) <= 0.0)
    assert sigmas[-1].max() < sigmas[0].max()


def test_collision_refills_with_the_sent_command_and_resets_the_smoother():
    t = np.arange(40) * DT
    z = np.stack([0.02 * t, -0.01 * t], axis=1)
    collision = np.zeros(40)
    collision[20:26] = 1.0
    for method in ("pass-through", "online-cks", "bmfls"):
        records, _ = run_chain(z, method=method, collision=collision)
        q = records["q_sent"]
        held = q[19]
        # Ticks 20..25: the robot holds the command sent at tick 19, exactly.
        for k in range(20, 26):
            np.testing.assert_array_equal(q[k], held, err_msg=f"{method} tick {k}")
        if method == "pass-through":
            # After the hold the queue still holds q_held for L ticks, then new samples flow.
            for k in range(26, 26 + LAG):
                np.testing.assert_array_equal(q[k], held)
            np.testing.assert_array_equal(q[26 + LAG], z[26])
        # Nothing queued before the collision (samples 17..19) is ever sent after it.
        for k in range(20, 40):
            for j in (17, 18, 19):
                assert not np.array_equal(q[k], z[j]) or np.array_equal(z[j], held)


def test_clutch_release_policy_holds_until_reindexed():
    t = np.arange(40) * DT
    z = np.stack([0.02 * t], axis=1)
    collision = np.zeros(40)
    collision[10:12] = 1.0
    enable = np.ones(40)
    enable[18:20] = 0.0
    records, _ = run_chain(z, method="pass-through", collision=collision, enable=enable,
                           fifo_config=DelayFifoConfig(release="clutch"))
    q = records["q_sent"][:, 0]
    held = q[9]
    # Collision cleared at tick 12 but the hold lasts until the clutch re-engages at 20.
    np.testing.assert_array_equal(q[10:20 + LAG], held)
    assert q[20 + LAG] == z[20, 0]


def test_nan_sample_is_never_queued():
    z = np.tile([[0.1, 0.2]], (12, 1))
    z[6] = [np.nan, 0.2]
    records, _ = run_chain(z, method="pass-through")
    assert np.all(np.isfinite(records["q_sent"]))
    np.testing.assert_array_equal(records["q_sent"][6], records["q_sent"][5])


def test_uplink_holds_and_flags_a_non_finite_command():
    dut = Uplink(UplinkConfig(), num_joints=2, initial_position_rad=[0.0, 0.0])
    context = dut.CreateDefaultContext()
    assert dut.get_sequence_number_output_port().Eval(context)[0] == -1.0
    for k, command in enumerate(([0.1, 0.2], [np.nan, 0.3], [0.4, 0.5])):
        context.SetTime(k * DT)
        dut.get_q_smoothed_input_port().FixValue(context, command)
        dut.CalcForcedDiscreteVariableUpdate(context, context.get_mutable_discrete_state())
        assert dut.get_sequence_number_output_port().Eval(context)[0] == k
        assert dut.get_send_time_output_port().Eval(context)[0] == k * DT
        rejected = dut.get_command_rejected_output_port().Eval(context)[0]
        assert rejected == (1.0 if k == 1 else 0.0)
        expected = [0.1, 0.2] if k < 2 else [0.4, 0.5]
        np.testing.assert_array_equal(dut.get_q_sent_output_port().Eval(context), expected)


def test_uplink_marks_hold_packets():
    dut = Uplink(UplinkConfig(), num_joints=1, initial_position_rad=[0.0])
    context = dut.CreateDefaultContext()
    # (command, ground-station hold flag) → packet marked as a hold?
    cases = (([0.1], None, 0.0), ([0.2], 0.0, 0.0), ([0.2], 1.0, 1.0), ([np.nan], 0.0, 1.0),
             ([0.3], 0.0, 0.0))
    for k, (command, holding, expected) in enumerate(cases):
        context.SetTime(k * DT)
        dut.get_q_smoothed_input_port().FixValue(context, command)
        if holding is not None:
            dut.get_holding_input_port().FixValue(context, [holding])
        dut.CalcForcedDiscreteVariableUpdate(context, context.get_mutable_discrete_state())
        assert dut.get_holding_sent_output_port().Eval(context)[0] == expected, k


def test_uplink_holds_between_ticks_in_a_simulator():
    builder = DiagramBuilder()
    source = builder.AddSystem(TickTable(np.arange(8.0)[:, None], period_s=0.1))
    dut = builder.AddSystem(Uplink(num_joints=1))
    builder.Connect(source.get_output_port(), dut.get_q_smoothed_input_port())
    log = LogVectorOutput(dut.get_q_sent_output_port(), builder, 0.05)
    simulator = Simulator(builder.Build())
    simulator.AdvanceTo(0.8 + 1e-6)
    data = log.FindLog(simulator.get_context())
    times, values = data.sample_times(), data.data()[0]
    for time, value in zip(times, values):
        # Just after t_k = 0.25 k the uplink holds the source value of that instant.
        k = int(np.floor(time / DT - 1e-9)) if time > 0 else -1
        expected = 0.0 if k < 0 else np.floor(k * DT / 0.1 + 1e-9)
        assert value == expected, (time, value)


def test_period_mean_is_the_mean_of_the_last_window():
    rng = np.random.default_rng(7)
    samples = rng.normal(size=(60, 2))
    builder = DiagramBuilder()
    source = builder.AddSystem(TickTable(samples, period_s=0.01))
    dut = builder.AddSystem(PeriodMean(PeriodMeanConfig(), num_joints=2))
    builder.Connect(source.get_output_port(), dut.get_q_target_input_port())
    diagram = builder.Build()
    simulator = Simulator(diagram)
    for j in (24, 25, 40, 59):
        simulator.AdvanceTo(j * 0.01 + 0.005)
        out = dut.get_q_mean_output_port().Eval(dut.GetMyContextFromRoot(simulator.get_context()))
        window = samples[max(0, j - 24):j + 1]
        padded = np.vstack([np.zeros((25 - len(window), 2)), window])
        np.testing.assert_allclose(out, padded.mean(axis=0), atol=1e-14)


@pytest.mark.parametrize("method", ["recursion", "superstate"])
@pytest.mark.parametrize("variant", ["A", "B1", "B2"])
def test_state_vector_round_trip_is_exact(method, variant):
    z = operator_recording(num_samples=12, num_joints=3, seed=8)
    model = JerkModel.make(DT, 4e-4, 1e-6, num_joints=3)
    online = OnlineCks(model, max_acceleration=0.01, max_jerk=0.02, method=method,
                       config=ReducedQConfig(variant=variant))
    packer = OnlineCksStateVector(online)
    state = online.initial_state(z[0])
    for k in range(12):
        state, _, _ = online.step(state, z[k])
        restored = packer.unpack(packer.pack(state))
        np.testing.assert_array_equal(restored.smoother.blocks_scaled,
                                      state.smoother.blocks_scaled)
        np.testing.assert_array_equal(restored.smoother.covariance, state.smoother.covariance)
        assert restored.smoother.steps == state.smoother.steps
        np.testing.assert_array_equal(restored.sigma, state.sigma)
        np.testing.assert_array_equal(restored.sent_positions, state.sent_positions)
        assert len(restored.window) == len(state.window)
        for (a, za), (b, zb) in zip(restored.window, state.window):
            np.testing.assert_array_equal(a.blocks_scaled, b.blocks_scaled)
            np.testing.assert_array_equal(za, zb)
    with pytest.raises(ValueError, match="shape"):
        packer.unpack(np.zeros(3))


@pytest.mark.parametrize("factory,match", [
    (lambda: DelayFifoConfig(delay_s=0.7), r"delay_s = 0.7 is not a whole number"),
    (lambda: DelayFifoConfig(period_s=-0.25), r"period_s = -0.25 must be positive"),
    (lambda: DelayFifoConfig(release="flush"), r"release = 'flush'"),
    (lambda: ReducedQSmootherConfig(method="magic"), r"method = 'magic'"),
    (lambda: ReducedQSmootherConfig(lag=-1), r"lag = -1"),
    (lambda: UplinkConfig(period_s=float("nan")), r"period_s = nan"),
    (lambda: PeriodMeanConfig(window_s=0.255), r"window_s = 0.255 is not a whole number"),
    (lambda: DelayFifo(num_joints=0), r"num_joints = 0"),
    (lambda: DelayFifo(num_joints=2, initial_position_rad=[0.0, np.inf]),
     r"initial_position_rad\[1\] = inf for joint 1 must be finite"),
    (lambda: ReducedQSmoother(joint_names=JOINTS, initial_position_rad=[0.0, np.nan]),
     r"initial_position_rad\[1\] = nan for joint 1 \('elbow'\) must be finite"),
    (lambda: ReducedQSmoother(ReducedQSmootherConfig(max_jerk_rad_per_s3=(0.1, -1.0)),
                              joint_names=JOINTS), r"elbow"),
    (lambda: Uplink(num_joints=2, initial_position_rad=[0.0]),
     r"initial_position_rad = \[0.0\] has shape \(1,\); expected \(2,\), one per joint$"),
])
def test_bad_configuration_is_rejected_with_a_clear_message(factory, match):
    with pytest.raises(ValueError, match=match):
        factory()


def test_clutch_policy_without_enable_input_says_so():
    dut = DelayFifo(DelayFifoConfig(release="clutch"), num_joints=1)
    context = dut.CreateDefaultContext()
    dut.get_q_target_input_port().FixValue(context, [0.0])
    with pytest.raises(RuntimeError, match="'enable' input"):
        dut.get_window_output_port().Eval(context)


def test_fifo_and_smoother_outputs_describe_the_same_instant():
    """On a noise-free ramp (in the jerk model's null space) the smoothed command converges to
    the FIFO's delayed sample of the same tick, and is clearly apart from its neighbours."""
    slope = 0.02
    ramp = slope * DT * np.arange(80)[:, None]
    builder = DiagramBuilder()
    source = builder.AddSystem(TickTable(ramp))
    fifo = builder.AddSystem(DelayFifo(num_joints=1, initial_position_rad=[0.0]))
    smoother = builder.AddSystem(ReducedQSmoother(
        ReducedQSmootherConfig(method="bmfls"), joint_names=("j",), initial_position_rad=[0.0]))
    builder.Connect(source.get_output_port(), fifo.get_q_target_input_port())
    builder.Connect(fifo.get_q_newest_output_port(), smoother.get_q_sample_input_port())
    diagram = builder.Build()
    context = diagram.CreateDefaultContext()
    fifo_context = fifo.GetMyContextFromRoot(context)
    smoother_context = smoother.GetMyContextFromRoot(context)
    simulator = Simulator(diagram, context)
    simulator.AdvanceTo(70 * DT + 1e-6)   # ticks 0..70 done; the state holds tick 70
    context.SetTime(71 * DT)               # outputs now describe tick 71
    delayed = fifo.get_q_delayed_output_port().Eval(fifo_context)[0]
    smoothed = smoother.get_q_smoothed_output_port().Eval(smoother_context)[0]
    assert delayed == pytest.approx(ramp[71 - LAG, 0], abs=1e-15)
    assert abs(smoothed - delayed) < 1e-4
    assert abs(smoothed - ramp[70 - LAG, 0]) > 4e-3
    assert abs(smoothed - ramp[72 - LAG, 0]) > 4e-3
