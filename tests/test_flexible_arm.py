"""FlexibleJointArm (+ LaserTracker): structure, residual vibration against an independent
modal prediction, ramp tracking, tracker kinematics and timing, rest, and the safety hold.

Frequency oracle: a hand-assembled linear model about the rest pose (zero gravity, zero
velocity), built from our own parameters, not from Drake's dynamics:

    M ẍ + (D + Kd) ẋ + (K + Kp) x = 0,    x = all 2n joint positions,

where M is the plant's mass matrix at the rest pose (``CalcMassMatrix``, which includes the
reflected rotor inertia). K and D are the description's spring stiffness and damping on the
deflection joints, and Kp and Kd its servo gains on the motor joints. Linearized about
rest, the PD set-point is constant. At v = 0 the Coriolis terms drop out, so this is the
exact linearization. The late part of a step response is dominated by the least-damped
oscillatory eigenvalue s = −σ + jω_d. Zero crossings of a decaying mode are exactly π/ω_d
apart, so the measured frequency is compared with f_d = ω_d/2π.

Drake's own ``Linearize`` cannot serve as this oracle in drake 1.51.1:
``MultibodyPlant.ToAutoDiffXd()`` drops the actuators' PD gains (``has_controller()`` is
false on the AutoDiff plant), so ``Linearize`` silently returns the servo-off dynamics. We
still use it to cross-check the hand model's M, K and D with the gains set to zero
(``test_hand_model_matches_drake_linearization``).
"""

import time

import numpy as np
import pytest
from pydrake.multibody.plant import MultibodyPlant
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder, InputPortSelection, OutputPortSelection
from pydrake.systems.primitives import Linearize, LogVectorOutput, TrajectorySource
from pydrake.trajectories import PiecewisePolynomial

from telesmooth.arms.description import AIR_BEARING_ARM_3DOF, SPACE_ARM_6DOF
from telesmooth.arms.drake_models import add_arm
from telesmooth.arms.planar import AIR_BEARING_ARM, planar_forward_kinematics
from telesmooth.systems.command_interpolator import CommandInterpolatorConfig
from telesmooth.systems.flexible_arm import (
    FlexibleArmConfig,
    FlexibleJointArm,
    desired_state_permutation,
)
from telesmooth.systems.laser_tracker import LaserTrackerConfig

UPLINK_PERIOD_S = 0.25
STEP_TIME_S = 0.25
WALL_CLOCK_PER_5_S = {}

LOGGED_OUTPUTS = ("plant_state", "position_measured", "q_link", "q_motor",
                  "tracker_sample_time", "state_desired", "command_rejected")


# -- harness ------------------------------------------------------------------------------


def held_commands(times_s, commands):
    """A 4 Hz-style held command source: commands[k] from times_s[k] on (ZOH), (n, K)."""
    commands = np.asarray(commands, dtype=float)
    times = np.append(np.asarray(times_s, dtype=float), 1e3)
    return TrajectorySource(PiecewisePolynomial.ZeroOrderHold(
        times, np.hstack([commands, commands[:, -1:]])))


def simulate(config, times_s, commands, duration_s):
    """Runs the arm on held commands; returns (dut, logs by port name, wall-clock seconds)."""
    builder = DiagramBuilder()
    dut = builder.AddNamedSystem("arm", FlexibleJointArm(config))
    source = builder.AddNamedSystem("uplink", held_commands(times_s, commands))
    builder.Connect(source.get_output_port(), dut.GetInputPort("q_commanded"))
    # Every plant step (1 ms) is logged, so held tracker samples show their timing.
    loggers = {name: LogVectorOutput(dut.GetOutputPort(name), builder)
               for name in LOGGED_OUTPUTS}
    diagram = builder.Build()
    simulator = Simulator(diagram)
    start = time.perf_counter()
    simulator.AdvanceTo(duration_s)
    wall_s = time.perf_counter() - start
    root = simulator.get_context()
    logs = {name: logger.FindLog(root) for name, logger in loggers.items()}
    return dut, logs, wall_s


def joint_signals(dut, plant_state):
    """(motor, deflection) position histories from logged plant states, each (n, N)."""
    motor = [dut.plant.GetJointByName(f"{name}_motor").position_start()
             for name in dut.joint_names]
    deflection = [dut.plant.GetJointByName(f"{name}_deflection").position_start()
                  for name in dut.joint_names]
    return plant_state[motor], plant_state[deflection]


