"""Jerk-limited collision stop: the planner core and the FIFO's "stop" policy.

Core tests (no simulator): seeded random sent histories inside the stoppable set are braked to
rest with every FD acceleration and jerk — recomputed with numpy from the sent sequence,
history included — within the limits; the stop stays between q_hold and q_hold + the
reported braking distance; every braking pose is checked; each fallback reason is reached.
System tests: FIFO → smoother → uplink with the uplink's q_sent fed back, as on the ground
station: the packets are the plan, the hold flag covers the stop, the hold is not released
before rest, and the queue continues from the rest pose.
"""

import numpy as np
import pytest
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder, LeafSystem
from pydrake.systems.primitives import LogVectorOutput

from telesmooth.safety.limiter import stop_position
from telesmooth.safety.stop import (
    SAME_SIDE_TOLERANCE_RAD,
    STOP_OUTCOMES,
    STOPPABLE_ROUNDING_TOLERANCE,
    nudge_into_stoppable_set,
    stop_params,
)
from telesmooth.systems.collision_stop import MakeCollisionStopPlanner, PreSimulatorPoseCheck
from telesmooth.systems.delay_fifo import DelayFifo, DelayFifoConfig
from telesmooth.systems.reduced_q_smoother import ReducedQSmoother, ReducedQSmootherConfig
from telesmooth.systems.uplink import Uplink

DT = 0.25
LAG = 3
A_MAX = 0.2
J_MAX = 0.5
RELATIVE = 1e-9
JOINTS = ("shoulder", "elbow")


def always_safe(q):
    return True


def make_planner(pose_is_safe=always_safe, *, max_velocity=None, a_max=A_MAX, j_max=J_MAX,
                 joints=JOINTS):
    return stop_params(dt_s=DT, max_acceleration=a_max, max_jerk=j_max,
                                max_velocity=max_velocity, pose_is_safe=pose_is_safe,
                                joint_names=joints)


def history_from(q_hold, velocity, acceleration):
    """Sent commands p_{k−3}, p_{k−2}, p_{k−1} = q_hold with these FD v and a."""
    q_hold, v, a = (np.asarray(x, dtype=float) for x in (q_hold, velocity, acceleration))
    p2 = q_hold - v * DT
    p1 = p2 - (v - a * DT) * DT
    return np.array([p1, p2, q_hold])


def fd_ratios(sent, first, *, a_max, j_max, v_max=None):
    """Largest |FD acceleration|/a_max, |FD jerk|/j_max (and |v|/v_max) over the differences
    whose newest sample is sent[first] or later."""
    sent = np.asarray(sent, dtype=float)
    acc = np.diff(sent, 2, axis=0)[first - 2:] / DT**2
    jerk = np.diff(sent, 3, axis=0)[first - 3:] / DT**3
    ratios = [np.max(np.abs(acc) / a_max), np.max(np.abs(jerk) / j_max)]
    if v_max is not None:
        ratios.append(np.max(np.abs(np.diff(sent, axis=0)[first - 1:] / DT) / v_max))
    return ratios


# -- the planner core ----------------------------------------------------------------------------

@pytest.mark.parametrize("v_max", [None, 0.3])
def test_random_stoppable_histories_brake_to_rest_within_the_limits(v_max):
    rng = np.random.default_rng(0)
    dut = make_planner(max_velocity=v_max)
    outcomes = []
    for _ in range(300):
        q_hold = rng.uniform(-2.0, 2.0, size=2)
        v = rng.uniform(-0.5, 0.5, size=2) * (1.0 if v_max is None else 0.6)
        a = rng.uniform(-1.0, 1.0, size=2) * A_MAX * 0.999
        plan = dut.plan(history_from(q_hold, v, a), max_ticks=400)
        outcomes.append(plan.outcome.label)
        if not plan.is_stop:
            assert plan.outcome.label in ("hold-not-stoppable", "hold-reverses")
            np.testing.assert_array_equal(plan.commands, [plan.hold_position])
            continue
        sent = np.vstack([history_from(q_hold, v, a), plan.commands, plan.commands[-1:],
                          plan.commands[-1:]])
        # Guarantee 1: FD acceleration and jerk of every stop command, history included.
        ratios = fd_ratios(sent, 3, a_max=A_MAX, j_max=J_MAX, v_max=v_max)
        assert max(ratios) <= 1.0 + RELATIVE, ratios
        # At rest: the last three commands are equal (and the hold keeps that pose).
        np.testing.assert_array_equal(sent[-5], sent[-3])
        # Guarantee 2: between q_hold and q_hold + braking distance, per joint.
        excursion = plan.commands - q_hold
        d = plan.braking_distance
        assert np.all(np.abs(excursion) <= np.abs(d))
        assert np.all(excursion * np.sign(d) >= -SAME_SIDE_TOLERANCE_RAD)
        # The rest pose is the time-optimal continuous stop point of the sent state.
        shrink = 1.0 - 1e-9
        target = stop_position(q_hold, v, a, A_MAX * shrink, J_MAX * shrink)
        np.testing.assert_allclose(plan.rest_position, target, rtol=0.0, atol=1e-9)
    assert outcomes.count("stop") > 200, {name: outcomes.count(name) for name in set(outcomes)}


