"""Diagram builders: the ground station, the onboard robot, and the whole chain in one process.

Data flow (the paper's Figure 2, docs/method.md §5.1), ground side at the haptic rate then at 4 Hz:

    haptic source ─pose, clutch─▶ inverse kinematics ─q_target─┬─▶ collision checker
                                                                │        (pre-simulator)
                                              [period mean] ◀──┘             │ collision
                                                    │                         ▼
                                                    └──────────────▶ delay FIFO (L = 3)
                                                                  q_newest │ reset
                                                                           ▼
                                                          reduced-Q smoother (BMFLS)
                                                                           │ x̂_{k−L|k}
                                                                           ▼
                                                                  4 Hz uplink (ZOH) ─┐
                                          q_sent (hold on collision) ◀───────────────┘
    onboard: (LCM) ─▶ command receiver ─▶ interpolator ─▶ flexible-joint plant ─▶ tracker

Builders never simulate. Each returns a small frozen dataclass of handles.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from pydrake.lcm import DrakeLcm
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.lcm import LcmInterfaceSystem, LcmPublisherSystem
from pydrake.systems.primitives import LogVectorOutput

from telesmooth.datasets.haptic_recording import HapticRecording
from telesmooth.diagrams.scenario import Scenario, initial_position, make_haptic_recording
from telesmooth.lcm_types import (
    lcmt_onboard_joint_status,
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
from telesmooth.systems.collision_checker import CollisionChecker
from telesmooth.systems.collision_event_sender import CollisionEventSender
from telesmooth.systems.collision_stop import (
    MakeCollisionStopPlanner,
    PreSimulatorPoseCheck,
    finite_smoother_limits,
)
from telesmooth.systems.delay_fifo import DelayFifo
from telesmooth.systems.flexible_arm import FlexibleJointArm
from telesmooth.systems.haptic_command_receiver import HapticCommandReceiver
from telesmooth.systems.haptic_source import HapticSource, HapticSourceConfig
from telesmooth.systems.inverse_kinematics import InverseKinematicsSystem
from telesmooth.systems.joint_command_receiver import JointCommandReceiver
from telesmooth.systems.joint_command_sender import JointCommandSender
from telesmooth.systems.joint_status_decoder import JointStatusDecoder
from telesmooth.systems.joint_status_sender import JointStatusSender
from telesmooth.systems.lcm_safe_subscriber import LcmSafeSubscriber
from telesmooth.systems.link_channel import LinkChannel
from telesmooth.systems.link_guard import LinkGuard
from telesmooth.systems.period_mean import PeriodMean, PeriodMeanConfig
from telesmooth.systems.reduced_q_smoother import ReducedQSmoother
from telesmooth.systems.uplink import Uplink

__all__ = [
    "GroundHandles",
    "MakeGroundDiagram",
    "MakeOnboardDiagram",
    "MakeTeleoperationDiagram",
    "OnboardHandles",
    "TeleoperationHandles",
    "AddGroundStation",
    "AddDeployedLink",
    "AddJointCommandSender",
    "AddJointStatusSender",
    "AddOnboardCommandPath",
    "AddOnboardRobot",
    "AddOperatorTargets",
    "OperatorTargets",
    "first_sample_indices",
    "uplink_packets",
]


@dataclasses.dataclass(frozen=True)
class GroundHandles:
    """The ground-station systems of one diagram."""

    haptic: object
    inverse_kinematics: InverseKinematicsSystem
    collision_checker: CollisionChecker
    period_mean: PeriodMean | None
    fifo: DelayFifo
    smoother: ReducedQSmoother
    uplink: Uplink
    recording: HapticRecording | None
    initial_position_rad: np.ndarray
    joint_names: tuple[str, ...]


@dataclasses.dataclass(frozen=True)
class OnboardHandles:
    """The onboard systems of one diagram."""

    arm: FlexibleJointArm
    receiver: JointCommandReceiver | None
    guard: LinkGuard | None = None
    link: LinkChannel | None = None


@dataclasses.dataclass(frozen=True)
class TeleoperationHandles:
    """A built diagram with its stages and loggers (name → VectorLogSink)."""

    diagram: object
    ground: GroundHandles | None
    onboard: OnboardHandles | None
    logs: dict
    lcm: DrakeLcm | None = None
    scenario: Scenario | None = None


def scenario_smoother_config(scenario: Scenario):
    """The smoother config of ``scenario``, with r divided by M under the period mean."""
    config = scenario.smoother
    if scenario.period_mean:
        # Averaging M samples of white hand noise divides its variance by M (docs/method.md §5.1).
        samples = _period_mean_config(scenario).num_samples
        config = dataclasses.replace(config, r=config.r / samples)
    return config


@dataclasses.dataclass(frozen=True)
class OperatorTargets:
    """Stages 1-2 (and the FIFO's sampling option): what the 4 Hz stages sample."""

    haptic: object
    inverse_kinematics: InverseKinematicsSystem
    period_mean: PeriodMean | None
    q_sampled: object   # output port: the IK target, or its period mean


def _period_mean_config(scenario: Scenario) -> PeriodMeanConfig:
    return PeriodMeanConfig(sample_period_s=scenario.haptic.period_s,
                            window_s=scenario.fifo.period_s)


def AddOperatorTargets(builder: DiagramBuilder, scenario: Scenario, *, recording,
                       initial_position_rad, lcm: DrakeLcm | None = None,
                       haptic=None) -> OperatorTargets:
    """Adds the haptic source (or live LCM receiver), the inverse kinematics and, with
    ``scenario.period_mean``, the period mean; ``q_sampled`` is the port the FIFO samples.
    ``haptic``: a system already in ``builder`` that is the operator's hand (its
    ``pose_desired`` and ``enable`` outputs; e.g. the browser console of ``teleop``)
    instead of the scenario's source.

    Shared by the ground station and the offline planner, so both see the same targets.
    """
    arm = scenario.arm_description
    q0 = initial_position_rad
    # The operator's hand: recorded, synthetic, or a live device over LCM.
    if haptic is not None:
        pass
    elif recording is not None:
        haptic = builder.AddNamedSystem("haptic_source", HapticSource(
            recording, HapticSourceConfig(period_s=scenario.haptic.period_s)))
    else:
        if scenario.haptic.source == "console":
            raise ValueError("haptic.source = 'console' is the browser console of "
                             "`telesmooth teleop` and `telesmooth operator`: run one of them")
        if lcm is None:
            raise ValueError("haptic.source = 'lcm' needs an LCM instance (ground process)")
        # A subscriber that survives malformed packets (they count as rejected messages).
        subscriber = builder.AddNamedSystem("haptic_subscriber", LcmSafeSubscriber(
            channel=TELEOP_HAPTIC_COMMAND, lcm_type=lcmt_teleop_haptic_command, lcm=lcm))
        live_pose = np.asarray(scenario.haptic.live_initial_pose, dtype=float)
        if scenario.arm == "space_arm":
            from telesmooth.arms.air_bearing import planar_pose_to_space_arm
            live_pose = planar_pose_to_space_arm(live_pose)
        haptic = builder.AddNamedSystem("haptic_receiver", HapticCommandReceiver(
            initial_pose=live_pose))
        builder.Connect(subscriber.get_lcm_message_output_port(),
                        haptic.get_lcm_message_input_port())
        builder.Connect(subscriber.get_message_undecodable_output_port(),
                        haptic.get_message_undecodable_input_port())

    # Inverse kinematics, at the haptic rate.
    ik = builder.AddNamedSystem("inverse_kinematics", InverseKinematicsSystem(
        scenario.inverse_kinematics, arm=arm, initial_position_rad=q0))
    builder.Connect(haptic.get_pose_desired_output_port(), ik.get_pose_desired_input_port())
    builder.Connect(haptic.get_enable_output_port(), ik.get_enable_input_port())

    period_mean = None
    q_sampled = ik.get_q_target_output_port()
    if scenario.period_mean:
        period_mean = builder.AddNamedSystem("period_mean", PeriodMean(
            _period_mean_config(scenario), num_joints=arm.num_joints, initial_position_rad=q0))
        builder.Connect(ik.get_q_target_output_port(), period_mean.get_q_target_input_port())
        q_sampled = period_mean.get_q_mean_output_port()
    return OperatorTargets(haptic=haptic, inverse_kinematics=ik, period_mean=period_mean,
                           q_sampled=q_sampled)


def AddGroundStation(builder: DiagramBuilder, scenario: Scenario, *,
                     lcm: DrakeLcm | None = None, haptic=None) -> GroundHandles:
    """Adds the ground station (haptic source … uplink) to ``builder``.

    The haptic source is the scenario's recording, or an LCM subscription to
    TELEOP_HAPTIC_COMMAND when ``scenario.haptic.source == "lcm"`` (needs ``lcm``), or
    ``haptic``, a system already in ``builder`` (:func:`AddOperatorTargets`). A live operator
    (LCM or ``haptic``) can stop the robot (its ``stop_requested`` output drives the FIFO's
    stop) and re-engages at the robot's commanded pose (the inverse kinematics' anchor is
    the uplink's held command while the FIFO holds).
    """
    arm = scenario.arm_description
    recording = None if haptic is not None else make_haptic_recording(scenario)
    q0 = initial_position(scenario, recording)
    n = arm.num_joints

    # Stages 1-2: the operator's hand and the inverse kinematics (the task plan manager).
    operator = AddOperatorTargets(builder, scenario, recording=recording,
                                  initial_position_rad=q0, lcm=lcm, haptic=haptic)
    haptic, ik = operator.haptic, operator.inverse_kinematics

    # Stage 3: the pre-simulator's collision check on the newest (undelayed) target.
    checker = builder.AddNamedSystem("collision_checker", CollisionChecker(
        scenario.collision_checker, arm=arm, workspace=scenario.workspace_or_default))
    builder.Connect(ik.get_q_target_output_port(), checker.get_q_target_input_port())

    # Stage 4: the 0.75 s FIFO, sampling the latest target or the period mean.
    # With fifo.on_collision = "stop", the jerk-limited stop is planned with the smoother's
    # limits and checked against the pre-simulator's own collision model.
    stop_planner = None
    if scenario.fifo.on_collision == "stop":
        stop_planner = MakeCollisionStopPlanner(
            period_s=scenario.fifo.period_s, smoother_config=scenario.smoother, arm=arm,
            collision_model=checker.collision_model,
            safety_margin_m=scenario.collision_checker.safety_margin_m)
    fifo = builder.AddNamedSystem("delay_fifo", DelayFifo(
        scenario.fifo, num_joints=n, initial_position_rad=q0,
        **({} if stop_planner is None else {"collision_stop": stop_planner})))
    builder.Connect(operator.q_sampled, fifo.get_q_target_input_port())
    builder.Connect(checker.GetOutputPort("collision_detected"),
                    fifo.get_collision_detected_input_port())
    builder.Connect(haptic.get_enable_output_port(), fifo.get_enable_input_port())

    # Stage 5: the reduced-Q fixed-lag smoother on the FIFO's window.
    smoother = builder.AddNamedSystem("smoother", ReducedQSmoother(
        scenario_smoother_config(scenario), joint_names=arm.joint_names, initial_position_rad=q0))
    builder.Connect(fifo.get_q_newest_output_port(), smoother.get_q_sample_input_port())
    builder.Connect(fifo.get_reset_output_port(), smoother.get_reset_input_port())

    # Stage 6: the 4 Hz uplink; its held command is what the FIFO refills with on collision.
    uplink = builder.AddNamedSystem("uplink", Uplink(
        scenario.uplink, num_joints=n, initial_position_rad=q0))
    builder.Connect(smoother.get_q_smoothed_output_port(), uplink.get_q_smoothed_input_port())
    builder.Connect(smoother.get_state_smoothed_output_port(),
                    uplink.get_state_smoothed_input_port())
    builder.Connect(uplink.get_q_sent_output_port(), fifo.get_q_sent_input_port())
    builder.Connect(fifo.get_holding_output_port(), uplink.get_holding_input_port())

    # A live operator: the stop button, and re-engaging where the robot was held.
    if recording is None:
        builder.Connect(haptic.get_stop_requested_output_port(),
                        fifo.get_stop_requested_input_port())
        builder.Connect(uplink.get_q_sent_output_port(), ik.get_q_anchor_input_port())
        builder.Connect(fifo.get_holding_output_port(), ik.get_anchor_input_port())

    return GroundHandles(
        haptic=haptic, inverse_kinematics=ik, collision_checker=checker,
        period_mean=operator.period_mean, fifo=fifo, smoother=smoother, uplink=uplink,
        recording=recording, initial_position_rad=q0, joint_names=arm.joint_names)


def AddOnboardRobot(builder: DiagramBuilder, scenario: Scenario, *,
                    initial_position_rad, command_period_s: float | None = None,
                    tracker_in_diagram: bool = True,
                    contact_geometry: bool = True) -> FlexibleJointArm:
    """Adds the flexible-joint arm (interpolator + plant + tracker), starting at rest.

    ``command_period_s``: the period at which its command can change, when the caller knows
    it (the uplink's, driving the robot directly): its interpolator polls only then (see
    :class:`~telesmooth.systems.flexible_arm.FlexibleJointArm`); None: every 10 ms.
    ``tracker_in_diagram``: False leaves the tracker out of the diagram (a playback samples
    it afterwards, see :class:`~telesmooth.systems.flexible_arm.FlexibleJointArm`).
    ``contact_geometry``: False builds the plant without collision geometry (a playback
    certified free of self-contact afterwards,
    :func:`~telesmooth.diagrams.offline_playback.play_path`)."""
    config = dataclasses.replace(
        scenario.onboard, arm=scenario.arm,
        initial_position_rad=tuple(float(v) for v in initial_position_rad))
    return builder.AddNamedSystem("robot", FlexibleJointArm(
        config, command_period_s=command_period_s, tracker_in_diagram=tracker_in_diagram,
        contact_geometry=contact_geometry))


def AddJointCommandSender(builder: DiagramBuilder, ground: GroundHandles, scenario: Scenario,
                          *, session_id: int = 0, uplink_key: bytes | None = None,
                          onboard_epoch: int = 0) -> JointCommandSender:
    """Adds the uplink's packet former (``lcmt_teleop_joint_command``, signed with a key)."""
    sender = builder.AddNamedSystem("joint_command_sender", JointCommandSender(
        joint_names=ground.joint_names, delay_s=scenario.fifo.delay_s, session_id=session_id,
        uplink_key=uplink_key, onboard_epoch=onboard_epoch))
    uplink = ground.uplink
    builder.Connect(uplink.get_q_sent_output_port(), sender.get_q_sent_input_port())
    builder.Connect(uplink.get_state_sent_output_port(), sender.get_state_sent_input_port())
    builder.Connect(uplink.get_sequence_number_output_port(),
                    sender.get_sequence_number_input_port())
    builder.Connect(uplink.get_send_time_output_port(), sender.get_send_time_input_port())
    builder.Connect(uplink.get_holding_sent_output_port(), sender.get_holding_input_port())
    return sender


def MakeLinkGuard(scenario: Scenario, *, initial_position_rad,
                  collision_model=None) -> LinkGuard:
    """The onboard link guard: the smoother's limits (the robot's), the joint limits and the
    workspace's collision model (a ramp-down never commands a pose the pre-simulator would
    reject). ``collision_model``: an existing ``ArmCollisionModel`` of the scenario's arm and
    workspace to share (in process, the pre-simulator's); None builds one."""
    arm = scenario.arm_description
    names = tuple(arm.joint_names)
    limits = finite_smoother_limits(
        scenario.smoother, names,
        purpose="the onboard link guard (its ramp-down brakes within these limits)")
    model = collision_model
    if model is None:
        from telesmooth.arms.collision import ArmCollisionModel
        model = ArmCollisionModel(
            arm, scenario.workspace_or_default,
            distance_horizon_m=scenario.collision_checker.distance_horizon_m)
    check = PreSimulatorPoseCheck(model,
                                  safety_margin_m=scenario.collision_checker.safety_margin_m,
                                  lower_rad=arm.joint_lower_rad, upper_rad=arm.joint_upper_rad)
    return LinkGuard(scenario.link_guard, joint_names=names, lower_rad=arm.joint_lower_rad,
                     upper_rad=arm.joint_upper_rad, initial_position_rad=initial_position_rad,
                     max_acceleration=limits["max_acceleration_rad_per_s2"],
                     max_jerk=limits["max_jerk_rad_per_s3"], pose_is_safe=check)


def AddOnboardCommandPath(builder: DiagramBuilder, scenario: Scenario, *, packets,
                          initial_position_rad, uplink_key: bytes | None = None,
                          collision_model=None, onboard_epoch: int = 0):
    """Adds the onboard receiver (every packet of ``packets`` examined: authentication,
    freshness — ``onboard_epoch``, the session order —, validity) and the link guard
    (:func:`MakeLinkGuard`, sharing ``collision_model`` if given); returns (receiver, guard).
    Connect ``guard.get_q_commanded_output_port()`` to the robot."""
    arm = scenario.arm_description
    receiver = builder.AddNamedSystem("joint_command_receiver", JointCommandReceiver(
        scenario.command_receiver, joint_names=arm.joint_names,
        lower_rad=arm.joint_lower_rad, upper_rad=arm.joint_upper_rad,
        initial_position_rad=initial_position_rad, uplink_key=uplink_key,
        onboard_epoch=onboard_epoch))
    builder.Connect(packets, receiver.get_packets_input_port())
    guard = builder.AddNamedSystem("link_guard", MakeLinkGuard(
        scenario, initial_position_rad=initial_position_rad, collision_model=collision_model))
    builder.Connect(receiver.get_q_commanded_output_port(), guard.get_q_accepted_input_port())
    builder.Connect(receiver.get_accepted_count_output_port(),
                    guard.get_accepted_count_input_port())
    # The packet identity lets the guard see a gap (a lost or reordered packet).
    builder.Connect(receiver.get_last_command_seq_output_port(),
                    guard.get_command_seq_input_port())
    builder.Connect(receiver.get_last_command_session_output_port(),
                    guard.get_command_session_input_port())
    return receiver, guard


def ConnectUplinkToRobot(builder, uplink: Uplink, robot: FlexibleJointArm) -> None:
    """The uplink's held command drives the robot directly; its send time tells the
    interpolator when each command was issued, so the ramp starts at the send time."""
    builder.Connect(uplink.get_q_sent_output_port(), robot.GetInputPort("q_commanded"))
    builder.Connect(uplink.get_send_time_output_port(), robot.GetInputPort("command_time"))


def AddLinkLoggers(builder, receiver: JointCommandReceiver, guard: LinkGuard,
                     period_s: float) -> dict:
    """Loggers of the onboard command path: accepted commands, counts, guard output/mode."""
    return {
        "q_accepted": LogVectorOutput(receiver.get_q_commanded_output_port(), builder, period_s),
        "accepted_count": LogVectorOutput(receiver.get_accepted_count_output_port(), builder,
                                          period_s),
        "last_command_seq": LogVectorOutput(receiver.get_last_command_seq_output_port(),
                                            builder, period_s),
        "rejection_counts": LogVectorOutput(receiver.get_rejection_counts_output_port(),
                                            builder, period_s),
        "guard_q_commanded": LogVectorOutput(guard.get_q_commanded_output_port(), builder,
                                             period_s),
        "guard_mode": LogVectorOutput(guard.get_guard_mode_output_port(), builder, period_s),
        "guard_command_count": LogVectorOutput(guard.get_command_count_output_port(), builder,
                                               period_s),
        "guard_stop_outcome": LogVectorOutput(guard.get_stop_outcome_output_port(), builder,
                                              period_s),
        "guard_stream_distance": LogVectorOutput(guard.get_stream_distance_output_port(),
                                                 builder, period_s),
        "guard_limited_count": LogVectorOutput(guard.get_limited_count_output_port(),
                                               builder, period_s),
    }


def AddGroundLoggers(builder, ground: GroundHandles, scenario: Scenario) -> dict:
    """Loggers of the ground station's targets, flags, packets, FIFO output and σ."""
    haptic_period = scenario.haptic.period_s
    tick = scenario.uplink.period_s
    ik, checker, uplink = ground.inverse_kinematics, ground.collision_checker, ground.uplink
    return {
        "q_target": LogVectorOutput(ik.get_q_target_output_port(), builder, haptic_period),
        "ik_failed": LogVectorOutput(ik.GetOutputPort("ik_failed"), builder, haptic_period),
        "collision_detected": LogVectorOutput(checker.GetOutputPort("collision_detected"),
                                              builder, haptic_period),
        "min_distance": LogVectorOutput(checker.GetOutputPort("min_distance"), builder,
                                        haptic_period),
        "sequence_number": LogVectorOutput(uplink.get_sequence_number_output_port(), builder,
                                           haptic_period),
        "send_time": LogVectorOutput(uplink.get_send_time_output_port(), builder,
                                     haptic_period),
        "state_sent": LogVectorOutput(uplink.get_state_sent_output_port(), builder,
                                      haptic_period),
        "q_delayed": LogVectorOutput(ground.fifo.get_q_delayed_output_port(), builder, tick),
        "holding": LogVectorOutput(ground.fifo.get_holding_output_port(), builder, tick),
        "sigma": LogVectorOutput(ground.smoother.get_sigma_output_port(), builder, tick),
        **({} if scenario.fifo.on_collision != "stop" else {
            "stop_status": LogVectorOutput(ground.fifo.get_stop_status_output_port(), builder,
                                           tick),
            "braking_distance": LogVectorOutput(
                ground.fifo.get_braking_distance_output_port(), builder, tick)}),
    }


def first_sample_indices(sequence) -> np.ndarray:
    """Indices where each non-negative value of a logged sequence number first appears.

    Counters like the uplink's sequence number are logged faster than they change; this picks
    one row per value (−1, "nothing yet", is skipped).
    """
    sequence = np.asarray(sequence)
    _, first = np.unique(sequence, return_index=True)
    first = np.sort(first)
    return first[sequence[first] >= 0]


def uplink_packets(handles: TeleoperationHandles, context):
    """The logged uplink packets of a run: (seq (M,), send times (M,), states (M, 4J))."""
    logs = handles.logs
    seq = logs["sequence_number"].FindLog(context).data()[0]
    rows = first_sample_indices(seq)
    return (seq[rows].astype(int), logs["send_time"].FindLog(context).data()[0][rows],
            logs["state_sent"].FindLog(context).data().T[rows])


def AddOnboardLoggers(builder, robot: FlexibleJointArm, period_s: float) -> dict:
    """Loggers of the robot: "tracker", the laser tracker's samples with the time each was
    taken (read it with :func:`~telesmooth.systems.laser_tracker.tracker_record`: a logger
    stamps a held sample one period after it was measured), "command_rejected", and
    "command_ramp", the interpolator's ramp in progress (its start time t₀ is when the robot
    began to move towards each command: the link's latency and the receiver's poll included).
    """
    return {
        "tracker": LogVectorOutput(robot.GetOutputPort("tracker_measurement"), builder,
                                   period_s),
        "command_rejected": LogVectorOutput(robot.GetOutputPort("command_rejected"), builder,
                                            period_s),
        "command_ramp": LogVectorOutput(robot.GetOutputPort("command_ramp"), builder, period_s),
    }


def MakeTeleoperationDiagram(scenario: Scenario, *, meshcat=None) -> TeleoperationHandles:
    """The whole chain in one process.

    ``scenario.chain == "deployed"`` (the default): each packet goes as between the two
    processes: formed by the ``JointCommandSender``, carried by a ``LinkChannel`` (a perfect
    link, or ``scenario.link.faults``), examined by the ``JointCommandReceiver`` and passed
    through the ``LinkGuard`` to the robot (no authentication in process: nobody else can
    reach the link). ``"paper"``: the uplink's held command drives the plant directly.

    ``meshcat``: optional ``pydrake.geometry.Meshcat``; the robot (and its workspace) are then
    drawn by :func:`telesmooth.diagrams.visualization.AddRobotVisualizer`.
    """
    builder = DiagramBuilder()
    ground = AddGroundStation(builder, scenario)
    q0 = ground.initial_position_rad
    deployed = scenario.chain == "deployed"
    # In the paper's chain the uplink drives the robot: its command changes only at the
    # ticks. Deployed, the robot is built as the onboard process builds it.
    robot = AddOnboardRobot(
        builder, scenario, initial_position_rad=q0,
        command_period_s=None if deployed else scenario.uplink.period_s)
    receiver = guard = link = None
    logs = {}
    if deployed:
        _, receiver, guard, link = AddDeployedLink(builder, ground, scenario, robot)
        logs.update(AddLinkLoggers(builder, receiver, guard,
                                     scenario.command_receiver.poll_period_s))
        logs["link_counts"] = LogVectorOutput(link.get_link_counts_output_port(), builder,
                                              scenario.uplink.period_s)
    else:
        ConnectUplinkToRobot(builder, ground.uplink, robot)
    if meshcat is not None:
        from telesmooth.diagrams.visualization import AddRobotVisualizer
        AddRobotVisualizer(builder, robot, meshcat)
    logs.update(AddGroundLoggers(builder, ground, scenario))
    logs.update(AddOnboardLoggers(builder, robot, scenario.onboard.tracker.period_s))
    diagram = builder.Build()
    diagram.set_name("teleoperation")
    return TeleoperationHandles(
        diagram=diagram, ground=ground,
        onboard=OnboardHandles(arm=robot, receiver=receiver, guard=guard, link=link),
        logs=logs, scenario=scenario)


def AddDeployedLink(builder: DiagramBuilder, ground: GroundHandles, scenario: Scenario,
                    robot: FlexibleJointArm):
    """The deployed chain between the ground's uplink and ``robot`` in one process: sender →
    ``LinkChannel`` (``scenario.link.faults``) → receiver → link guard → robot; returns
    (sender, receiver, guard, link).

    The channel polls at the receiver's period, just before each of its polls (see
    :class:`~telesmooth.systems.link_channel.LinkChannel`), and the guard shares the
    pre-simulator's collision model (same arm and workspace) instead of building a second
    plant."""
    sender = AddJointCommandSender(builder, ground, scenario)
    poll = scenario.command_receiver.poll_period_s
    link = builder.AddNamedSystem("link", LinkChannel(
        scenario.link.faults, lcm_type=lcmt_teleop_joint_command, poll_period_s=poll,
        poll_offset_s=0.9 * poll))
    builder.Connect(sender.get_lcm_message_output_port(), link.get_lcm_message_input_port())
    receiver, guard = AddOnboardCommandPath(
        builder, scenario, packets=link.get_packets_output_port(),
        initial_position_rad=ground.initial_position_rad,
        collision_model=ground.collision_checker.collision_model)
    builder.Connect(guard.get_q_commanded_output_port(), robot.GetInputPort("q_commanded"))
    return sender, receiver, guard, link


def MakeGroundDiagram(scenario: Scenario, *, lcm: DrakeLcm, session_id: int = 0,
                      uplink_key: bytes | None = None, session_nonce: int | None = None,
                      onboard_epoch: int = 0) -> TeleoperationHandles:
    """The ground process: ground station → TELEOP_JOINT_COMMAND (+ collision events), and
    the link status from ONBOARD_JOINT_STATUS (:class:`LinkMonitor`).

    Every packet carries the robot's epoch and this run's session
    (:mod:`telesmooth.link.session`). With ``session_nonce`` (the ground process) both come
    from the robot's telemetry through the monitor: ``onboard_epoch`` and ``session_id`` are
    what the telemetry read before the start said (0: none yet; packets are then withheld
    until telemetry arrives); a restarted robot is picked up from its telemetry. Without it
    (tests) they are fixed. ``uplink_key`` signs every packet (None: unsigned).
    """
    from telesmooth.systems.link_monitor import LinkMonitor
    builder = DiagramBuilder()
    builder.AddNamedSystem("lcm", LcmInterfaceSystem(lcm))
    ground = AddGroundStation(builder, scenario, lcm=lcm)
    period = scenario.uplink.period_s
    # The packet formed at t_k is published at t_k + publish_offset_s (Drake publishes the
    # pre-update state at an event time, so an offset of 0 would send packet k−1).
    sender = AddJointCommandSender(builder, ground, scenario, session_id=session_id,
                                   uplink_key=uplink_key, onboard_epoch=onboard_epoch)
    command_publisher = builder.AddNamedSystem("joint_command_publisher",
        LcmPublisherSystem.Make(TELEOP_JOINT_COMMAND, lcmt_teleop_joint_command, lcm,
                                publish_period=period,
                                publish_offset=scenario.publish_offset_s))
    builder.Connect(sender.get_lcm_message_output_port(), command_publisher.get_input_port())
    events = builder.AddNamedSystem("collision_event_sender", CollisionEventSender())
    builder.Connect(ground.collision_checker.GetOutputPort("collision_detected"),
                    events.get_collision_detected_input_port())
    builder.Connect(ground.fifo.get_holding_output_port(), events.get_holding_input_port())
    builder.Connect(ground.collision_checker.GetOutputPort("min_distance"),
                    events.get_min_distance_input_port())
    builder.Connect(ground.uplink.get_sequence_number_output_port(),
                    events.get_sequence_number_input_port())
    event_publisher = builder.AddNamedSystem("collision_event_publisher",
        LcmPublisherSystem.Make(TELEOP_COLLISION_EVENT, lcmt_teleop_collision_event, lcm,
                                publish_period=period,
                                publish_offset=scenario.publish_offset_s))
    builder.Connect(events.get_lcm_message_output_port(), event_publisher.get_input_port())
    telemetry = builder.AddNamedSystem("joint_status_subscriber", LcmSafeSubscriber(
        channel=ONBOARD_JOINT_STATUS, lcm_type=lcmt_onboard_joint_status, lcm=lcm))
    monitor = builder.AddNamedSystem("link_monitor", LinkMonitor(
        session_id=session_id, session_nonce=session_nonce, onboard_epoch=onboard_epoch))
    if session_nonce is not None:
        builder.Connect(monitor.GetOutputPort("onboard_epoch"),
                        sender.get_onboard_epoch_input_port())
        builder.Connect(monitor.GetOutputPort("session_id"), sender.get_session_id_input_port())
    builder.Connect(telemetry.get_lcm_message_output_port(), monitor.GetInputPort("telemetry"))
    builder.Connect(telemetry.get_message_count_output_port(),
                    monitor.GetInputPort("telemetry_count"))
    builder.Connect(ground.uplink.get_sequence_number_output_port(),
                    monitor.GetInputPort("sequence_number"))
    logs = AddGroundLoggers(builder, ground, scenario)
    for name in ("link_status", "telemetry_age", "unacknowledged", "onboard_guard_mode",
                 "onboard_counts", "stream_distance"):
        logs[name] = LogVectorOutput(monitor.GetOutputPort(name), builder, 0.05)
    # What the robot reported, for the ground's report (one row per telemetry period; a
    # message is repeated until the next arrives, the report keeps one row per seq).
    decoder = builder.AddNamedSystem("joint_status_decoder", JointStatusDecoder(
        num_joints=len(ground.joint_names)))
    builder.Connect(telemetry.get_lcm_message_output_port(),
                    decoder.get_lcm_message_input_port())
    logs["telemetry"] = LogVectorOutput(decoder.get_telemetry_output_port(), builder,
                                        scenario.onboard.tracker.period_s)
    diagram = builder.Build()
    diagram.set_name("ground")
    return TeleoperationHandles(diagram=diagram, ground=ground, onboard=None, logs=logs,
                                lcm=lcm, scenario=scenario)


def AddJointStatusSender(builder: DiagramBuilder, robot: FlexibleJointArm,
                         receiver: JointCommandReceiver, guard: LinkGuard, *,
                         onboard_epoch: int = 0) -> JointStatusSender:
    """Adds the robot's telemetry message (``lcmt_onboard_joint_status``) from the robot's
    tracker, the receiver and the guard; publish it at the tracker's rate."""
    status = builder.AddNamedSystem("joint_status_sender", JointStatusSender(
        num_joints=robot.num_joints, period_s=robot.config.tracker.period_s,
        onboard_epoch=onboard_epoch))
    for robot_port, status_port in (
            ("q_link", status.get_q_link_input_port()),
            ("q_motor", status.get_q_motor_input_port()),
            ("position_measured", status.get_position_measured_input_port()),
            ("velocity_measured", status.get_velocity_measured_input_port()),
            ("tracker_sample_time", status.get_sample_time_input_port())):
        builder.Connect(robot.GetOutputPort(robot_port), status_port)
    for name in ("last_command_seq", "last_command_session", "command_rejected",
                 "command_timeout", "accepted_count", "rejection_counts"):
        builder.Connect(receiver.GetOutputPort(name), status.GetInputPort(name))
    builder.Connect(guard.get_q_commanded_output_port(), status.get_q_commanded_input_port())
    builder.Connect(guard.get_guard_mode_output_port(), status.get_guard_mode_input_port())
    builder.Connect(guard.get_stream_distance_output_port(),
                    status.get_stream_distance_input_port())
    return status


def MakeOnboardDiagram(scenario: Scenario, *, lcm: DrakeLcm, initial_position_rad=None,
                       uplink_key: bytes | None = None, uplink_lcm=None,
                       onboard_epoch: int = 0) -> TeleoperationHandles:
    """The onboard process: TELEOP_JOINT_COMMAND → receiver → link guard → plant → telemetry.

    Every packet is examined (:class:`JointCommandReceiver`: authentication when
    ``scenario.command_receiver.authentication == "required"``, with ``uplink_key``; order;
    validity); the :class:`LinkGuard` ramps the robot down within the limits when commands
    stop and re-joins them without a jump. ``initial_position_rad`` defaults to the
    scenario's (or the IK of its first pose).

    ``uplink_lcm``: optional ``lcm.LCM`` (the ``lcm`` package) or
    :class:`~telesmooth.link.udpm_receiver.UdpmReceiver` on the same bus as ``lcm`` for the
    uplink subscription, which then queues a burst of packets instead of keeping one
    (:mod:`~telesmooth.systems.lcm_safe_subscriber`); the onboard process uses a receiver,
    which also counts the packets lost before decoding.
    ``onboard_epoch``: this run's epoch (:func:`telesmooth.link.session.new_epoch`),
    announced in the telemetry; only commands that carry it are accepted.
    """
    if initial_position_rad is None:
        initial_position_rad = initial_position(scenario, make_haptic_recording(scenario))
    builder = DiagramBuilder()
    builder.AddNamedSystem("lcm", LcmInterfaceSystem(lcm))
    # A subscriber that survives malformed packets; the receiver examines every packet.
    # With its own uplink bus it pumps when the receiver polls, so that the receiver sees
    # every batch of packets it takes (lcm_safe_subscriber: pump_period_s).
    subscriber = builder.AddNamedSystem("joint_command_subscriber", LcmSafeSubscriber(
        channel=TELEOP_JOINT_COMMAND, lcm_type=lcmt_teleop_joint_command,
        lcm=lcm if uplink_lcm is None else uplink_lcm,
        pump_period_s=(None if uplink_lcm is None
                       else scenario.command_receiver.poll_period_s)))
    receiver, guard = AddOnboardCommandPath(
        builder, scenario, packets=subscriber.get_packets_output_port(),
        initial_position_rad=initial_position_rad, uplink_key=uplink_key,
        onboard_epoch=onboard_epoch)
    robot = AddOnboardRobot(builder, scenario, initial_position_rad=initial_position_rad)
    builder.Connect(guard.get_q_commanded_output_port(), robot.GetInputPort("q_commanded"))
    tracker_period = scenario.onboard.tracker.period_s
    status = AddJointStatusSender(builder, robot, receiver, guard, onboard_epoch=onboard_epoch)
    status_publisher = builder.AddNamedSystem("joint_status_publisher",
        LcmPublisherSystem.Make(ONBOARD_JOINT_STATUS, lcmt_onboard_joint_status, lcm,
                                publish_period=tracker_period,
                                publish_offset=scenario.publish_offset_s))
    builder.Connect(status.get_lcm_message_output_port(), status_publisher.get_input_port())
    logs = AddOnboardLoggers(builder, robot, tracker_period)
    logs.update(AddLinkLoggers(builder, receiver, guard,
                                 scenario.command_receiver.poll_period_s))
    logs["last_command_session"] = LogVectorOutput(
        receiver.get_last_command_session_output_port(), builder,
        scenario.command_receiver.poll_period_s)
    diagram = builder.Build()
    diagram.set_name("onboard")
    return TeleoperationHandles(diagram=diagram, ground=None,
                                onboard=OnboardHandles(arm=robot, receiver=receiver,
                                                       guard=guard),
                                logs=logs, lcm=lcm, scenario=scenario)
