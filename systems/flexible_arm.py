"""The onboard robot: a flexible-joint arm with its motor servos and the laser tracker.

This is the "plant" end of the teleoperation chain. It takes the held 4 Hz joint commands
that arrive over the uplink and returns what the onboard sensors see: the 100 Hz
end-effector position from the laser tracker, plus the link-side and motor-side joint
angles. Inside it are three parts:

* a MultibodyPlant + SceneGraph with the flexible model of the arm. Each moving joint is a
  motor-side actuated joint ``<name>_motor`` in series with a link-side joint
  ``<name>_deflection`` that carries a spring and a damper (see
  :mod:`telesmooth.arms.description`). The motor servo is the plant's own PD controller on
  the motor joints (gains from the model's ``drake:controller_gains``). By default the
  plant is continuous and the Simulator's error-controlled integrator chooses its steps;
  with a fixed step (``time_step_s`` > 0) Drake computes the PD implicitly (SAP).
* a :class:`~telesmooth.systems.command_interpolator.CommandInterpolator`, which turns the
  held commands into the servo's desired state and rejects unsafe commands (the robot
  holds).
* a :class:`~telesmooth.systems.laser_tracker.LaserTracker`, which samples the state at
  100 Hz.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from pydrake.multibody.plant import AddMultibodyPlant, MultibodyPlant, MultibodyPlantConfig
from pydrake.systems.analysis import ResetIntegratorFromFlags, Simulator
from pydrake.systems.framework import Diagram, DiagramBuilder
from pydrake.systems.primitives import MatrixGain

from telesmooth.arms.description import (
    ARMS,
    DRIVE_FIELDS,
    PLANT_PRESETS,
    ArmDescription,
    drive_preset,
    with_drive,
)
from telesmooth.arms.drake_models import add_arm
from telesmooth.arms.joint_vectors import as_per_joint, check_joint_vector
from telesmooth.systems.command_interpolator import (
    CommandInterpolator,
    CommandInterpolatorConfig,
)
from telesmooth.systems.laser_tracker import LaserTracker, LaserTrackerConfig

__all__ = [
    "DISCRETE_CONTACT_APPROXIMATIONS",
    "DriveConfig",
    "FlexibleArmConfig",
    "FlexibleJointArm",
    "INTEGRATION_SCHEMES",
    "desired_state_permutation",
    "MakeSimulator",
]


DISCRETE_CONTACT_APPROXIMATIONS = ("lagged", "sap", "similar")
"""The values of ``MultibodyPlantConfig.discrete_contact_approximation`` that we accept: the
SAP-based ones, whose implicit PD runs the motor servos. ``"tamsi"`` (deprecated in Drake) is
refused: with it the plant's PD controllers do nothing (the motors stay put)."""

INTEGRATION_SCHEMES = ("bogacki_shampine3", "runge_kutta3", "runge_kutta5", "radau1", "radau3",
                       "implicit_euler", "velocity_implicit_euler")
"""Drake's error-controlled integrators that ``FlexibleArmConfig.integration_scheme`` accepts
(the fixed-step ones, ``runge_kutta2`` and the Euler methods, are refused: nothing would
bound their error)."""

MAX_INTEGRATOR_STEP_S = 0.01
"""The integrator's largest step, s: 10 ms, the period of the laser tracker and of the chain's
other 100 Hz stages. In a run of the chain their events end a step every 10 ms anyway. A
playback (``compare``, ``experiment``, the offline mode) takes its tracker samples from the
integrator's dense output instead, with no event; this cap keeps its steps, and with them its
accuracy, those of the event-bound run. The error control at ``integration_accuracy`` alone
lets the steps grow past the 14.7 Hz mode of the lab arm and e move by 3 % (docs/numerics.md)."""