def test_every_braking_pose_is_checked_and_a_rejected_pose_falls_back_to_hold():
    history = history_from([0.3, -0.2], [0.2, -0.1], [0.05, 0.0])
    queried = []

    def record(q):
        queried.append(np.array(q))
        return True

    accepted = make_planner(record).plan(history, max_ticks=100)
    assert accepted.is_stop and accepted.ticks_to_rest > 4
    np.testing.assert_array_equal(np.array(queried), accepted.commands)
    # A wall half way along joint 0's braking distance.
    wall = 0.3 + 0.5 * accepted.braking_distance[0]
    rejected = make_planner(lambda q: q[0] < wall).plan(history, max_ticks=100)
    assert rejected.outcome.label == "hold-pose-rejected"
    assert rejected.rejected_command == int(np.argmax(accepted.commands[:, 0] >= wall))
    np.testing.assert_array_equal(rejected.commands, [history[-1]])
    np.testing.assert_array_equal(rejected.braking_distance, [0.0, 0.0])


def test_a_state_outside_the_stoppable_set_falls_back_to_hold():
    dut = make_planner(max_velocity=0.3)
    # |a| above a_max (the Online-CKS history may break the limits).
    assert dut.plan(history_from([0.0, 0.0], [0.1, 0.0], [1.01 * A_MAX, 0.0]),
                    max_ticks=100).outcome.label == "hold-not-stoppable"
    # Inside the box but cornered: at the velocity limit and still accelerating.
    plan = dut.plan(history_from([0.0, 0.0], [0.3, 0.0], [0.5 * A_MAX, 0.0]), max_ticks=100)
    assert plan.outcome.label == "hold-not-stoppable"
    assert int(plan.outcome) == 3


def test_a_stop_that_must_first_reverse_falls_back_to_hold():
    # Slow and already braking hard: the first command still moves forward (by 0.19 mrad),
    # then every admissible stop passes back behind q_hold (to about −0.82 mrad).
    plan = make_planner().plan(history_from([0.0, 0.0], [0.02, 0.0], [-0.1692, 0.0]),
                               max_ticks=100)
    assert plan.outcome.label == "hold-reverses"
    np.testing.assert_array_equal(plan.commands, [[0.0, 0.0]])
    # Moving back from the first command on is not a reversal: it stays on one side.
    backward = make_planner().plan(history_from([0.0, 0.0], [0.01, 0.0], [-0.19, 0.0]),
                                   max_ticks=100)
    assert backward.is_stop and backward.braking_distance[0] < 0.0


def test_too_long_a_stop_falls_back_to_hold():
    history = history_from([0.0, 0.0], [0.4, 0.0], [0.0, 0.0])
    assert make_planner().plan(history, max_ticks=4).outcome.label == "hold-too-long"
    assert make_planner().plan(history, max_ticks=100).is_stop


def test_a_history_at_rest_is_a_one_command_stop():
    plan = make_planner().plan(np.tile([0.1, 0.2], (3, 1)), max_ticks=10)
    assert plan.is_stop and plan.ticks_to_rest == 1
    np.testing.assert_array_equal(plan.commands, [[0.1, 0.2]])
    np.testing.assert_array_equal(plan.braking_distance, [0.0, 0.0])