def step_commands(num_joints, joint, amplitude):
    values = np.zeros((num_joints, 2))
    values[joint, 1] = amplitude
    return [0.0, STEP_TIME_S], values


def zero_crossing_frequency_hz(times, signal):
    """(number of crossings − 1) half-periods over the span between the first and last."""
    crossings = times[1:][np.sign(signal[1:]) != np.sign(signal[:-1])]
    assert len(crossings) >= 4, f"only {len(crossings)} zero crossings"
    return (len(crossings) - 1) / (2.0 * (crossings[-1] - crossings[0]))


def hand_linear_model(plant, arm, *, with_servo=True):
    """The state matrix A of M ẍ + (D + Kd) ẋ + (K + Kp) x = 0 at the rest pose (module doc)."""
    context = plant.CreateDefaultContext()
    mass = plant.CalcMassMatrix(context)
    size = plant.num_velocities()
    stiffness, damping = np.zeros((size, size)), np.zeros((size, size))
    for joint in arm.joints:
        motor = plant.GetJointByName(f"{joint.name}_motor").velocity_start()
        deflection = plant.GetJointByName(f"{joint.name}_deflection").velocity_start()
        stiffness[deflection, deflection] = joint.stiffness_n_m_per_rad
        damping[deflection, deflection] = joint.damping_n_m_s_per_rad
        if with_servo:
            stiffness[motor, motor] = joint.motor_kp_n_m_per_rad
            damping[motor, motor] = joint.motor_kd_n_m_s_per_rad
    inverse_mass = np.linalg.inv(mass)
    return np.block([[np.zeros((size, size)), np.eye(size)],
                     [-inverse_mass @ stiffness, -inverse_mass @ damping]])


def least_damped_mode(state_matrix):
    """(damped frequency f_d in Hz, decay rate σ in 1/s) of the slowest-decaying oscillation."""
    eigenvalues = np.linalg.eigvals(state_matrix)
    oscillatory = eigenvalues[eigenvalues.imag > 1e-6]
    slowest = oscillatory[np.argmax(oscillatory.real)]
    return slowest.imag / (2 * np.pi), -slowest.real


# -- shared simulations (module scope: each is run once) --------------------------------


@pytest.fixture(scope="module")
def air_step_zoh():
    """Air-bearing arm, pure step (zoh) of 0.1 rad on the elbow at 0.25 s, 4 s."""
    config = FlexibleArmConfig(
        arm="air_bearing_arm", interpolator=CommandInterpolatorConfig(interpolation="zoh"))
    times, values = step_commands(3, 1, 0.1)
    dut, logs, _ = simulate(config, times, values, 4.0)
    return dut, logs


@pytest.fixture(scope="module")
def air_ramp():
    """Air-bearing arm, 0.1 rad over 5 s on all joints, sampled at 4 Hz and held, 5 s."""
    times = np.arange(0.0, 5.0 + 1e-9, UPLINK_PERIOD_S)
    values = np.tile(0.1 * times / 5.0, (3, 1))
    dut, logs, wall_s = simulate(FlexibleArmConfig(arm="air_bearing_arm"), times, values, 5.0)
    WALL_CLOCK_PER_5_S["air_bearing_arm"] = wall_s
    print(f"\n[speed] air_bearing_arm (3 joints, 6 DOF): 5 s simulated in {wall_s:.2f} s wall")
    return dut, logs


@pytest.fixture(scope="module")
def space_step():
    """Space arm, default (linear) interpolation, 0.05 rad step on elbow_pitch, 5 s."""
    times, values = step_commands(6, 2, 0.05)
    dut, logs, wall_s = simulate(FlexibleArmConfig(arm="space_arm"), times, values, 5.0)
    WALL_CLOCK_PER_5_S["space_arm"] = wall_s
    print(f"\n[speed] space_arm (6 joints, 12 DOF): 5 s simulated in {wall_s:.2f} s wall")
    return dut, logs


# -- structure ----------------------------------------------------------------------------