@dataclasses.dataclass(frozen=True)
class DriveConfig:
    """The drive-train of every joint: what makes the onboard arm flexible.

    Each joint is a motor (rotor inertia J_r behind a gear ratio N; the plant's PD servo with
    gains kp, kd) driving its link through a spring k with a damper c (see
    :mod:`telesmooth.arms.description`). ``preset`` picks a named set of these numbers
    (:data:`~telesmooth.arms.description.PLANT_PRESETS`); every other field, if given,
    replaces the preset's value. A per-joint field takes one number for all joints, a list
    (one per joint, base to tip) or a mapping joint name → number naming every joint.

    Attributes:
        preset: ``"lab"`` (default: the laboratory arm) or ``"lightweight"`` (10× softer
            springs, lowest lightly damped mode about 0.9-1.2 Hz, damping ratio about 0.02).
        stiffness_n_m_per_rad: Link-side spring stiffness k, N·m/rad (> 0).
        damping_n_m_s_per_rad: Link-side damping c, N·m·s/rad (> 0).
        rotor_inertia_kg_m2: Rotor inertia J_r before the gear, kg·m² (> 0); the motor
            coordinate sees N²·J_r.
        motor_kp_n_m_per_rad: Servo proportional gain kp, N·m/rad (> 0).
        motor_kd_n_m_s_per_rad: Servo derivative gain kd, N·m·s/rad (> 0).
    """

    preset: str = "lab"
    stiffness_n_m_per_rad: object = None
    damping_n_m_s_per_rad: object = None
    rotor_inertia_kg_m2: object = None
    motor_kp_n_m_per_rad: object = None
    motor_kd_n_m_s_per_rad: object = None

    def __post_init__(self) -> None:
        if self.preset not in PLANT_PRESETS:
            raise ValueError(f"preset = {self.preset!r} must be one of {PLANT_PRESETS}")

    def apply(self, arm: ArmDescription) -> ArmDescription:
        """``arm`` with this drive: the preset, then the given fields.

        Raises:
            ValueError: naming the field (``drive.<field>``), the joint and the value, if a
                value is not a positive finite number or the joint count does not match.
        """
        arm = drive_preset(arm, self.preset)
        values = {}
        for field in DRIVE_FIELDS:
            value = getattr(self, field)
            if value is not None:
                values[field] = tuple(as_per_joint(f"drive.{field}", value, arm.num_joints,
                                                   arm.joint_names))
        return with_drive(arm, **values) if values else arm


