"""The plant's drive parameters as scenario fields, its linearised vibration modes, and the
two presets.

Oracles: a mass-spring-damper's closed form; the two-degree-of-freedom flexible joint's
characteristic polynomial (roots by numpy.roots, not by the eigen-solver under test) with
inertias computed by hand from the description; and the simulated plant ringing at the
predicted damped frequency.
"""

import dataclasses
import math

import numpy as np
import pytest
from pydrake.multibody.plant import MultibodyPlant
from pydrake.multibody.tree import ForceElementIndex
from pydrake.systems.analysis import Simulator

from telesmooth.arms.description import (
    AIR_BEARING_ARM_3DOF,
    ArmDescription,
    JointDescription,
    LinkDescription,
    drive_preset,
    with_drive,
)
from telesmooth.arms.drake_models import add_arm
from telesmooth.arms.modes import plant_modes, vibration_modes
from telesmooth.diagrams.scenario import LoadScenario, initial_position, make_haptic_recording
from telesmooth.diagrams.simulation import plant_summary, plant_text
from telesmooth.systems.flexible_arm import DriveConfig, FlexibleArmConfig, FlexibleJointArm

ONE_JOINT = ArmDescription(
    name="one_joint",
    base=LinkDescription("base", 10.0, 0.05, (0.0, 0.0, -0.1)),
    base_to_first_joint_m=(0.0, 0.0, 0.0),
    joints=(JointDescription("hinge", (0.0, 0.0, 1.0), -3.0, 3.0, 200.0,
                             stiffness_n_m_per_rad=150.0, damping_n_m_s_per_rad=0.2,
                             motor_kp_n_m_per_rad=900.0, motor_kd_n_m_s_per_rad=60.0,
                             rotor_inertia_kg_m2=2e-4, gear_ratio=50.0),),
    links=(LinkDescription("link1", 3.0, 0.04, (0.6, 0.0, 0.0)),),
)


def _one_joint_inertias():
    """(motor-side J_m, link-side J_l) about the hinge, kg·m², by hand."""
    joint, link = ONE_JOINT.joints[0], ONE_JOINT.links[0]
    length, radius, mass = link.length_m, link.radius_m, link.mass_kg
    # A solid rod about a transverse axis through its end (parallel axis from its centre).
    link_inertia = mass * (3 * radius**2 + length**2) / 12 + mass * (length / 2) ** 2
    motor_inertia = joint.gear_ratio**2 * joint.rotor_inertia_kg_m2 \
        + ONE_JOINT.rotor_body_inertia_kg_m2
    return motor_inertia, link_inertia


def test_a_mass_spring_damper_has_its_closed_form_mode():
    mass, stiffness, damping = 2.0, 800.0, 4.0
    modes = vibration_modes([[mass]], [stiffness], [damping])
    assert modes.natural_frequency_hz[0] == pytest.approx(
        math.sqrt(stiffness / mass) / (2 * math.pi), rel=1e-12)
    assert modes.damping_ratio[0] == pytest.approx(
        damping / (2 * math.sqrt(stiffness * mass)), rel=1e-12)
    # Overdamped: no oscillation, two real decays.
    overdamped = vibration_modes([[mass]], [stiffness], [200.0])
    assert overdamped.natural_frequency_hz.size == 0 and overdamped.num_decays == 2


def test_the_flexible_joint_modes_are_the_roots_of_its_characteristic_polynomial():
    """Coordinates (motor angle, deflection); link angle = motor + deflection, so
    M = [[J_m + J_l, J_l], [J_l, J_l]], K = diag(kp, k), C = diag(kd, c), and
    det(λ²M + λC + K) = (M₁₁λ² + kd λ + kp)(J_l λ² + c λ + k) − J_l² λ⁴."""
    joint = ONE_JOINT.joints[0]
    motor_inertia, link_inertia = _one_joint_inertias()
    top = [motor_inertia + link_inertia, joint.motor_kd_n_m_s_per_rad,
           joint.motor_kp_n_m_per_rad]
    bottom = [link_inertia, joint.damping_n_m_s_per_rad, joint.stiffness_n_m_per_rad]
    polynomial = np.polysub(np.polymul(top, bottom), [link_inertia**2, 0, 0, 0, 0])
    roots = np.roots(polynomial)
    oscillatory = roots[roots.imag > 1e-9]
    expected = sorted((abs(r) / (2 * math.pi), -r.real / abs(r)) for r in oscillatory)
    for pose in (0.0, 0.7, -2.0):          # one joint: the modes do not depend on the pose
        modes = plant_modes(ONE_JOINT, [pose])
        assert modes.natural_frequency_hz.size == len(expected)
        for (f, zeta), f_dut, zeta_dut in zip(expected, modes.natural_frequency_hz,
                                              modes.damping_ratio):
            assert f_dut == pytest.approx(f, rel=1e-9)
            assert zeta_dut == pytest.approx(zeta, rel=1e-9)
    # Undamped, the quadratic in ω²: J_m J_l ω⁴ − (kp J_l + k (J_m + J_l)) ω² + kp k = 0.
    undamped = with_drive(ONE_JOINT, damping_n_m_s_per_rad=(1e-300,),
                          motor_kd_n_m_s_per_rad=(1e-300,))
    kp, k = joint.motor_kp_n_m_per_rad, joint.stiffness_n_m_per_rad
    omega2 = np.sort(np.roots([motor_inertia * link_inertia,
                               -(kp * link_inertia + k * (motor_inertia + link_inertia)),
                               kp * k]).real)
    np.testing.assert_allclose(plant_modes(undamped, [0.0]).natural_frequency_hz,
                               np.sqrt(omega2) / (2 * math.pi), rtol=1e-9)