class _FakeCollisionModel:
    """A collision model whose 'obstacle' is joint 0 above 1.0 rad."""

    class _Query:
        def __init__(self, distance):
            self.min_distance_m = distance

        def in_collision(self, margin_m=0.0):
            return self.min_distance_m < margin_m

    def query(self, q):
        return self._Query(1.0 - q[0])


def test_pre_simulator_pose_check_uses_margin_and_joint_limits():
    dut = PreSimulatorPoseCheck(_FakeCollisionModel(), safety_margin_m=0.1,
                                lower_rad=[-1.0, -1.0], upper_rad=[2.0, 1.0])
    assert dut([0.85, 0.0])
    assert not dut([0.95, 0.0])          # within the margin of the obstacle
    assert not dut([0.0, 1.5])           # beyond a joint limit
    assert not dut([np.nan, 0.0])


@pytest.mark.parametrize("make, message", [
    (lambda: DelayFifoConfig(on_collision="brake"), r"on_collision = 'brake' must be one of"),
    (lambda: DelayFifoConfig(max_stop_duration_s=0.3), r"max_stop_duration_s = 0.3 is not"),
    (lambda: DelayFifoConfig(max_stop_duration_s=0.0), r"max_stop_duration_s = 0.0 must be"),
    (lambda: DelayFifo(DelayFifoConfig(on_collision="stop"), num_joints=2),
     r"on_collision = 'stop' needs the collision_stop planner"),
    (lambda: DelayFifo(DelayFifoConfig(on_collision="stop", period_s=0.5, delay_s=1.5),
                       num_joints=2, collision_stop=make_planner()),
     r"collision_stop.dt_s = 0.25 must equal DelayFifoConfig.period_s = 0.5"),
    (lambda: DelayFifo(DelayFifoConfig(on_collision="stop"), num_joints=3,
                       collision_stop=make_planner()), r"collision_stop has 2 joints"),
    (lambda: make_planner(a_max=-1.0), r"max_acceleration_rad_per_s2.*-1.0"),
    (lambda: make_planner(pose_is_safe=None), r"pose_is_safe = None must be callable"),
    (lambda: make_planner().plan(np.zeros((2, 2)), max_ticks=5), r"sent_history has shape"),
    (lambda: make_planner().plan(np.zeros((3, 2)), max_ticks=0), r"max_ticks = 0"),
])
def test_bad_values_are_named(make, message):
    with pytest.raises(ValueError, match=message):
        make()


def test_make_planner_needs_finite_smoother_limits():
    from telesmooth.arms.planar import AIR_BEARING_ARM

    config = ReducedQSmootherConfig(max_jerk_rad_per_s3=float("inf"))
    with pytest.raises(ValueError, match=r"smoother.max_jerk_rad_per_s3 = inf must be finite"):
        MakeCollisionStopPlanner(period_s=DT, smoother_config=config, arm=AIR_BEARING_ARM,
                                 collision_model=_FakeCollisionModel(), safety_margin_m=0.02)


# -- the FIFO's "stop" policy in the ground chain ----------------------------------------------

class TickTable(LeafSystem):
    """Test source: row k of ``table`` for t in [t_k, t_{k+1}); last row after the end."""

    def __init__(self, table):
        super().__init__()
        self._table = np.asarray(table, dtype=float)
        self.DeclareVectorOutputPort("y", self._table.shape[1], self._calc)

    def _calc(self, context, output):
        k = int(np.floor(context.get_time() / DT + 1e-9))
        output.SetFromVector(self._table[min(k, len(self._table) - 1)])