def test_ports_and_plant_structure_air_bearing():
    dut = FlexibleJointArm(FlexibleArmConfig(arm="air_bearing_arm"))
    assert dut.joint_names == ("shoulder", "elbow", "wrist")
    assert dut.joint_names == AIR_BEARING_ARM.joint_names
    assert dut.num_input_ports() == 2
    assert dut.get_input_port(0).get_name() == "q_commanded"
    assert dut.get_input_port(0).size() == 3
    assert dut.get_input_port(1).get_name() == "command_time"
    assert dut.get_input_port(1).size() == 1
    sizes = {dut.get_output_port(i).get_name(): dut.get_output_port(i).size()
             for i in range(dut.num_output_ports()) if dut.get_output_port(i).get_name()
             != "query_object"}
    assert sizes == {"position_measured": 3, "q_link": 3, "q_motor": 3,
                     "tracker_sample_time": 1, "tracker_measurement": 10, "velocity_measured": 6,
                     "command_rejected": 1, "state_desired": 6, "command_ramp": 7,
                     "plant_state": 12}
    plant = dut.plant
    assert plant.time_step() == 0.0   # continuous by default
    assert plant.num_positions() == 6 and plant.num_actuators() == 3
    np.testing.assert_array_equal(plant.gravity_field().gravity_vector(), [0, 0, 0])
    for joint in AIR_BEARING_ARM_3DOF.joints:  # the servo gains come from the description
        actuator = plant.GetJointActuatorByName(f"{joint.name}_motor")
        gains = actuator.get_controller_gains()
        assert (gains.p, gains.d) == (joint.motor_kp_n_m_per_rad, joint.motor_kd_n_m_s_per_rad)
        assert actuator.effort_limit() == joint.max_effort_n_m
    # Each actuator row of the desired-state map selects its own joint's q and v.
    permutation = desired_state_permutation(plant, dut.model_instance, dut.joint_names)
    for row, index in enumerate(plant.GetJointActuatorIndices(dut.model_instance)):
        name = plant.get_joint_actuator(index).joint().name().removesuffix("_motor")
        column = dut.joint_names.index(name)
        assert permutation[row, column] == 1 and permutation[3 + row, 3 + column] == 1
    assert permutation.sum() == 6


@pytest.mark.parametrize("arm", [AIR_BEARING_ARM_3DOF, SPACE_ARM_6DOF])
def test_no_consecutive_links_can_collide(arm):
    dut = FlexibleJointArm(FlexibleArmConfig(arm=arm.name))
    inspector = dut.scene_graph.model_inspector()

    def body(geometry):
        return dut.plant.GetBodyFromFrameId(inspector.GetFrameId(geometry)).name()

    candidates = {frozenset((body(a), body(b))) for a, b in inspector.GetCollisionCandidates()}
    bodies = [arm.base.name] + [link.name for link in arm.links]
    consecutive = {frozenset(pair) for pair in zip(bodies[:-1], bodies[1:])}
    assert candidates and not candidates & consecutive
    # No contact at the rest pose either (contact would corrupt the dynamics silently).
    context = dut.CreateDefaultContext()
    query = dut.GetOutputPort("query_object").Eval(context)
    assert query.ComputePointPairPenetration() == []


def test_set_initial_positions_puts_the_arm_at_rest():
    dut = FlexibleJointArm(FlexibleArmConfig(arm="air_bearing_arm"))
    context = dut.CreateDefaultContext()
    q = np.array([0.4, -0.7, 1.1])
    dut.SetInitialPositions(context, q)
    motor, deflection = joint_signals(dut, dut.GetOutputPort("plant_state").Eval(context))
    np.testing.assert_array_equal(motor, q)
    np.testing.assert_array_equal(deflection, 0.0)
    np.testing.assert_array_equal(dut.GetOutputPort("plant_state").Eval(context)[6:], 0.0)
    np.testing.assert_array_equal(dut.GetOutputPort("state_desired").Eval(context),
                                  np.concatenate([q, np.zeros(3)]))
    np.testing.assert_allclose(dut.GetOutputPort("q_link").Eval(context), q, atol=1e-15)
    np.testing.assert_allclose(
        dut.GetOutputPort("position_measured").Eval(context)[:2],
        planar_forward_kinematics(q, AIR_BEARING_ARM.link_lengths_m), atol=1e-12, rtol=0)
    with pytest.raises(ValueError, match=r"q_commanded\[2\] \(wrist\) = 3.5 is outside"):
        dut.SetInitialPositions(context, [0.0, 0.0, 3.5])


# -- configuration errors -----------------------------------------------------------------