@dataclasses.dataclass(frozen=True)
class FlexibleArmConfig:
    """Settings of the onboard flexible-joint arm.

    Attributes:
        arm: Which arm: ``"air_bearing_arm"`` (default; the planar 3-joint laboratory set-up,
            moving in the world x-y plane) or ``"space_arm"`` (the 6-DOF manipulator).
        time_step_s: Plant step, s (≥ 0). 0 (default): a continuous plant, integrated by
            the Simulator's error-controlled integrator (``integration_scheme`` at
            ``integration_accuracy``), which follows each new command from the instant the
            interpolator sees it. A positive step gives a discrete plant (SAP, implicit
            PD and damping) that reads its set-point at the start of each step: a command
            sent at t moves the motors only from the first step after t, so the set-point
            stalls for up to one step at every command, and the tracking error grows with
            the step (see docs/numerics.md, "Simulation speed and accuracy").
        integration_scheme: The error-controlled integrator of the continuous plant, one of
            :data:`INTEGRATION_SCHEMES` (drake's names). The default is
            ``"bogacki_shampine3"`` (third order with an embedded second-order error
            estimate). Applied by :func:`MakeSimulator`; ignored by a discrete plant.
        integration_accuracy: The integrator's target accuracy (relative, > 0 and < 1). The
            default 1e-3 keeps e, P, E_def and the link deflection within 1 % of a 1e-6
            integration (``tests/test_plant_accuracy.py``; measured ≤ 0.6 %): the steps are
            bounded by the 10 ms events, so a tighter target buys little.
        discrete_contact_approximation: One of :data:`DISCRETE_CONTACT_APPROXIMATIONS`.
            The default is ``"lagged"``. Without contact, all of them give the same
            result here.
        gravity_m_per_s2: Gravity vector in the world frame, m/s². The default is zero:
            in orbit, and on the air-bearing table, where the arm moves in a horizontal
            plane.
        interpolator: Settings of the command interpolator (motor set-point).
        tracker: Settings of the laser tracker.
        drive: The joints' springs, dampers, rotor inertias and servo gains (a preset and
            overrides); the plant's vibration modes follow from them.
        initial_position_rad: Joint angles at t = 0 (motors and links, no deflection), and
            the position held before the first command, rad; one per joint of ``arm``,
            within its limits. ``None`` means all zeros.
    """

    arm: str = "air_bearing_arm"
    time_step_s: float = 0.0
    integration_scheme: str = "bogacki_shampine3"
    integration_accuracy: float = 1e-3
    discrete_contact_approximation: str = "lagged"
    gravity_m_per_s2: tuple[float, float, float] = (0.0, 0.0, 0.0)
    interpolator: CommandInterpolatorConfig = dataclasses.field(
        default_factory=CommandInterpolatorConfig)
    tracker: LaserTrackerConfig = dataclasses.field(default_factory=LaserTrackerConfig)
    drive: DriveConfig = dataclasses.field(default_factory=DriveConfig)
    initial_position_rad: tuple[float, ...] | None = None

    def __post_init__(self) -> None:
        if self.arm not in ARMS:
            raise ValueError(
                f"FlexibleArmConfig.arm = {self.arm!r} must be one of {tuple(ARMS)}")
        step = self.time_step_s
        if isinstance(step, bool) or not isinstance(step, (int, float)) \
                or not math.isfinite(step) or step < 0.0:
            raise ValueError(
                f"FlexibleArmConfig.time_step_s = {step!r} must be finite and >= 0 "
                "(0 = continuous plant)")
        if self.integration_scheme not in INTEGRATION_SCHEMES:
            raise ValueError(
                f"FlexibleArmConfig.integration_scheme = {self.integration_scheme!r} must be "
                f"one of {INTEGRATION_SCHEMES}")
        accuracy = self.integration_accuracy
        if isinstance(accuracy, bool) or not isinstance(accuracy, (int, float)) \
                or not 0.0 < accuracy < 1.0:
            raise ValueError(
                f"FlexibleArmConfig.integration_accuracy = {accuracy!r} must be > 0 and < 1")
        if self.discrete_contact_approximation not in DISCRETE_CONTACT_APPROXIMATIONS:
            raise ValueError(
                "FlexibleArmConfig.discrete_contact_approximation = "
                f"{self.discrete_contact_approximation!r} must be one of "
                f"{DISCRETE_CONTACT_APPROXIMATIONS}")
        gravity = _float_tuple("FlexibleArmConfig.gravity_m_per_s2", self.gravity_m_per_s2)
        if len(gravity) != 3:
            raise ValueError(
                f"FlexibleArmConfig.gravity_m_per_s2 = {self.gravity_m_per_s2!r} must have "
                "3 values (x, y, z)")
        object.__setattr__(self, "gravity_m_per_s2", gravity)
        if not isinstance(self.interpolator, CommandInterpolatorConfig):
            raise ValueError(
                f"FlexibleArmConfig.interpolator = {self.interpolator!r} must be a "
                "CommandInterpolatorConfig")
        if not isinstance(self.tracker, LaserTrackerConfig):
            raise ValueError(
                f"FlexibleArmConfig.tracker = {self.tracker!r} must be a LaserTrackerConfig")
        if not isinstance(self.drive, DriveConfig):
            raise ValueError(
                f"FlexibleArmConfig.drive = {self.drive!r} must be a DriveConfig")
        if self.initial_position_rad is not None:
            arm = ARMS[self.arm]
            q0 = check_joint_vector("FlexibleArmConfig.initial_position_rad",
                                    self.initial_position_rad, arm.joint_names,
                                    lower=arm.joint_lower_rad, upper=arm.joint_upper_rad)
            object.__setattr__(self, "initial_position_rad", tuple(q0.tolist()))

    @property
    def arm_description(self) -> ArmDescription:
        """The :class:`ArmDescription` named by :attr:`arm`, with :attr:`drive` applied.

        Raises:
            ValueError: if a drive value does not fit the arm (see :meth:`DriveConfig.apply`).
        """
        return self.drive.apply(ARMS[self.arm])


def _float_tuple(field: str, values) -> tuple[float, ...]:
    """``values`` as a tuple of finite floats, or ValueError naming ``field``, index, value."""
    try:
        result = tuple(float(value) for value in values)
    except (TypeError, ValueError):
        raise ValueError(f"{field} = {values!r} must be a sequence of numbers") from None
    for index, value in enumerate(result):
        if not math.isfinite(value):
            raise ValueError(f"{field}[{index}] = {value!r} must be finite")
    return result