def run_stop_chain(z, collision, *, fifo_config, planner=None):
    """Source → FIFO → smoother (pass-through) → uplink, q_sent fed back; per-tick records
    keyed by packet number (packet k is formed at tick k)."""
    z = np.asarray(z, dtype=float)
    num_ticks, n = z.shape
    builder = DiagramBuilder()
    source = builder.AddSystem(TickTable(z))
    flags = builder.AddSystem(TickTable(np.asarray(collision, float)[:, None]))
    fifo = builder.AddSystem(DelayFifo(fifo_config, num_joints=n, initial_position_rad=z[0],
                                       collision_stop=planner))
    smoother = builder.AddSystem(ReducedQSmoother(
        ReducedQSmootherConfig(method="pass-through"), joint_names=JOINTS[:n],
        initial_position_rad=z[0]))
    uplink = builder.AddSystem(Uplink(num_joints=n, initial_position_rad=z[0]))
    builder.Connect(source.get_output_port(), fifo.get_q_target_input_port())
    builder.Connect(flags.get_output_port(), fifo.get_collision_detected_input_port())
    builder.Connect(fifo.get_q_newest_output_port(), smoother.get_q_sample_input_port())
    builder.Connect(fifo.get_reset_output_port(), smoother.get_reset_input_port())
    builder.Connect(smoother.get_q_smoothed_output_port(), uplink.get_q_smoothed_input_port())
    builder.Connect(uplink.get_q_sent_output_port(), fifo.get_q_sent_input_port())
    builder.Connect(fifo.get_holding_output_port(), uplink.get_holding_input_port())
    # Logged at t_k before the update: the tick-k values of the FIFO; packet k−1 of the uplink.
    logs = {"holding": LogVectorOutput(fifo.get_holding_output_port(), builder, DT),
            "q_delayed": LogVectorOutput(fifo.get_q_delayed_output_port(), builder, DT),
            "q_sent": LogVectorOutput(uplink.get_q_sent_output_port(), builder, DT),
            "holding_sent": LogVectorOutput(uplink.get_holding_sent_output_port(), builder,
                                            DT)}
    if planner is not None:
        logs["braking_distance"] = LogVectorOutput(fifo.get_braking_distance_output_port(),
                                                   builder, DT)
        logs["stop_status"] = LogVectorOutput(fifo.get_stop_status_output_port(), builder, DT)
    simulator = Simulator(builder.Build())
    simulator.AdvanceTo(num_ticks * DT + 1e-6)
    context = simulator.get_context()
    out = {name: log.FindLog(context).data().T for name, log in logs.items()}
    # Rows 1.. of the uplink logs are packets 0..; rows 0.. of the FIFO logs are ticks 0...
    for name in ("q_sent", "holding_sent"):
        out[name] = out[name][1:]
    for name in ("holding", "q_delayed", "braking_distance", "stop_status"):
        if name in out:
            out[name] = out[name][:-1]
    return out


def ramp(num_ticks=60):
    t = np.arange(num_ticks) * DT
    return np.stack([0.3 + 0.12 * t, -0.2 - 0.05 * t], axis=1)


COLLISION_TICK = 20


def collision_flags(num_ticks=60, ticks=3):
    flags = np.zeros(num_ticks)
    flags[COLLISION_TICK:COLLISION_TICK + ticks] = 1.0
    return flags


def test_fifo_stop_sends_the_plan_within_the_limits_then_holds_and_continues_from_rest():
    z = ramp()
    planner = make_planner()
    out = run_stop_chain(z, collision_flags(), planner=planner,
                         fifo_config=DelayFifoConfig(on_collision="stop"))
    q = out["q_sent"]
    k = COLLISION_TICK
    plan = planner.plan(q[k - 3:k], max_ticks=120)
    assert plan.is_stop and plan.ticks_to_rest > 5   # longer than the collision flag
    n_stop = plan.ticks_to_rest
    # The packets are exactly the plan; the hold keeps its rest pose.
    np.testing.assert_array_equal(q[k:k + n_stop], plan.commands)
    # Guarantee 1 on the packets (history before the collision included).
    assert max(fd_ratios(q[:k + n_stop + 2], k, a_max=A_MAX, j_max=J_MAX)) <= 1.0 + RELATIVE
    # Held (and flagged) from the collision until the stop is at rest, not only while the
    # collision flag is up; released at the first tick after.
    release = k + n_stop
    np.testing.assert_array_equal(out["holding"][k:release, 0], 1.0)
    np.testing.assert_array_equal(out["holding_sent"][k:release, 0], 1.0)
    assert out["holding"][release, 0] == 0.0 and out["holding"][k - 1, 0] == 0.0
    # Reported: braking distance and outcome, from the collision tick on.
    np.testing.assert_array_equal(out["braking_distance"][k:], np.tile(plan.braking_distance,
                                                                       (len(z) - k, 1)))
    np.testing.assert_array_equal(out["braking_distance"][:k], 0.0)
    assert out["stop_status"][k - 1, 0] == 0 and out["stop_status"][k, 0] == 1
    # Guarantee 4: the queue continues from the rest pose, not from the q_sent of before the stop.
    rest = plan.rest_position
    np.testing.assert_array_equal(q[release:release + LAG], np.tile(rest, (LAG, 1)))
    np.testing.assert_array_equal(out["q_delayed"][release:release + LAG],
                                  np.tile(rest, (LAG, 1)))
    np.testing.assert_array_equal(q[release + LAG], z[release])