def test_the_simulated_joint_rings_at_the_predicted_damped_frequency():
    """The one-joint plant, released from a deflection with the servo holding: the link's
    zero crossings give its damped frequency f_n·√(1 − ζ²) of the lightly damped mode."""
    plant = MultibodyPlant(1e-4)
    instance = add_arm(plant, ONE_JOINT, flexible=True)
    plant.Finalize()
    simulator = Simulator(plant)
    context = simulator.get_mutable_context()
    plant.get_desired_state_input_port(instance).FixValue(context, np.zeros(2))
    plant.get_actuation_input_port().FixValue(context, np.zeros(1))
    plant.GetJointByName("hinge_deflection").set_angle(context, 0.01)
    simulator.AdvanceTo(0.0)
    times, deflection = [], []
    for t in np.arange(0.0, 3.0, 1e-3):
        simulator.AdvanceTo(t)
        times.append(t)
        deflection.append(plant.GetJointByName("hinge_deflection").get_angle(context))
    times, deflection = np.array(times), np.array(deflection)
    late = times > 0.5
    signs = np.sign(deflection[late])
    crossings = times[late][1:][signs[1:] != signs[:-1]]
    measured_hz = (len(crossings) - 1) / (2 * (crossings[-1] - crossings[0]))
    modes = plant_modes(ONE_JOINT, [0.0])
    lightest = int(np.argmin(modes.damping_ratio))
    f_n, zeta = modes.natural_frequency_hz[lightest], modes.damping_ratio[lightest]
    assert measured_hz == pytest.approx(f_n * math.sqrt(1 - zeta**2), rel=0.01)


# -- the presets -------------------------------------------------------------------------


def _start_pose(scenario):
    return initial_position(scenario, make_haptic_recording(scenario))


@pytest.mark.parametrize("name", ["Defaults", "OneOfEverything"])
def test_the_lightweight_preset_rings_slowly_and_lightly_damped(name):
    """Lowest mode 0.5-1.5 Hz with damping ratio at most 0.03 about the start pose; the lab
    arm's is faster and better damped."""
    lab = LoadScenario(scenario_name=name)
    light = LoadScenario(scenario_name=name,
                          scenario_text="{onboard: {drive: {preset: lightweight}}}")
    pose = _start_pose(lab)
    lab_f, lab_zeta = plant_modes(lab.onboard.arm_description, pose).lowest_ringing()
    light_f, light_zeta = plant_modes(light.onboard.arm_description, pose).lowest_ringing()
    assert 0.5 <= light_f <= 1.5 and 0.01 <= light_zeta <= 0.03
    assert lab_f > 2.5 and lab_zeta > 0.05    # the lab arm: faster and better damped
    if name == "Defaults":       # the laboratory arm of the paper's set-up
        assert lab_f == pytest.approx(2.66, abs=0.01)
        assert lab_zeta == pytest.approx(0.072, abs=0.001)
        assert light_f == pytest.approx(0.90, abs=0.01)
        assert light_zeta == pytest.approx(0.020, abs=0.001)


