"""The operator's seat in one process: the whole deployed chain with telemetry coming back,
the predicted robot, and (with a browser) the console and the display.

:func:`MakeTeleopDiagram` builds

    operator (console, or the scenario's recording) → ground station → sender
        → uplink link (``link.faults``) → receiver → link guard → flexible plant → tracker
        → telemetry (``lcmt_onboard_joint_status``) → downlink (``link.downlink``)
        → predicted robot (:class:`~telesmooth.systems.robot_predictor.RobotPredictor`)
        → display (Meshcat)

The predicted robot runs :func:`MakePredictorReplica`: a copy of the onboard chain built by
the same builders (receiver, guard, interpolator, plant), with the ground's model of the
plant's drive (``predictor.drive``) and the uplink's nominal delay, fed the packets the ground
sent. Builders never simulate; ``telesmooth teleop`` (:mod:`telesmooth.scripts.teleop`) runs
it against the wall clock.
"""

from __future__ import annotations

import dataclasses

from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import LogVectorOutput

from telesmooth.diagrams.scenario import Scenario
from telesmooth.diagrams.teleoperation import (
    AddDeployedLink,
    AddGroundLoggers,
    AddGroundStation,
    AddJointStatusSender,
    AddLinkLoggers,
    AddOnboardCommandPath,
    AddOnboardLoggers,
    AddOnboardRobot,
    GroundHandles,
    OnboardHandles,
)
from telesmooth.lcm_types import lcmt_onboard_joint_status
from telesmooth.systems.flexible_arm import MakeSimulator
from telesmooth.systems.link_channel import LinkChannel
from telesmooth.systems.packet_replay import PacketLog, PacketReplay
from telesmooth.systems.robot_predictor import PredictorReplica, RobotPredictor

__all__ = ["MakeOperatorDiagram", "MakePredictorReplica", "MakeTeleopDiagram", "OperatorHandles",
           "TeleopHandles", "console_pose_names", "model_scenario"]


@dataclasses.dataclass(frozen=True)
class TeleopHandles:
    """A built teleoperation diagram with its stages and loggers (name → VectorLogSink)."""

    diagram: object
    ground: GroundHandles
    onboard: OnboardHandles
    predictor: RobotPredictor
    downlink: LinkChannel
    logs: dict
    scenario: Scenario
    console: object | None = None
    display: object | None = None


def console_pose_names(scenario: Scenario) -> tuple[str, ...]:
    """The pose coordinates of the operator's hand for the scenario's arm."""
    from telesmooth.datasets.haptic_recording import PLANAR_POSE_NAMES, SPATIAL_POSE_NAMES

    return PLANAR_POSE_NAMES if scenario.arm == "air_bearing_arm" else SPATIAL_POSE_NAMES


def model_scenario(scenario: Scenario) -> Scenario:
    """The scenario as the ground's model of the robot sees it: the predictor's drive (if
    given) for the robot's, and a noise-free tracker (the model's own tool position)."""
    onboard = scenario.onboard
    if scenario.predictor.drive is not None:
        onboard = dataclasses.replace(onboard, drive=scenario.predictor.drive)
    onboard = dataclasses.replace(onboard, tracker=dataclasses.replace(onboard.tracker,
                                                                       noise_m=0.0))
    return dataclasses.replace(scenario, onboard=onboard)


def MakePredictorReplica(scenario: Scenario, *, initial_position_rad,
                         collision_model=None) -> PredictorReplica:
    """The copy of the onboard chain that the predicted robot runs: ``PacketReplay`` (the
    uplink's nominal delay, ``link.faults.delay_s``; the ground cannot know which packets a
    faulty link loses) → receiver → link guard → the model's plant
    (:func:`model_scenario`), at rest at ``initial_position_rad``. ``collision_model``: the
    pre-simulator's, shared with the guard's ramp-down check (None builds one)."""
    model = model_scenario(scenario)
    builder = DiagramBuilder()
    log = PacketLog()
    poll = scenario.command_receiver.poll_period_s
    # The link as AddDeployedLink's channel delivers on a perfect link with the nominal delay.
    replay = builder.AddNamedSystem("packet_replay", PacketReplay(
        log, delay_s=scenario.link.faults.delay_s, poll_period_s=poll,
        poll_offset_s=0.9 * poll))
    receiver, guard = AddOnboardCommandPath(
        builder, model, packets=replay.get_packets_output_port(),
        initial_position_rad=initial_position_rad, collision_model=collision_model)
    # The predictor reads the plant's state itself: no tracker event stops the integrator.
    robot = AddOnboardRobot(builder, model, initial_position_rad=initial_position_rad,
                            tracker_in_diagram=False)
    builder.Connect(guard.get_q_commanded_output_port(), robot.GetInputPort("q_commanded"))
    diagram = builder.Build()
    diagram.set_name("predicted_robot")
    config = robot.config
    return PredictorReplica(diagram=diagram, robot=robot, packets=log,
                            MakeSimulator=lambda d: MakeSimulator(d, config))