def test_fifo_stop_falls_back_to_exactly_the_hold_when_a_pose_is_rejected():
    z = ramp()
    hold = run_stop_chain(z, collision_flags(), fifo_config=DelayFifoConfig())
    wall = z[COLLISION_TICK - LAG - 1, 0] + 0.01
    out = run_stop_chain(z, collision_flags(), planner=make_planner(lambda q: q[0] < wall),
                         fifo_config=DelayFifoConfig(on_collision="stop"))
    np.testing.assert_array_equal(out["q_sent"], hold["q_sent"])
    np.testing.assert_array_equal(out["holding"], hold["holding"])
    assert out["stop_status"][COLLISION_TICK, 0] == STOP_OUTCOMES.index("hold-pose-rejected")
    np.testing.assert_array_equal(out["braking_distance"], 0.0)


def test_stop_only_ports_exist_only_with_the_stop_policy():
    hold = DelayFifo(num_joints=2)
    with pytest.raises(RuntimeError, match=r"'braking_distance' output exists only with"):
        hold.get_braking_distance_output_port()
    stop = DelayFifo(DelayFifoConfig(on_collision="stop"), num_joints=2,
                     collision_stop=make_planner())
    names = [stop.get_output_port(i).get_name() for i in range(stop.num_output_ports())]
    assert names[-2:] == ["braking_distance", "stop_status"]
    assert stop.get_stop_status_output_port().size() == 1


def test_the_fifo_plans_between_ticks_and_a_tick_without_a_plan_holds():
    """The stop is planned at mid-period from the history the next tick will have (never in
    an output calculation); a collision tick whose history was not planned (a tick forced
    without the mid-period update) falls back to the hold instead of planning on the spot."""
    moving = history_from([0.3, -0.2], [0.2, -0.1], [0.0, 0.0])
    config = DelayFifoConfig(on_collision="stop")
    fifo = DelayFifo(config, num_joints=2, initial_position_rad=[0.0, 0.0],
                     collision_stop=make_planner())
    # No plan for this history (a fresh context: the plan is the rest at the start pose).
    context = fifo.CreateDefaultContext()
    fifo.get_q_target_input_port().FixValue(context, [0.0, 0.0])
    fifo.get_q_sent_input_port().FixValue(context, moving[2])
    fifo.get_collision_detected_input_port().FixValue(context, [1.0])
    np.testing.assert_array_equal(fifo.get_q_delayed_output_port().Eval(context), moving[2])
    assert STOP_OUTCOMES[int(fifo.get_stop_status_output_port().Eval(context)[0])] == "hold"
    # In a simulation the sent commands m0, m1, m2 arrive at the ticks; the mid-period update
    # before the collision tick plans from [m0, m1, m2], and the tick plays that plan.
    simulator = Simulator(fifo)
    context = simulator.get_mutable_context()
    fifo.get_q_target_input_port().FixValue(context, [0.0, 0.0])
    fifo.get_collision_detected_input_port().FixValue(context, [0.0])
    # Tick k sends p_{k−1} = q_sent: m0 at tick 1, m1 at tick 2; m2 is sent at t_2 and the
    # mid-period update after it plans for tick 3 from [m0, m1, m2].
    for k, until in enumerate((1.0 * DT + 1e-3, 2.0 * DT + 1e-3, 2.5 * DT + 1e-3)):
        fifo.get_q_sent_input_port().FixValue(context, moving[k])
        simulator.AdvanceTo(until)
    fifo.get_collision_detected_input_port().FixValue(context, [1.0])
    context.SetTime(3 * DT)                                # tick 3, before its update
    plan = make_planner().plan(moving, max_ticks=config.max_stop_ticks)
    assert plan.is_stop and plan.ticks_to_rest > 2
    np.testing.assert_array_equal(fifo.get_q_delayed_output_port().Eval(context),
                                  plan.commands[0])
    assert STOP_OUTCOMES[int(fifo.get_stop_status_output_port().Eval(context)[0])] == "stop"
    np.testing.assert_array_equal(fifo.get_braking_distance_output_port().Eval(context),
                                  plan.braking_distance)