def desired_state_permutation(plant, model_instance, joint_names) -> np.ndarray:
    """P such that P·[q_d; v_d] (joint order) is the plant's desired state (actuator order).

    ``plant.get_desired_state_input_port(model_instance)`` takes [q_d; v_d] ordered like the
    instance's actuators (``plant.GetJointActuatorIndices(model_instance)``). Each actuator
    is matched to its joint by name: the actuator of ``<name>_motor`` belongs to ``name``.

    Returns:
        A (2n, 2n) permutation matrix.

    Raises:
        ValueError: if the actuators and ``joint_names`` do not match one to one.
    """
    names = list(joint_names)
    n = len(names)
    actuators = [plant.get_joint_actuator(index)
                 for index in plant.GetJointActuatorIndices(model_instance)]
    actuated = [actuator.joint().name() for actuator in actuators]
    expected = sorted(name + "_motor" for name in names)
    if sorted(actuated) != expected:
        raise ValueError(
            f"the actuated joints {actuated} of the model do not match joint_names {names} "
            "(expected one actuated '<name>_motor' joint per name)")
    permutation = np.zeros((2 * n, 2 * n))
    for row, joint_name in enumerate(actuated):
        column = names.index(joint_name.removesuffix("_motor"))
        permutation[row, column] = 1.0
        permutation[n + row, n + column] = 1.0
    return permutation