def test_drive_fields_override_the_preset_and_reach_the_plant():
    scenario = LoadScenario(scenario_text=(
        "{onboard: {drive: {preset: lightweight, stiffness_n_m_per_rad: 77, "
        "motor_kp_n_m_per_rad: {shoulder: 1000, elbow: 900, wrist: 800}, "
        "motor_kd_n_m_s_per_rad: [61, 62, 63], rotor_inertia_kg_m2: 2.0e-4}}}"))
    arm = scenario.onboard.arm_description
    light = drive_preset(AIR_BEARING_ARM_3DOF, "lightweight")
    robot = FlexibleJointArm(scenario.onboard)
    plant = robot.plant
    for index, joint in enumerate(arm.joints):
        assert joint.stiffness_n_m_per_rad == 77.0
        assert joint.damping_n_m_s_per_rad == light.joints[index].damping_n_m_s_per_rad
        assert joint.motor_kp_n_m_per_rad == (1000.0, 900.0, 800.0)[index]
        spring = next(element for element in (
            plant.get_force_element(ForceElementIndex(i))
            for i in range(plant.num_force_elements())) if hasattr(element, "joint")
            and element.joint().name() == f"{joint.name}_deflection")
        assert spring.default_stiffness() == 77.0
        assert plant.GetJointByName(f"{joint.name}_deflection").default_damping() == \
            light.joints[index].damping_n_m_s_per_rad
        actuator = plant.GetJointActuatorByName(f"{joint.name}_motor")
        gains = actuator.get_controller_gains()
        assert (gains.p, gains.d) == ((1000.0, 900.0, 800.0)[index], 61.0 + index)
        assert actuator.default_rotor_inertia() == 2.0e-4


@pytest.mark.parametrize("text, message", [
    ("{onboard: {drive: {preset: feather}}}",
     "onboard.drive.preset = 'feather' must be one of ('lab', 'lightweight')"),
    ("{onboard: {drive: {stiffness_n_m_per_rad: [1, 2]}}}",
     "onboard.drive.stiffness_n_m_per_rad has 2 value(s)"),
    ("{onboard: {drive: {damping_n_m_s_per_rad: {shoulder: 1, elbow: -2, wrist: 3}}}}",
     "onboard.drive.damping_n_m_s_per_rad[1] = -2.0 for joint 1 ('elbow') must be finite"),
    ("{onboard: {drive: {motor_kp_n_m_per_rad: .nan}}}",
     "onboard.drive.motor_kp_n_m_per_rad"),
])
def test_invalid_drive_values_are_refused_naming_the_key_path(text, message):
    with pytest.raises(ValueError) as error:
        LoadScenario(scenario_text=text)
    assert message in str(error.value)


def test_drive_config_checks_its_preset():
    with pytest.raises(ValueError, match="preset = 'x'"):
        DriveConfig(preset="x")
    with pytest.raises(ValueError, match="must be a DriveConfig"):
        FlexibleArmConfig(drive={"preset": "lab"})


def test_the_report_states_the_plant_and_its_modes():
    scenario = LoadScenario(scenario_text="{onboard: {drive: {preset: lightweight}}}")
    summary = plant_summary(scenario, _start_pose(scenario))
    expected = plant_modes(scenario.onboard.arm_description, _start_pose(scenario))
    assert summary["drive_preset"] == "lightweight"
    assert summary["drive"]["stiffness_n_m_per_rad"] == [50.0, 30.0, 10.0]
    np.testing.assert_array_equal(summary["modes"]["natural_frequency_hz"],
                                  expected.natural_frequency_hz[:3])
    text = plant_text(summary)
    assert "`lightweight`" in text and "(continuous)" in text     # the default plant
    assert f"{expected.lowest_ringing()[0]:.3g} Hz" in text
    assert summary["modes"]["lowest_ringing_hz"] == expected.lowest_ringing()[0]
    stepped = dataclasses.replace(scenario, onboard=dataclasses.replace(
        scenario.onboard, time_step_s=0.001))
    assert "(1 ms steps)" in plant_text(plant_summary(stepped, _start_pose(scenario)))


def test_servo_modes_are_told_apart_from_the_ringing_ones():
    """The 6-DOF lab arm at the OneOfEverything pose has a servo mode at 1.59 Hz (ζ ≈ 1)
    below its lowest ringing mode (3.66 Hz, ζ 0.051): the report names the ringing one."""
    scenario = LoadScenario(scenario_name="OneOfEverything")
    modes = plant_modes(scenario.onboard.arm_description, _start_pose(scenario))
    assert modes.natural_frequency_hz[0] < 2.0 and modes.damping_ratio[0] > 0.9
    f, zeta = modes.lowest_ringing()
    assert f == pytest.approx(3.66, abs=0.01) and zeta == pytest.approx(0.051, abs=0.001)
    assert modes.describe(1) == "3.66 Hz (ζ 0.051); 1 servo mode(s) with ζ ≥ 0.3 in between"