def test_default_config_is_valid_and_builds():
    config = FlexibleArmConfig()
    assert (config.arm, config.time_step_s, config.gravity_m_per_s2) == (
        "air_bearing_arm", 0.0, (0.0, 0.0, 0.0))
    assert FlexibleJointArm(config).num_joints == 3


@pytest.mark.parametrize("kwargs,match", [
    ({"arm": "moon_arm"}, r"FlexibleArmConfig.arm = 'moon_arm' must be one of"),
    ({"time_step_s": -1e-3}, r"FlexibleArmConfig.time_step_s = -0.001 must be finite"),
    ({"time_step_s": float("nan")}, r"FlexibleArmConfig.time_step_s = nan"),
    ({"discrete_contact_approximation": "magic"},
     r"discrete_contact_approximation = 'magic' must be one of"),
    ({"gravity_m_per_s2": (0.0, -9.81)}, r"gravity_m_per_s2 = \(0.0, -9.81\) must have 3"),
    ({"gravity_m_per_s2": (0.0, 0.0, float("inf"))},
     r"FlexibleArmConfig.gravity_m_per_s2\[2\] = inf must be finite"),
    ({"initial_position_rad": (0.0, 0.0)},
     r"^FlexibleArmConfig.initial_position_rad = \(0.0, 0.0\) has shape \(2,\); expected "
     r"\(3,\), one per joint of \('shoulder', 'elbow', 'wrist'\)$"),
    ({"initial_position_rad": (0.0, 3.2, 0.0)},
     r"^FlexibleArmConfig.initial_position_rad\[1\] = 3.2 for joint 1 \('elbow'\) must be "
     r"finite and within \[-\d.*, \d.*\] rad$"),
    ({"initial_position_rad": (float("nan"), 0.0, 0.0)},
     r"^FlexibleArmConfig.initial_position_rad\[0\] = nan for joint 0 \('shoulder'\) must be "
     r"finite"),
    ({"tracker": {"period_s": 0.01}}, r"FlexibleArmConfig.tracker = .* must be a"),
])
def test_config_errors_name_field_and_value(kwargs, match):
    with pytest.raises(ValueError, match=match):
        FlexibleArmConfig(**kwargs)


@pytest.mark.parametrize("kwargs,match", [
    ({"period_s": 0.0}, r"LaserTrackerConfig.period_s = 0.0 must be positive"),
    ({"noise_m": -1e-4}, r"LaserTrackerConfig.noise_m = -0.0001 must be finite and >= 0"),
    ({"seed": -3}, r"LaserTrackerConfig.seed = -3 must be an integer >= 0"),
    ({"seed": 1.5}, r"LaserTrackerConfig.seed = 1.5 must be an integer"),
])
def test_tracker_config_errors_name_field_and_value(kwargs, match):
    with pytest.raises(ValueError, match=match):
        LaserTrackerConfig(**kwargs)


# -- residual vibration (air-bearing arm) -------------------------------------------------


def test_hand_model_matches_drake_linearization():
    """Cross-checks the oracle's M, K, D against Drake's Linearize of a continuous plant."""
    plant = MultibodyPlant(0.0)
    instance = add_arm(plant, AIR_BEARING_ARM_3DOF, flexible=True)
    plant.mutable_gravity_field().set_gravity_vector([0.0, 0.0, 0.0])
    plant.Finalize()
    context = plant.CreateDefaultContext()
    plant.get_desired_state_input_port(instance).FixValue(context, np.zeros(6))
    plant.get_actuation_input_port().FixValue(context, np.zeros(3))
    linear = Linearize(plant, context, input_port_index=InputPortSelection.kNoInput,
                       output_port_index=OutputPortSelection.kNoOutput)
    # drake 1.51.1: the AutoDiff plant has lost the PD gains, so Linearize has no servo.
    servo_survives = plant.ToAutoDiffXd().get_joint_actuator(
        plant.GetJointActuatorIndices(instance)[0]).has_controller()
    hand = hand_linear_model(plant, AIR_BEARING_ARM_3DOF, with_servo=servo_survives)
    np.testing.assert_allclose(linear.A(), hand, rtol=1e-9, atol=1e-9)