class FlexibleJointArm(Diagram):
    r"""The onboard flexible-joint arm: command interpolation, motor servos, laser tracker.

    .. pydrake_system::

        name: FlexibleJointArm
        input_ports:
        - q_commanded
        - command_time (optional)
        output_ports:
        - position_measured
        - q_link
        - q_motor
        - tracker_sample_time
        - tracker_measurement
        - velocity_measured
        - command_rejected
        - state_desired
        - plant_state
        - query_object

    Ports (n = number of joints: 3 for the air-bearing arm, 6 for the space arm; joint order
    = :attr:`joint_names`):

    - ``q_commanded``: the held joint-position command (4 Hz uplink, zero-order hold), rad,
      (n,). Must be connected or fixed. The upstream hold must start at the robot's pose
      (see "before the first command").
    - ``command_time``: optional; when the held command was issued (e.g. the uplink's
      ``send_time``), s, (1,). Connected, a new command's ramp starts at that instant
      instead of at the poll that sees it (see :class:`CommandInterpolator`).
    - ``position_measured``: laser-tracker end-effector position p_WT (origin of the
      ``tool`` frame in world), m, (3,), sampled every ``tracker.period_s`` (100 Hz) and
      held; for the air-bearing arm it moves in the world x-y plane (z = 0).
    - ``q_link``: link-side joint angles (motor + deflection), rad, (n,), same samples.
    - ``q_motor``: motor-side joint angles, rad, (n,), same samples.
    - ``tracker_sample_time``: time of the held tracker sample, s, (1,).
    - ``tracker_measurement``: [t_k, p_WT, q_link, q_motor], the held sample with the time
      it was taken, (4 + 2n,): the port to log (see :class:`LaserTracker`).
    - ``velocity_measured``: the link-side and motor-side joint velocities of the same
      sample, [v_link; v_motor], rad/s, (2n,).
    - ``command_rejected``: 1.0 while the last received command was rejected (not finite,
      or outside the joint limits) and the robot holds its previous target, else 0.0, (1,).
    - ``state_desired``: the servo set-point [q_d; v_d], rad and rad/s, (2n,), joint order;
      at time t it is the ramp at t + h (h = ``time_step_s``, 0 for the continuous plant):
      a discrete plant reads it at the start of a step and its implicit PD reaches it at
      the end, so the motors track the ramp itself, not the ramp one step late.
    - ``plant_state``: the full plant state [q; v], (4n,): per joint (motor, deflection)
      positions in the plant's order, then velocities (see ``plant.GetStateNames()``).
    - ``query_object``: SceneGraph's query output, for visualizers (absent when built with
      ``contact_geometry=False``).

    Motor servo (the plant's PD, per motor joint i, clamped to the motor's effort limit):

        τ_i = kp_i·(q_d,i − q_motor,i) + kd_i·(v_d,i − v_motor,i)

    Link side: τ_spring,i = −k_i·δ_i − c_i·δ̇_i, with δ_i = the deflection and
    q_link,i = q_motor,i + δ_i.

    The set-point (see :class:`CommandInterpolator`): a new command u starts a ramp at t₀,
    the command's ``command_time`` if connected, else the poll that sees it (polls every
    ``command_period_s`` or 10 ms, 0.1 ms after each multiple),
    from the set-point q₀ = q_d(t₀):

        "linear": q_d(t) = q₀ + clip((t − t₀)/T, 0, 1)·(u − q₀),
                  v_d(t) = (u − q₀)/T on [t₀, t₀ + T), else 0     (T = 0.25 s)
        "zoh":    q_d(t) = u, v_d(t) = 0

    Before the first command, and at t = 0, the set-point is ``initial_position_rad``
    (zeros by default) with zero velocity. The default plant state is that pose with zero
    deflection and zero velocity, and the tracker's first sample is taken at t = 0 (at
    Simulator initialization), so the robot is at rest and holds. A command that is not
    finite or is outside the limits is never sent to the servo: the robot keeps its
    previous target and ``command_rejected`` is 1.0 until a valid command is received.

    Collision filtering: the rotor bodies between the links break Drake's automatic
    parent/child filter; the generated SDF declares ``drake:collision_filter_group``s for
    every consecutive link pair (``ArmDescription.filtered_pairs``), so none can be in
    contact.
    """

    def __init__(self, config: FlexibleArmConfig = FlexibleArmConfig(), *,
                 command_period_s: float | None = None, tracker_in_diagram: bool = True,
                 contact_geometry: bool = True):
        """Builds the diagram.

        Args:
            config: The arm, plant step, gravity, initial pose and sub-system settings.
            command_period_s: The period at which ``q_commanded`` can change, s, if the
                diagram that drives the robot knows it (the uplink's 0.25 s when it drives
                the robot directly): the interpolator then polls at it, 0.1 ms after each
                change, instead of every 10 ms (unless ``config.interpolator.poll_period_s``
                says otherwise). None: 10 ms, the onboard receiver's rate.
            tracker_in_diagram: True (default): the laser tracker is a stage of the diagram,
                sampling the plant with its own periodic event. False (a playback whose
                tracker record is read only after the run): the tracker is built but left
                out of the diagram, so its samples do not stop the integrator, and the
                diagram has no tracker ports (``position_measured``, ``q_link``,
                ``q_motor``, ``tracker_sample_time``, ``tracker_measurement``); its
                :meth:`LaserTracker.Record` takes the samples afterwards from the plant's
                states at the sample instants
                (:func:`~telesmooth.diagrams.offline_playback.simulate_playback`).
            contact_geometry: True (default): the plant carries the arm's collision geometry
                (links that meet push each other apart) in a SceneGraph. False (a playback
                whose run is then certified free of self-contact,
                :mod:`telesmooth.arms.self_contact`): the plant has no geometry and no
                SceneGraph, and the diagram has no ``query_object`` port; continuous plant
                only.

        Raises:
            ValueError: if ``config`` is not a FlexibleArmConfig. Invalid field values are
                already rejected when the config is constructed.
        """
        super().__init__()
        if not isinstance(config, FlexibleArmConfig):
            raise ValueError(f"config = {config!r} must be a FlexibleArmConfig")
        if not contact_geometry and config.time_step_s != 0.0:
            raise ValueError("contact_geometry=False needs the continuous plant "
                             f"(time_step_s = 0); got time_step_s = {config.time_step_s!r}")
        arm = config.arm_description
        n = arm.num_joints
        q0 = (np.zeros(n) if config.initial_position_rad is None
              else np.array(config.initial_position_rad))
        self._config = config
        self._arm = arm
        self._joint_names = arm.joint_names
        builder = DiagramBuilder()

        # Plant: the flexible model (motor joint + spring/damper joint per joint).
        # Output ports computed from the state (not "sampled"): with sampled output ports, a
        # discrete update at t_n (the tracker's sample) reads the plant's state after its
        # step at t_n, i.e. the state of t_n + h, while loggers and the state itself are of
        # t_n. Unsampled, every reader at t sees the state of t.
        plant_config = MultibodyPlantConfig(
            time_step=config.time_step_s,
            discrete_contact_approximation=config.discrete_contact_approximation,
            use_sampled_output_ports=False)
        if contact_geometry:
            plant, scene_graph = AddMultibodyPlant(plant_config, builder)
        else:
            # No SceneGraph: the parser registers no geometry, and the plant asks for none.
            plant, scene_graph = builder.AddNamedSystem(
                "plant", MultibodyPlant(config.time_step_s)), None
        instance = add_arm(plant, arm, flexible=True)
        plant.mutable_gravity_field().set_gravity_vector(np.array(config.gravity_m_per_s2))
        for name, angle in zip(arm.joint_names, q0):
            plant.GetJointByName(name + "_motor", instance).set_default_angle(angle)
            plant.GetJointByName(name + "_deflection", instance).set_default_angle(0.0)
        plant.Finalize()

        # Motor set-point: held 4 Hz commands → [q_d; v_d], unsafe commands rejected.
        interpolator = builder.AddNamedSystem("command_interpolator", CommandInterpolator(
            config.interpolator, joint_names=arm.joint_names, lower_rad=arm.joint_lower_rad,
            upper_rad=arm.joint_upper_rad, initial_position_rad=q0,
            lead_s=config.time_step_s, continuous_diagram=config.time_step_s == 0.0,
            command_period_s=command_period_s))
        # Joint order → actuator order for the plant's PD (desired-state input).
        to_actuator_order = builder.AddNamedSystem(
            "desired_state_to_actuator_order",
            MatrixGain(desired_state_permutation(plant, instance, arm.joint_names)))
        builder.Connect(interpolator.get_state_desired_output_port(),
                        to_actuator_order.get_input_port())
        builder.Connect(to_actuator_order.get_output_port(),
                        plant.get_desired_state_input_port(instance))

        # Onboard sensors: the 100 Hz laser tracker and the joint encoders.
        tracker = LaserTracker(config.tracker, plant=plant, model_instance=instance,
                               joint_names=arm.joint_names, tool_frame_name=arm.tool_frame)
        tracker.set_name("laser_tracker")
        if tracker_in_diagram:
            builder.AddSystem(tracker)
            builder.Connect(plant.get_state_output_port(),
                            tracker.get_plant_state_input_port())
            for port, name in ((tracker.get_position_measured_output_port(),
                                "position_measured"),
                               (tracker.get_q_link_output_port(), "q_link"),
                               (tracker.get_q_motor_output_port(), "q_motor"),
                               (tracker.get_sample_time_output_port(), "tracker_sample_time"),
                               (tracker.get_measurement_output_port(),
                                "tracker_measurement"),
                               (tracker.get_velocity_measured_output_port(),
                                "velocity_measured")):
                builder.ExportOutput(port, name)

        builder.ExportInput(interpolator.get_q_commanded_input_port(), "q_commanded")
        builder.ExportInput(interpolator.get_command_time_input_port(), "command_time")
        builder.ExportOutput(interpolator.get_command_rejected_output_port(),
                             "command_rejected")
        builder.ExportOutput(interpolator.get_state_desired_output_port(), "state_desired")
        builder.ExportOutput(interpolator.get_ramp_output_port(), "command_ramp")
        builder.ExportOutput(plant.get_state_output_port(), "plant_state")
        if scene_graph is not None:
            builder.ExportOutput(scene_graph.get_query_output_port(), "query_object")
        builder.BuildInto(self)
        self.set_name(f"flexible_{arm.name}")

        self._plant = plant
        self._scene_graph = scene_graph
        self._model_instance = instance
        self._interpolator = interpolator
        self._tracker = tracker
        self._tracker_in_diagram = bool(tracker_in_diagram)

    # -- accessors ------------------------------------------------------------------------

    @property
    def config(self) -> FlexibleArmConfig:
        return self._config

    @property
    def arm(self) -> ArmDescription:
        return self._arm

    @property
    def joint_names(self) -> tuple[str, ...]:
        """Joint names, base to tip: the order of every joint-space port."""
        return self._joint_names

    @property
    def num_joints(self) -> int:
        return len(self._joint_names)

    @property
    def plant(self):
        """The MultibodyPlant (flexible model, finalized)."""
        return self._plant

    @property
    def scene_graph(self):
        return self._scene_graph

    @property
    def model_instance(self):
        """The arm's model instance in :attr:`plant`."""
        return self._model_instance

    @property
    def interpolator(self) -> CommandInterpolator:
        return self._interpolator

    @property
    def tracker(self) -> LaserTracker:
        """The laser tracker (a stage of this diagram unless built with
        ``tracker_in_diagram=False``)."""
        return self._tracker

    @property
    def tracker_in_diagram(self) -> bool:
        """False if built without the tracker as a stage (no tracker ports, no 100 Hz event)."""
        return self._tracker_in_diagram

    def SetInitialPositions(self, root_context, q_rad) -> None:
        """Puts the arm at rest at ``q_rad`` in ``root_context`` and makes it hold there.

        Motors and links at ``q_rad`` (zero deflection), zero velocities, the interpolator
        holding ``q_rad`` from the context's time, and the tracker's sample retaken. The
        upstream command hold must start at ``q_rad`` too: a different held ``q_commanded``
        is a new command at the next poll.

        Args:
            root_context: A context of the root diagram that contains this arm (or of
                this arm itself).
            q_rad: Joint angles, rad; shape (n,), finite and within the joint limits.

        Raises:
            ValueError: naming the joint and value, if ``q_rad`` is invalid.
        """
        interpolator_context = self._interpolator.GetMyMutableContextFromRoot(root_context)
        # Validates q_rad (shape, finite, limits) before anything is changed.
        self._interpolator.SetHoldPosition(interpolator_context, q_rad)
        q = np.asarray(q_rad, dtype=float)
        plant_context = self._plant.GetMyMutableContextFromRoot(root_context)
        for name, angle in zip(self._joint_names, q):
            self._plant.GetJointByName(name + "_motor", self._model_instance).set_angle(
                plant_context, angle)
            self._plant.GetJointByName(name + "_deflection", self._model_instance).set_angle(
                plant_context, 0.0)
        self._plant.SetVelocities(plant_context, self._model_instance,
                                  np.zeros(self._plant.num_velocities(self._model_instance)))
        if self._tracker_in_diagram:
            self._tracker.Sample(self._tracker.GetMyMutableContextFromRoot(root_context))

    def SetMeasuredState(self, root_context, *, q_link, q_motor, v_link, v_motor) -> None:
        """Sets the plant's state in ``root_context`` from measured joints (the robot's
        telemetry): motor angles and rates, and the deflection = link − motor (angle and
        rate). The interpolator and the tracker keep their state.

        Args:
            root_context: A context of the root diagram that contains this arm.
            q_link, q_motor: Link-side and motor-side angles, rad, (n,).
            v_link, v_motor: Their rates, rad/s, (n,).

        Raises:
            ValueError: if a vector has the wrong size or a non-finite entry.
        """
        values = {}
        for name, value in (("q_link", q_link), ("q_motor", q_motor), ("v_link", v_link),
                            ("v_motor", v_motor)):
            array = np.asarray(value, dtype=float)
            if array.shape != (self.num_joints,) or not np.all(np.isfinite(array)):
                raise ValueError(f"{name} = {array.tolist()!r} must be {self.num_joints} "
                                 "finite numbers")
            values[name] = array
        plant, instance = self._plant, self._model_instance
        plant_context = plant.GetMyMutableContextFromRoot(root_context)
        positions = plant.GetPositions(plant_context).copy()
        velocities = plant.GetVelocities(plant_context).copy()
        for j, name in enumerate(self._joint_names):
            motor = plant.GetJointByName(name + "_motor", instance)
            deflection = plant.GetJointByName(name + "_deflection", instance)
            positions[motor.position_start()] = values["q_motor"][j]
            positions[deflection.position_start()] = values["q_link"][j] - values["q_motor"][j]
            velocities[motor.velocity_start()] = values["v_motor"][j]
            velocities[deflection.velocity_start()] = (values["v_link"][j]
                                                       - values["v_motor"][j])
        plant.SetPositions(plant_context, positions)
        plant.SetVelocities(plant_context, velocities)


def MakeSimulator(diagram, config: FlexibleArmConfig) -> Simulator:
    """A Simulator of ``diagram`` whose integrator is the one ``config`` names.

    ``integration_scheme`` at ``integration_accuracy``, largest step
    :data:`MAX_INTEGRATOR_STEP_S`. Every run of a diagram that holds the continuous plant
    (``simulate``, ``compare``, ``experiment``, the onboard process) is built here, so they
    all integrate it alike. The Simulator is not initialized.
    """
    simulator = Simulator(diagram)
    integrator = ResetIntegratorFromFlags(simulator, config.integration_scheme,
                                          MAX_INTEGRATOR_STEP_S)
    integrator.set_target_accuracy(config.integration_accuracy)
    return simulator