def _histories_at_the_limits(limiter, target, ticks=120):
    """The last three commands of ``limiter`` (from rest at 0) chasing ``target`` and its
    negative in turn, 20 ticks each: at its limits, FD states on the boundary of S."""
    target = np.asarray(target, dtype=float)
    sent = [np.zeros(target.size)] * 3
    for tick in range(ticks):
        sent.append(limiter.step(target if (tick // 20) % 2 == 0 else -target))
        yield np.array(sent[-3:])


def test_rounding_tolerance_plans_from_the_nudged_history_and_is_validated():
    from telesmooth.smoothing.online_hard import OnlineHardLimiter
    exact = make_planner()
    tolerant = stop_params(dt_s=DT, max_acceleration=A_MAX, max_jerk=J_MAX,
                                    pose_is_safe=always_safe, joint_names=JOINTS,
                                    rounding_tolerance=STOPPABLE_ROUNDING_TOLERANCE)
    limiter = OnlineHardLimiter(dt_s=DT, max_acceleration=A_MAX, max_jerk=J_MAX,
                                q_start=[0.0, 0.0])
    sets = limiter.stoppable_sets
    rescued = 0
    for history in _histories_at_the_limits(limiter, [2.0, -2.0]):
        plan = tolerant.plan(history, max_ticks=400)
        oracle = exact.plan(nudge_into_stoppable_set(history, sets, DT), max_ticks=400)
        assert plan.outcome == oracle.outcome
        np.testing.assert_array_equal(plan.commands, oracle.commands)
        rescued += exact.plan(history, max_ticks=400).outcome.label == "hold-not-stoppable" and \
            plan.is_stop
    assert rescued > 0
    for bad in (-1e-12, 1e-3, float("nan")):
        with pytest.raises(ValueError, match="rounding_tolerance"):
            stop_params(dt_s=DT, max_acceleration=A_MAX, max_jerk=J_MAX,
                                 pose_is_safe=always_safe, joint_names=JOINTS,
                                 rounding_tolerance=bad)


def test_the_ground_planner_treats_rounding_like_the_onboard_guard():
    # MakeCollisionStopPlanner (the ground FIFO's) plans from the nudged history: a limiter
    # at its limits, whose recomputed FD state lands on the boundary of S, gets the same
    # stop as the exact planner from the nudged history, never the hold's velocity step
    # where only rounding is at fault.
    from telesmooth.arms.planar import AIR_BEARING_ARM
    from telesmooth.smoothing.online_hard import OnlineHardLimiter

    class FarAway:
        def query(self, q):
            return _FakeCollisionModel._Query(10.0)

    config = ReducedQSmootherConfig(max_acceleration_rad_per_s2=A_MAX,
                                    max_jerk_rad_per_s3=J_MAX)
    ground = MakeCollisionStopPlanner(period_s=DT, smoother_config=config, arm=AIR_BEARING_ARM,
                                      collision_model=FarAway(), safety_margin_m=0.02)
    names = tuple(AIR_BEARING_ARM.joint_names)
    exact = stop_params(dt_s=DT, max_acceleration=A_MAX, max_jerk=J_MAX,
                                 pose_is_safe=always_safe, joint_names=names)
    limiter = OnlineHardLimiter(dt_s=DT, max_acceleration=A_MAX, max_jerk=J_MAX,
                                q_start=[0.0, 0.0, 0.0])
    rescued = 0
    for history in _histories_at_the_limits(limiter, [0.5, -0.5, 0.5]):
        plan = ground.plan(history, max_ticks=400)
        oracle = exact.plan(nudge_into_stoppable_set(history, limiter.stoppable_sets, DT),
                            max_ticks=400)
        assert plan.outcome == oracle.outcome
        np.testing.assert_array_equal(plan.commands, oracle.commands)
        rescued += (exact.plan(history, max_ticks=400).outcome.label == "hold-not-stoppable"
                    and plan.is_stop)
    assert rescued > 0