def test_step_leaves_link_side_vibration_after_the_motor_settles(air_step_zoh):
    dut, logs = air_step_zoh
    t = logs["plant_state"].sample_times()
    motor, deflection = joint_signals(dut, logs["plant_state"].data())
    late = t >= 1.5  # 1.25 s after the step
    motor_error = np.abs(motor[1, late] - 0.1).max()
    deflection_p2p = np.ptp(deflection[1, late])
    tracker_p2p = np.ptp(logs["position_measured"].data()[:, late], axis=1).max()
    motor_p2p = np.ptp(motor[1, late])
    print(f"\n[vibration] elbow step 0.1 rad (zoh), t >= 1.5 s: motor error "
          f"{motor_error:.2e} rad, motor p2p {motor_p2p:.2e} rad, deflection p2p "
          f"{deflection_p2p:.2e} rad, end-effector p2p {1e3 * tracker_p2p:.2f} mm")
    # Motor servos are stiff (kp = 4-7.5 k, critically damped on the reflected rotor
    # inertia): the motor has settled while the link-side spring still rings.
    assert motor_error < 0.02 * 0.1
    assert motor_p2p < deflection_p2p / 3.0
    assert deflection_p2p > 1e-3  # but the link still rings (> 1 mrad peak to peak)
    assert tracker_p2p > 3e-4  # and the laser tracker sees it (> 0.3 mm)
    assert np.all(np.isfinite(logs["plant_state"].data()))


def test_vibration_frequency_matches_the_linear_model(air_step_zoh):
    dut, logs = air_step_zoh
    t = logs["plant_state"].sample_times()
    _, deflection = joint_signals(dut, logs["plant_state"].data())
    late = t >= 1.5
    measured_hz = zero_crossing_frequency_hz(t[late], deflection[1, late])
    predicted_hz, decay_per_s = least_damped_mode(
        hand_linear_model(dut.plant, AIR_BEARING_ARM_3DOF))
    print(f"\n[frequency] air-bearing: measured {measured_hz:.4f} Hz, predicted "
          f"{predicted_hz:.4f} Hz (decay {decay_per_s:.3f} 1/s)")
    assert measured_hz == pytest.approx(predicted_hz, rel=0.10)


def test_default_linear_interpolation_also_leaves_vibration():
    config = FlexibleArmConfig(arm="air_bearing_arm")  # "linear": 0.25 s ramp
    times, values = step_commands(3, 1, 0.1)
    dut, logs, _ = simulate(config, times, values, 3.0)
    t = logs["plant_state"].sample_times()
    motor, deflection = joint_signals(dut, logs["plant_state"].data())
    late = t >= 1.5
    assert np.abs(motor[1, late] - 0.1).max() < 0.02 * 0.1
    assert np.ptp(deflection[1, late]) > 1e-3


# -- ramp tracking and the tracker (air-bearing arm) --------------------------------------


def test_slow_ramp_is_tracked(air_ramp):
    dut, logs = air_ramp
    sample_time = logs["tracker_sample_time"].data()[0]
    q_link = logs["q_link"].data()
    after_lag = sample_time >= 1.0

    def ramp(t):
        return 0.1 * np.clip(t, 0.0, 5.0) / 5.0

    # The interpolator delays the 4 Hz samples by one uplink period (module docstring of
    # command_interpolator); the link must follow that delayed ramp.
    error = np.abs(q_link[:, after_lag] - ramp(sample_time[after_lag] - UPLINK_PERIOD_S))
    undelayed = np.abs(q_link[:, after_lag] - ramp(sample_time[after_lag]))
    print(f"\n[ramp] link error after 1 s: {error.max():.2e} rad vs the ramp delayed by "
          f"{UPLINK_PERIOD_S} s; {undelayed.max():.2e} rad vs the undelayed ramp")
    assert error.max() < 5e-3
    assert q_link[:, -1] == pytest.approx(ramp(4.99 - UPLINK_PERIOD_S), abs=5e-3)


def test_tracker_position_is_planar_kinematics_of_link_angles(air_ramp):
    _, logs = air_ramp
    position = logs["position_measured"].data()
    q_link = logs["q_link"].data()
    np.testing.assert_allclose(
        position[:2].T, planar_forward_kinematics(q_link.T, AIR_BEARING_ARM.link_lengths_m),
        atol=1e-9, rtol=0)
    np.testing.assert_allclose(position[2], 0.0, atol=1e-12)
    # Link angle = motor + deflection (the motor alone would give a different pose).
    assert np.abs(q_link - logs["q_motor"].data()).max() > 1e-4