def MakeTeleopDiagram(scenario: Scenario, *, console=None, display=None,
                      monitor=None) -> TeleopHandles:
    """The operator's seat in one process (module docstring).

    Args:
        scenario: The scenario (its ``chain`` is the deployed one whatever it says: the
            robot is driven through the onboard receiver and guard, and its telemetry comes
            back over ``link.downlink``).
        console: The operator's hand, a system with ``pose_desired``, ``enable`` and
            ``stop_requested`` outputs (the browser console); None: the scenario's haptic
            source (a recording drives the seat, e.g. in tests).
        display: Optional system drawing the seat; connected by
            :meth:`~telesmooth.systems.operator_display.OperatorDisplay.Connect`.
        monitor: Optional system without ports added as it is (e.g. the
            :class:`~telesmooth.systems.wall_clock_monitor.WallClockMonitor` of a live run).
    """
    builder = DiagramBuilder()
    if console is not None:
        builder.AddNamedSystem("operator_console", console)
    ground = AddGroundStation(builder, scenario, haptic=console)
    q0 = ground.initial_position_rad
    n = len(ground.joint_names)
    robot = AddOnboardRobot(builder, scenario, initial_position_rad=q0)
    sender, receiver, guard, link = AddDeployedLink(builder, ground, scenario, robot)
    status = AddJointStatusSender(builder, robot, receiver, guard)
    tracker_period = scenario.onboard.tracker.period_s
    # The telemetry leaves the robot as the onboard process publishes it (publish_offset_s
    # after each sample) and crosses the downlink.
    downlink = builder.AddNamedSystem("downlink", LinkChannel(
        scenario.link.downlink, lcm_type=lcmt_onboard_joint_status,
        poll_period_s=tracker_period, poll_offset_s=scenario.publish_offset_s))
    builder.Connect(status.get_lcm_message_output_port(), downlink.get_lcm_message_input_port())
    collision_model = ground.collision_checker.collision_model
    predictor = builder.AddNamedSystem("robot_predictor", RobotPredictor(
        lambda start: MakePredictorReplica(scenario, initial_position_rad=start,
                                           collision_model=collision_model),
        num_joints=n, period_s=scenario.predictor.period_s,
        resync_period_s=scenario.predictor.resync_period_s, initial_position_rad=q0,
        sample_period_s=tracker_period))
    builder.Connect(sender.get_lcm_message_output_port(),
                    predictor.get_uplink_message_input_port())
    builder.Connect(downlink.get_packets_output_port(),
                    predictor.get_telemetry_packets_input_port())
    if display is not None:
        builder.AddNamedSystem("operator_display", display)
        display.Connect(builder, ground=ground, predictor=predictor, console=console)
    if monitor is not None:
        builder.AddNamedSystem("wall_clock_monitor", monitor)
    if console is not None and console.get_q_anchor_input_port() is not None:
        # Engaging after a stop re-anchors the hand where the robot was held.
        builder.Connect(ground.uplink.get_q_sent_output_port(),
                        console.get_q_anchor_input_port())
        builder.Connect(ground.fifo.get_holding_output_port(), console.get_anchor_input_port())
    logs = AddGroundLoggers(builder, ground, scenario)
    logs.update(AddOnboardLoggers(builder, robot, tracker_period))
    poll = scenario.command_receiver.poll_period_s
    logs.update(AddLinkLoggers(builder, receiver, guard, poll))
    haptic_period = scenario.haptic.period_s
    logs["hand_pose"] = LogVectorOutput(ground.haptic.get_pose_desired_output_port(), builder,
                                        haptic_period)
    logs["hand_enable"] = LogVectorOutput(ground.haptic.get_enable_output_port(), builder,
                                          haptic_period)
    if console is not None:
        # The console's own state, for the session's console.csv.
        for name in ("stop_requested", "notice", "saturated"):
            logs[f"console_{name}"] = LogVectorOutput(console.GetOutputPort(name), builder,
                                                      haptic_period)
    # What the display shows of the prediction, at the display's rate.
    for name in ("q_predicted", "residual", "telemetry_silence", "telemetry_age"):
        logs[f"predictor_{name}"] = LogVectorOutput(predictor.get_output(name), builder,
                                                    scenario.predictor.period_s)
    diagram = builder.Build()
    diagram.set_name("teleop")
    return TeleopHandles(
        diagram=diagram, ground=ground,
        onboard=OnboardHandles(arm=robot, receiver=receiver, guard=guard, link=link),
        predictor=predictor, downlink=downlink, logs=logs, scenario=scenario,
        console=console, display=display)