def test_tracker_samples_at_exactly_100_hz(air_ramp):
    _, logs = air_ramp
    log_times = logs["tracker_sample_time"].sample_times()
    sample_time = logs["tracker_sample_time"].data()[0]
    samples = np.unique(sample_time)
    np.testing.assert_allclose(samples, 0.01 * np.arange(500), atol=1e-12, rtol=0)
    # Every logged output is the newest sample not after the log time (zero-order hold).
    assert np.all(sample_time <= log_times + 1e-12)
    assert np.all(log_times - sample_time < 0.01 + 1e-9)
    # Between samples the measurements are held: they change only with the sample time.
    changes = np.any(np.diff(logs["position_measured"].data(), axis=1) != 0, axis=0)
    assert np.all(np.diff(sample_time)[changes] > 0)


def test_tracker_noise_is_seeded_and_has_the_configured_size():
    def rest_positions(seed):
        config = FlexibleArmConfig(tracker=LaserTrackerConfig(noise_m=1e-3, seed=seed))
        _, logs, _ = simulate(config, [0.0], np.zeros((3, 1)), 1.0)
        return logs["position_measured"].data(), logs["tracker_sample_time"].data()[0]

    position, sample_time = rest_positions(seed=0)
    _, first = np.unique(sample_time, return_index=True)
    noise = position[:, first] - np.array([[1.1], [0.0], [0.0]])  # stretched rest pose
    assert noise.shape == (3, 100)
    assert np.std(noise) == pytest.approx(1e-3, rel=0.2)
    assert abs(np.mean(noise)) < 3 * 1e-3 / np.sqrt(noise.size)
    np.testing.assert_array_equal(rest_positions(seed=0)[0], position)
    assert np.abs(rest_positions(seed=1)[0] - position).max() > 1e-4


# -- safety: unsafe commands never reach the plant ---------------------------------------


def test_unsafe_commands_hold_the_robot_and_raise_the_flag():
    dut = FlexibleJointArm(FlexibleArmConfig(arm="air_bearing_arm"))
    simulator = Simulator(dut)
    context = simulator.get_mutable_context()
    port = dut.GetInputPort("q_commanded")
    flag = dut.GetOutputPort("command_rejected")
    port.FixValue(context, [0.05, 0.0, 0.0])
    simulator.AdvanceTo(0.5)
    port.FixValue(context, [0.3, np.nan, 0.0])
    simulator.AdvanceTo(0.75)
    assert flag.Eval(context)[0] == 1.0
    port.FixValue(context, [4.0, 0.0, 0.0])  # beyond the 170° limit
    simulator.AdvanceTo(1.5)
    assert flag.Eval(context)[0] == 1.0
    np.testing.assert_array_equal(dut.GetOutputPort("state_desired").Eval(context),
                                  [0.05, 0, 0, 0, 0, 0])
    plant_state = dut.GetOutputPort("plant_state").Eval(context)
    assert np.all(np.isfinite(plant_state))
    # Still ringing from the first step (±1e-2), but nowhere near 0.3 or 4.0 rad.
    np.testing.assert_allclose(dut.GetOutputPort("q_link").Eval(context), [0.05, 0, 0],
                               atol=2e-2)
    port.FixValue(context, [0.06, 0.0, 0.0])  # a valid command: recovery
    simulator.AdvanceTo(1.6)
    assert flag.Eval(context)[0] == 0.0
    # The poll 0.1 ms after 1.5 s starts the 0.25 s ramp from 0.05 to 0.06 (no lead: the
    # plant is continuous).
    assert dut.GetOutputPort("state_desired").Eval(context)[0] == pytest.approx(
        0.05 + (0.1 - 0.0001) / 0.25 * 0.01, abs=1e-12)
    assert dut.interpolator.get_rejected_command_count(
        dut.interpolator.GetMyContextFromRoot(context)) == 2


# -- the 6-DOF space arm ------------------------------------------------------------------


def test_space_arm_holds_still_at_rest():
    q0 = (0.3, 0.4, -0.5, 0.2, 0.1, -0.2)
    config = FlexibleArmConfig(arm="space_arm", initial_position_rad=q0)
    dut, logs, _ = simulate(config, [0.0], np.array(q0)[:, None], 1.0)
    plant = dut.plant
    assert plant.num_positions() == 12 and plant.num_actuators() == 6
    assert dut.joint_names == SPACE_ARM_6DOF.joint_names
    motor, deflection = joint_signals(dut, logs["plant_state"].data())
    drift = max(np.abs(motor - np.array(q0)[:, None]).max(), np.abs(deflection).max())
    print(f"\n[rest] space arm drift over 1 s: {drift:.1e} rad")
    assert drift < 1e-6
    np.testing.assert_allclose(logs["q_link"].data(), np.array(q0)[:, None] @ np.ones(
        (1, logs["q_link"].data().shape[1])), atol=1e-6, rtol=0)


def test_space_arm_small_step_vibrates(space_step):
    dut, logs = space_step
    t = logs["plant_state"].sample_times()
    motor, deflection = joint_signals(dut, logs["plant_state"].data())
    window = (t >= 1.0) & (t < 2.0)
    motor_error = np.abs(motor[2, window] - 0.05).max()
    deflection_p2p = np.ptp(deflection[2, window])
    measured_hz = zero_crossing_frequency_hz(t[t >= 1.0], deflection[2, t >= 1.0])
    predicted_hz, _ = least_damped_mode(hand_linear_model(dut.plant, SPACE_ARM_6DOF))
    print(f"\n[vibration] space arm elbow_pitch step 0.05 rad, t in [1, 2) s: motor error "
          f"{motor_error:.2e} rad, deflection p2p {deflection_p2p:.2e} rad; frequency "
          f"{measured_hz:.3f} Hz measured, {predicted_hz:.3f} Hz predicted")
    assert motor_error < 0.04 * 0.05
    assert deflection_p2p > 5e-4
    assert measured_hz == pytest.approx(predicted_hz, rel=0.10)
    # Joints out of the pitch plane stay exactly still.
    for joint in (0, 4, 5):
        assert np.abs(motor[joint]).max() < 1e-9 and np.abs(deflection[joint]).max() < 1e-9


# -- continuous plant ---------------------------------------------------------------------


def test_continuous_plant_agrees_with_the_discrete_one():
    times, values = step_commands(3, 2, 0.05)
    results = {}
    for step in (0.0, 1e-3):
        dut, logs, _ = simulate(FlexibleArmConfig(time_step_s=step), times, values, 1.0)
        assert dut.plant.time_step() == step
        results[step] = logs["q_link"].data()[:, -1]
    # Measured difference 1.4e-5 rad (drake 1.51.1, RK3 at the default accuracy).
    np.testing.assert_allclose(results[0.0], results[1e-3], atol=1e-4, rtol=0)


# -- the interpolator polls when the command can change -----------------------------------


def test_the_interpolator_polls_at_the_command_period_when_the_diagram_knows_it():
    """Driven by commands that change only every 0.25 s, polling every 0.25 s (0.1 ms after
    each change) sees every command at the same instant as polling every 10 ms does: the
    same set-point and the same motion (to the integrator's accuracy: its steps differ)."""
    times = np.arange(0.0, 2.01, UPLINK_PERIOD_S)
    commands = np.vstack([0.3 * np.sin(times), -0.2 * times / 2.0, 0.1 * np.cos(times)])
    results = {}
    for period in (None, UPLINK_PERIOD_S):
        builder = DiagramBuilder()
        dut = builder.AddNamedSystem("arm", FlexibleJointArm(
            FlexibleArmConfig(), command_period_s=period))
        poll = dut.interpolator.gate.GetUniquePeriodicDiscreteUpdateAttribute()
        assert (poll.period_sec(), poll.offset_sec()) == (period or 0.01, 1e-4)
        source = builder.AddNamedSystem("uplink", held_commands(times, commands))
        builder.Connect(source.get_output_port(), dut.GetInputPort("q_commanded"))
        desired = LogVectorOutput(dut.GetOutputPort("state_desired"), builder, 0.01)
        tracker = LogVectorOutput(dut.GetOutputPort("tracker_measurement"), builder, 0.01)
        simulator = Simulator(builder.Build())
        simulator.AdvanceTo(2.5)
        root = simulator.get_context()
        results[period] = (desired.FindLog(root).data(), tracker.FindLog(root).data())
    np.testing.assert_array_equal(results[None][0], results[UPLINK_PERIOD_S][0])
    # Measured 2.4e-7 rad / m (the error control at drake's default accuracy 1e-4).
    np.testing.assert_allclose(results[None][1], results[UPLINK_PERIOD_S][1], rtol=0,
                               atol=2e-6)
    assert np.ptp(results[None][1][4:7], axis=1).max() > 0.1     # the arm moved