@dataclasses.dataclass(frozen=True)
class OperatorHandles:
    """The operator's own process (``telesmooth operator``): its systems and loggers."""

    diagram: object
    console: object
    inverse_kinematics: object
    predictor: RobotPredictor
    logs: dict
    scenario: Scenario
    display: object | None = None


def MakeOperatorDiagram(scenario: Scenario, *, lcm, console, display=None,
                        monitor=None, wall_clock=None) -> OperatorHandles:
    """The console alone, on the bus (docs/operator.md: operator, ground and onboard as three
    processes):

    * the operator's hand (``console``) → ``lcmt_teleop_haptic_command`` on
      TELEOP_HAPTIC_COMMAND every haptic period (what ``telesmooth ground`` with
      ``haptic: {source: lcm}`` reads);
    * the planning position: the console's own inverse kinematics of the hand (the same
      system and settings as the ground's);
    * the packets the ground sends (TELEOP_JOINT_COMMAND) and its collision events
      (TELEOP_COLLISION_EVENT), the robot's telemetry (ONBOARD_JOINT_STATUS) → the predicted
      robot (its copy on the robot's clock, :class:`~telesmooth.systems.robot_predictor.
      RemoteClock`) and the display.

    ``wall_clock`` (a monotonic clock, s; the live process passes ``time.perf_counter``) is
    what the predictor estimates the robot's clock against; None: this diagram's simulated
    time (see :class:`~telesmooth.systems.robot_predictor.RobotPredictor`).
    """
    from pydrake.systems.lcm import LcmInterfaceSystem, LcmPublisherSystem

    from telesmooth.diagrams.scenario import initial_position
    from telesmooth.lcm_types import (
        lcmt_teleop_collision_event,
        lcmt_teleop_haptic_command,
        lcmt_teleop_joint_command,
    )
    from telesmooth.lcm_types.channels import (
        ONBOARD_JOINT_STATUS,
        TELEOP_COLLISION_EVENT,
        TELEOP_HAPTIC_COMMAND,
        TELEOP_JOINT_COMMAND,
    )
    from telesmooth.systems.inverse_kinematics import InverseKinematicsSystem
    from telesmooth.systems.lcm_safe_subscriber import LcmSafeSubscriber
    from telesmooth.systems.operator_display import predictor_ports
    from telesmooth.systems.operator_messages import (
        CollisionEventValues,
        HapticCommandSender,
        JointCommandPositions,
    )

    arm = scenario.arm_description
    n = arm.num_joints
    period = scenario.haptic.period_s
    q0 = initial_position(scenario, None)
    builder = DiagramBuilder()
    builder.AddNamedSystem("lcm", LcmInterfaceSystem(lcm))
    builder.AddNamedSystem("operator_console", console)
    sender = builder.AddNamedSystem("haptic_command_sender", HapticCommandSender(
        num_axes=len(console_pose_names(scenario)), period_s=period))
    for name in ("pose_desired", "enable", "stop_requested"):
        builder.Connect(console.GetOutputPort(name), sender.GetInputPort(name))
    publisher = builder.AddNamedSystem("haptic_command_publisher", LcmPublisherSystem.Make(
        TELEOP_HAPTIC_COMMAND, lcmt_teleop_haptic_command, lcm, publish_period=period))
    builder.Connect(sender.get_lcm_message_output_port(), publisher.get_input_port())
    ik = builder.AddNamedSystem("inverse_kinematics", InverseKinematicsSystem(
        scenario.inverse_kinematics, arm=arm, initial_position_rad=q0))
    builder.Connect(console.get_pose_desired_output_port(), ik.get_pose_desired_input_port())
    builder.Connect(console.get_enable_output_port(), ik.get_enable_input_port())

    def subscriber(name, channel, lcm_type):
        return builder.AddNamedSystem(name, LcmSafeSubscriber(
            channel=channel, lcm_type=lcm_type, lcm=lcm))

    telemetry = subscriber("joint_status_subscriber", ONBOARD_JOINT_STATUS,
                           lcmt_onboard_joint_status)
    commands = subscriber("joint_command_subscriber", TELEOP_JOINT_COMMAND,
                          lcmt_teleop_joint_command)
    events = subscriber("collision_event_subscriber", TELEOP_COLLISION_EVENT,
                        lcmt_teleop_collision_event)
    model = dataclasses.replace(scenario, link=dataclasses.replace(
        scenario.link, faults=dataclasses.replace(scenario.link.faults, delay_s=0.0)))
    predictor = builder.AddNamedSystem("robot_predictor", RobotPredictor(
        lambda start: MakePredictorReplica(model, initial_position_rad=start),
        num_joints=n, period_s=scenario.predictor.period_s,
        resync_period_s=scenario.predictor.resync_period_s, remote=True,
        initial_position_rad=q0, uplink_period_s=scenario.uplink.period_s,
        sample_period_s=scenario.onboard.tracker.period_s,
        poll_period_s=scenario.command_receiver.poll_period_s,
        publish_offset_s=scenario.publish_offset_s, wall_clock=wall_clock))
    builder.Connect(telemetry.get_packets_output_port(),
                    predictor.get_telemetry_packets_input_port())
    builder.Connect(commands.get_packets_output_port(),
                    predictor.get_uplink_packets_input_port())
    positions = builder.AddNamedSystem("sent_positions", JointCommandPositions(num_joints=n))
    builder.Connect(commands.get_lcm_message_output_port(),
                    positions.get_lcm_message_input_port())
    values = builder.AddNamedSystem("collision_events", CollisionEventValues())
    builder.Connect(events.get_lcm_message_output_port(), values.get_lcm_message_input_port())
    builder.Connect(events.get_message_count_output_port(), values.get_message_count_input_port())
    if console.get_q_anchor_input_port() is not None:
        # Engaging after a stop re-anchors the hand at the last command the ground sent,
        # while its events say it holds the robot there.
        builder.Connect(positions.get_q_sent_output_port(), console.get_q_anchor_input_port())
        builder.Connect(values.GetOutput("holding"), console.get_anchor_input_port())
    if display is not None:
        builder.AddNamedSystem("operator_display", display)
        ports = {"q_planning": ik.get_q_target_output_port(),
                 "hand_pose": console.get_pose_desired_output_port(),
                 "enable": console.get_enable_output_port(),
                 "stop": console.get_stop_requested_output_port(),
                 "notice": console.get_notice_output_port(),
                 "saturated": console.get_saturated_output_port(),
                 "ik_status": ik.get_ik_status_output_port(),
                 "q_sent": positions.get_q_sent_output_port(),
                 "sent_sequence": positions.get_sequence_number_output_port(),
                 "collision": values.GetOutput("collision_detected"),
                 "holding": values.GetOutput("holding"),
                 "min_distance": values.GetOutput("min_distance"),
                 **predictor_ports(predictor)}
        display.ConnectPorts(builder, ports)
    if monitor is not None:
        builder.AddNamedSystem("wall_clock_monitor", monitor)
    logs = {"hand_pose": LogVectorOutput(console.get_pose_desired_output_port(), builder,
                                         period),
            "hand_enable": LogVectorOutput(console.get_enable_output_port(), builder, period)}
    for name in ("stop_requested", "notice", "saturated"):
        logs[f"console_{name}"] = LogVectorOutput(console.GetOutputPort(name), builder, period)
    diagram = builder.Build()
    diagram.set_name("operator")
    return OperatorHandles(diagram=diagram, console=console, inverse_kinematics=ik,
                           predictor=predictor, logs=logs, scenario=scenario, display=display)
