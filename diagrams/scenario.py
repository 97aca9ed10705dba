"""The scenario: every setting of a teleoperation run, loadable from YAML.

A :class:`Scenario` composes the config dataclass of each stage plus the run settings (arm,
operator source, LCM URL, duration). Scenario files are mappings from scenario names to
(partial) scenarios; :func:`LoadScenario` picks one, applies text overrides and builds the
dataclasses through their constructors, so every value is validated as in code and unknown
keys are errors (see :mod:`telesmooth.typed_yaml`).

Built-in scenarios (``diagrams/scenarios.yaml``): ``Defaults`` (all defaults: the air-bearing
arm replaying the LASA "Angle" demonstration 0, Online-CKS) and ``OneOfEverything`` (the
6-DOF arm, synthetic operator, period mean, B2 reduced-Q with the FD trigger, clutch release,
ZOH onboard interpolation, tracker noise).
"""

from __future__ import annotations

import dataclasses
import math
import pathlib
from collections.abc import Mapping

import numpy as np

from telesmooth.arms.air_bearing import (
    planar_joints_to_space_arm,
    planar_pose_to_space_arm,
    space_arm_pose_to_planar,
)
from telesmooth.arms.description import ARMS, ArmDescription
from telesmooth.arms.joint_vectors import as_per_joint, check_joint_vector
from telesmooth.arms.planar import AIR_BEARING_ARM, planar_3r_inverse_kinematics
from telesmooth.arms.workspace import AIR_BEARING_WORKSPACE, SPACE_ARM_WORKSPACE, Workspace
from telesmooth.datasets.haptic_recording import (
    PLANAR_POSE_NAMES,
    SPATIAL_POSE_NAMES,
    HapticRecording,
    read_haptic_csv,
    read_haptic_npz,
)
from telesmooth.datasets.lasa import WorkspaceMapping, validate_demo_index, validate_shape
from telesmooth.datasets.operator_recordings import (
    lasa_haptic_recording,
    synthetic_haptic_recording,
)
from telesmooth.datasets.synthetic import SyntheticOperatorConfig
from telesmooth.lcm_types.channels import DEFAULT_LCM_URL
from telesmooth.link.faults import LinkFaultConfig
from telesmooth.systems.collision_checker import CollisionCheckerConfig
from telesmooth.systems.delay_fifo import DelayFifoConfig
from telesmooth.systems.flexible_arm import DriveConfig, FlexibleArmConfig
from telesmooth.systems.haptic_source import RECORDING_PERIOD_RTOL
from telesmooth.systems.inverse_kinematics import InverseKinematicsConfig
from telesmooth.systems.joint_command_receiver import JointCommandReceiverConfig
from telesmooth.systems.link_guard import LinkGuardConfig
from telesmooth.systems.reduced_q_smoother import ReducedQSmootherConfig
from telesmooth.systems.uplink import UplinkConfig
from telesmooth.typed_yaml import config_from_data, load_yaml_text, merge_data
from telesmooth.user_input import (
    MAX_YAML_BYTES,
    InputFileError,
    quote,
    quote_path,
    read_file_bytes,
    unknown_choice,
)

__all__ = [
    "BUILTIN_SCENARIOS_FILE",
    "CHAINS",
    "HAPTIC_SOURCES",
    "HapticScenario",
    "LinkScenario",
    "PredictorScenario",
    "Scenario",
    "describe_chain",
    "describe_operator",
    "LoadScenario",
    "make_haptic_recording",
]

HAPTIC_SOURCES = ("lasa", "synthetic", "file", "lcm", "console")
LIVE_HAPTIC_SOURCES = ("lcm", "console")
"""The sources of a live operator (no recording): a device over LCM, the browser console."""
BUILTIN_SCENARIOS_FILE = pathlib.Path(__file__).resolve().parent / "scenarios.yaml"


@dataclasses.dataclass(frozen=True)
class HapticScenario:
    """Where the operator's commands come from.

    Attributes:
        source: ``"lasa"`` (a LASA demonstration), ``"synthetic"`` (the synthetic operator),
            ``"file"`` (a CSV or NPZ recording), ``"console"`` (the browser console of
            ``telesmooth teleop``, which sets it), or ``"lcm"`` (a live device publishing on
            TELEOP_HAPTIC_COMMAND; ground process only).
        lasa_shape, lasa_demo: The LASA demonstration.
        lasa_mapping: Its placement in the plane and in time.
        synthetic: The synthetic operator's settings.
        file: Path of the recording (``source = "file"``).
        period_s: Haptic sample period, s.
        live_initial_pose: First pose assumed for a live device before it sends anything;
            planar (x_m, y_m, phi_rad) (lifted for the 6-DOF arm).
        live_duration_s: How long a live session runs, s.

    Planar sessions (LASA, synthetic, 3-axis files) drive the 6-DOF arm in its air-bearing
    plane (:mod:`telesmooth.arms.air_bearing`).
    """

    source: str = "lasa"
    lasa_shape: str = "Angle"
    lasa_demo: int = 0
    lasa_mapping: WorkspaceMapping = dataclasses.field(default_factory=WorkspaceMapping)
    synthetic: SyntheticOperatorConfig = dataclasses.field(
        default_factory=SyntheticOperatorConfig)
    file: str | None = None
    period_s: float = 0.01
    live_initial_pose: tuple[float, float, float] = (0.7, 0.0, 0.0)
    live_duration_s: float = 60.0

    def __post_init__(self) -> None:
        # Every field is checked here, where the loader knows its key path (haptic.<field>),
        # not later where the recording is made and the names are the dataset's.
        if self.source not in HAPTIC_SOURCES:
            raise ValueError(unknown_choice("source", self.source, HAPTIC_SOURCES,
                                            noun="haptic sources"))
        if self.source == "file" and not self.file:
            raise ValueError("file must name a CSV or NPZ recording when source = 'file'")
        validate_shape(self.lasa_shape, field="lasa_shape")
        validate_demo_index(self.lasa_demo, self.lasa_shape, field="lasa_demo")
        for name in ("period_s", "live_duration_s"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f"{name} = {value!r} must be positive and finite")
        pose = self.live_initial_pose
        if len(pose) != 3 or not all(math.isfinite(v) for v in pose):
            raise ValueError(f"live_initial_pose = {quote(pose)} must be 3 finite numbers "
                             "(x_m, y_m, phi_rad)")


CHAINS = ("deployed", "paper")
"""The in-process chains (``Scenario.chain``): ``"deployed"`` puts the onboard packet checks
and link guard between the uplink and the robot, as the onboard process runs them;
``"paper"`` lets the uplink's held command drive the robot directly, as in the paper."""


@dataclasses.dataclass(frozen=True)
class LinkScenario:
    """The ground-to-onboard link of an in-process run (``chain: deployed`` only).

    Attributes:
        faults: Delay, jitter, loss, duplication, reordering and outages of the uplink
            (:class:`~telesmooth.link.faults.LinkFaultConfig`; seeded): the same model, and
            for the same seed the same fate of every packet, as ``telesmooth link-relay``
            between two processes.
        downlink: The same for the robot's telemetry on its way to the ground (read by the
            operator's display and the predicted robot of ``telesmooth teleop``).
    """

    faults: LinkFaultConfig = dataclasses.field(default_factory=LinkFaultConfig)
    downlink: LinkFaultConfig = dataclasses.field(default_factory=LinkFaultConfig)


@dataclasses.dataclass(frozen=True)
class PredictorScenario:
    """The ground's predicted robot (``telesmooth teleop``, the operator's display).

    Attributes:
        period_s: How often the prediction is made and the display redrawn, s (0.04 s =
            25 Hz).
        resync_period_s: How often the predicted robot is re-synchronised from the newest
            telemetry, s; in between it runs on (each re-synchronisation simulates the
            whole horizon again: the downlink's delay and the telemetry's age).
        drive: The ground's model of the robot's drive-train (springs, dampers, servos);
            None: the robot's own (``onboard.drive``: a perfect model). A model that is off
            shows in the prediction's residual.
        residual_warning_m: A measured residual above this (the largest over the last 2 s)
            tells the operator that the prediction is off, m; at least five times the
            tracker's noise is used. With the robot's own model and a clean link the
            residual is the integrators' difference, about a micrometre on Defaults; a
            stiffness 20 % off makes it 0.3 mm there.
    """

    period_s: float = 0.04
    resync_period_s: float = 0.2
    drive: DriveConfig | None = None
    residual_warning_m: float = 1e-4

    def __post_init__(self) -> None:
        for name in ("period_s", "resync_period_s"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0.0):
                raise ValueError(f"{name} = {value!r} must be positive and finite")
        if not (isinstance(self.residual_warning_m, (int, float))
                and math.isfinite(self.residual_warning_m) and self.residual_warning_m > 0.0):
            raise ValueError(f"residual_warning_m = {self.residual_warning_m!r} must be "
                             "positive and finite")


@dataclasses.dataclass(frozen=True)
class Scenario:
    """Every setting of a run.

    Attributes:
        arm: ``"air_bearing_arm"`` (3 joints in a plane) or ``"space_arm"`` (6-DOF).
        chain: ``"deployed"`` (default): in one process every uplink packet goes the way it
            goes between the two processes: formed and encoded by the ground's sender,
            carried by the simulated link (``link``), examined by the onboard receiver and
            passed through the onboard link guard, which keeps what reaches the robot within
            the limits. ``"paper"``: the uplink's held command drives the robot directly
            (the paper's set-up; ``compare`` and ``experiment`` play their commands so).
        haptic: The operator source.
        inverse_kinematics, collision_checker, fifo, smoother, uplink: the ground stages.
        workspace: Obstacles and bounding box; None = the arm's default scenario.
        period_mean: If true the FIFO samples the mean of each period instead of the latest
            IK target (the smoother's r is then divided by the samples per period).
        onboard: The flexible-joint plant (its ``arm`` is set from ``arm``).
        command_receiver: The onboard command receiver (the onboard process, and the
            deployed chain in one process).
        link_guard: The onboard link guard: the FD limits enforced on every command, a
            jerk-limited ramp-down when commands stop, and the converging re-join when they
            resume (same runs as ``command_receiver``; ``telesmooth.safety.guard``).
        link: The simulated link of an in-process run of the deployed chain.
        predictor: The ground's predicted robot (the operator's display).
        lcm_url: LCM URL of the ground/onboard processes.
        publish_offset_s: Delay after each uplink tick at which the packet is published, s.
        settle_s: Extra simulated time after the operator's recording ends, s.
        simulation_duration_s: Simulated time; None = recording length + ``settle_s``.
        initial_position_rad: Start pose of the arm; None = the IK of the first pose.
    """

    arm: str = "air_bearing_arm"
    chain: str = "deployed"
    haptic: HapticScenario = dataclasses.field(default_factory=HapticScenario)
    inverse_kinematics: InverseKinematicsConfig = dataclasses.field(
        default_factory=InverseKinematicsConfig)
    collision_checker: CollisionCheckerConfig = dataclasses.field(
        default_factory=CollisionCheckerConfig)
    workspace: Workspace | None = None
    period_mean: bool = False
    fifo: DelayFifoConfig = dataclasses.field(default_factory=DelayFifoConfig)
    smoother: ReducedQSmootherConfig = dataclasses.field(default_factory=ReducedQSmootherConfig)
    uplink: UplinkConfig = dataclasses.field(default_factory=UplinkConfig)
    onboard: FlexibleArmConfig = dataclasses.field(default_factory=FlexibleArmConfig)
    command_receiver: JointCommandReceiverConfig = dataclasses.field(
        default_factory=JointCommandReceiverConfig)
    link_guard: LinkGuardConfig = dataclasses.field(default_factory=LinkGuardConfig)
    link: LinkScenario = dataclasses.field(default_factory=LinkScenario)
    predictor: PredictorScenario = dataclasses.field(default_factory=PredictorScenario)
    lcm_url: str = DEFAULT_LCM_URL
    publish_offset_s: float = 0.001
    settle_s: float = 3.0
    simulation_duration_s: float | None = None
    initial_position_rad: tuple[float, ...] | None = None

    def __post_init__(self) -> None:
        if self.arm not in ARMS:
            raise ValueError(f"arm = {self.arm!r} must be one of {sorted(ARMS)}")
        if self.chain not in CHAINS:
            raise ValueError(unknown_choice("chain", self.chain, CHAINS, noun="chains"))
        if self.chain == "paper" and self.link.faults.enabled:
            raise ValueError("link.faults need chain: deployed (in the paper's chain the "
                             "uplink drives the robot directly, with no link between them)")
        if self.predictor.drive is not None:
            try:
                _ = self.predictor.drive.apply(ARMS[self.arm])
            except ValueError as error:
                raise ValueError(f"predictor.{error}") from None
        if self.onboard.arm != self.arm:
            object.__setattr__(self, "onboard", dataclasses.replace(self.onboard, arm=self.arm))
        periods = {"fifo.period_s": self.fifo.period_s,
                   "smoother.period_s": self.smoother.period_s,
                   "uplink.period_s": self.uplink.period_s}
        if len(set(periods.values())) != 1:
            raise ValueError(f"the 4 Hz stages must share one period; got {periods}")
        if self.smoother.lag != self.fifo.lag:
            raise ValueError(
                f"smoother.lag = {self.smoother.lag} must equal the FIFO length "
                f"fifo.delay_s/fifo.period_s = {self.fifo.lag}")
        for name in ("settle_s", "publish_offset_s"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f"{name} = {value!r} must be non-negative and finite")
        if not self.publish_offset_s < self.uplink.period_s:
            raise ValueError(
                f"publish_offset_s = {self.publish_offset_s!r} must be below uplink.period_s")
        if self.simulation_duration_s is not None and not (
                math.isfinite(self.simulation_duration_s) and self.simulation_duration_s > 0):
            raise ValueError(
                f"simulation_duration_s = {self.simulation_duration_s!r} must be positive")
        try:
            _ = self.onboard.arm_description  # raises unless the drive's values fit the arm
        except ValueError as error:
            raise ValueError(f"onboard.{error}") from None
        names = self.arm_description.joint_names
        for field in ("sigma", "max_acceleration_rad_per_s2", "max_jerk_rad_per_s3"):
            try:
                as_per_joint(field, getattr(self.smoother, field), len(names), names,
                             allow_inf=field != "sigma")
            except ValueError as error:
                raise ValueError(f"smoother.{error}") from None
        if self.initial_position_rad is not None:
            description = self.arm_description
            check_joint_vector("initial_position_rad", self.initial_position_rad,
                               description.joint_names, lower=description.joint_lower_rad,
                               upper=description.joint_upper_rad)

    @property
    def arm_description(self) -> ArmDescription:
        return ARMS[self.arm]

    @property
    def workspace_or_default(self) -> Workspace:
        if self.workspace is not None:
            return self.workspace
        return AIR_BEARING_WORKSPACE if self.arm == "air_bearing_arm" else SPACE_ARM_WORKSPACE


def describe_operator(scenario: Scenario) -> str:
    """Who operates, for a report: the LASA shape, demonstration and speed, the synthetic
    operator's seed, the recording's file, or a live device."""
    haptic = scenario.haptic
    if haptic.source == "lasa":
        mapping = haptic.lasa_mapping
        speed = WorkspaceMapping().time_scale / mapping.time_scale
        return (f"the LASA demonstration `{haptic.lasa_shape}` #{haptic.lasa_demo} at "
                f"{speed:g}× the demonstrator's hand speed (time_scale {mapping.time_scale:g})")
    if haptic.source == "synthetic":
        return f"the synthetic operator (seed {haptic.synthetic.seed})"
    if haptic.source == "file":
        return f"the recording `{haptic.file}`"
    if haptic.source == "console":
        return "the operator at the browser console"
    return "a live haptic device over LCM"


def describe_chain(scenario: Scenario) -> str:
    """Which chain a run simulated, for the first lines of a report."""
    if scenario.chain == "paper":
        return ("the paper's chain: the uplink's held command drives the robot directly, "
                "with no onboard packet checks and no link guard")
    faults = scenario.link.faults
    link = ("a perfect link" if not faults.enabled
            else f"the seeded link fault model ({faults.describe()})")
    return ("the deployed chain: every uplink packet crosses " + link + ", is examined by "
            "the onboard receiver and passes the onboard link guard, which keeps what reaches "
            "the robot within the limits (as `telesmooth onboard` runs it)")


def make_haptic_recording(scenario: Scenario) -> HapticRecording | None:
    """The operator recording of ``scenario`` in the arm's pose convention (None for a live
    operator: ``lcm``, ``console``).

    Planar recordings are lifted into the 6-DOF arm's air-bearing plane when the arm is
    ``space_arm``.
    """
    haptic = scenario.haptic
    if haptic.source in LIVE_HAPTIC_SOURCES:
        return None
    if haptic.source == "lasa":
        recording = lasa_haptic_recording(haptic.lasa_shape, haptic.lasa_demo,
                                          haptic.lasa_mapping, period_s=haptic.period_s)
    elif haptic.source == "synthetic":
        recording = synthetic_haptic_recording(haptic.synthetic, period_s=haptic.period_s)
    else:
        path = pathlib.Path(haptic.file)
        reader = read_haptic_npz if path.suffix.lower() == ".npz" else read_haptic_csv
        try:
            recording = reader(path)
        except ValueError as error:   # the reader's messages start with the path
            raise ValueError(f"haptic.file: {error}") from None
        # The pose names carry the units: a planar pose, or (for the 6-DOF arm) a spatial one.
        allowed = [PLANAR_POSE_NAMES] + ([SPATIAL_POSE_NAMES] if scenario.arm == "space_arm"
                                         else [])
        if tuple(recording.pose_names) == SPATIAL_POSE_NAMES and scenario.arm != "space_arm":
            raise ValueError(
                f"haptic.file = {quote_path(str(path))}: a 6-DOF pose (x_m … yaw_rad) needs "
                f"arm: space_arm; the arm {scenario.arm!r} reads {list(PLANAR_POSE_NAMES)}")
        if tuple(recording.pose_names) not in allowed:
            raise ValueError(
                f"haptic.file = {quote_path(str(path))}: the pose columns "
                f"{quote(list(recording.pose_names))} "
                f"are not a pose of the arm {scenario.arm!r}; expected "
                + " or ".join(str(list(names)) for names in allowed)
                + " (metres and radians)")
        if abs(recording.period_s - haptic.period_s) > RECORDING_PERIOD_RTOL * haptic.period_s:
            raise ValueError(
                f"haptic.file = {quote_path(str(path))}: its samples are "
                f"{recording.period_s:.6g} s apart ({1.0 / recording.period_s:.6g} Hz, from its "
                f"t column) but haptic.period_s = {haptic.period_s:.6g} s; resample the "
                f"recording or set haptic.period_s: {recording.period_s:.6g}")
    if scenario.arm == "space_arm" and recording.num_pose == 3:
        recording = HapticRecording(
            t_s=recording.t_s, pose=planar_pose_to_space_arm(recording.pose),
            enable=recording.enable, pose_names=SPATIAL_POSE_NAMES)
    return recording


def initial_position(scenario: Scenario, recording: HapticRecording | None) -> np.ndarray:
    """The arm's start pose: the scenario's, else the IK of the first commanded pose."""
    if scenario.initial_position_rad is not None:
        return np.asarray(scenario.initial_position_rad, dtype=float)
    if recording is None:
        planar_pose = np.asarray(scenario.haptic.live_initial_pose, dtype=float)
    elif recording.num_pose == 3:
        planar_pose = recording.pose[0]
    else:
        # A 6-DOF recording: take the air-bearing plane's planar pose if it lies in it.
        planar_pose = space_arm_pose_to_planar(recording.pose[0])
    q, reachable = planar_3r_inverse_kinematics(
        planar_pose[:2], planar_pose[2], AIR_BEARING_ARM,
        elbow=scenario.inverse_kinematics.elbow)
    if not bool(np.all(reachable)):
        raise ValueError(
            f"the first commanded pose {planar_pose.tolist()!r} is not reachable; set "
            "initial_position_rad in the scenario")
    q = np.asarray(q, dtype=float)
    return planar_joints_to_space_arm(q) if scenario.arm == "space_arm" else q


HAPTIC_KEY_SOURCES: dict[str, tuple[str, ...]] = {
    "lasa_shape": ("lasa",),
    "lasa_demo": ("lasa",),
    "lasa_mapping": ("lasa",),
    "synthetic": ("synthetic",),
    "file": ("file",),
    "live_initial_pose": LIVE_HAPTIC_SOURCES,
    "live_duration_s": LIVE_HAPTIC_SOURCES,
}
"""The keys of ``haptic`` that only some sources read → the sources that read them (every
other key of ``haptic`` is read by every source). A new source adds itself to the keys it
reads; :func:`check_ignored_keys` refuses the others under it."""

_CONTINUOUS = (lambda step: step == 0.0, "= 0, the continuous plant")
_DISCRETE = (lambda step: step > 0.0, "> 0, a discrete plant")

_KEYS_READ_ONLY_WHEN: tuple[tuple[str, str | None, object], ...] = (
    # (key path, the setting that decides whether it is read, the setting's values that read
    # it: a tuple of names, or (test, how the message says it)); setting None: no setting
    # of a scenario reads the key (the third entry says what sets it instead).
    *((f"haptic.{key}", "haptic.source", sources)
      for key, sources in HAPTIC_KEY_SOURCES.items()),
    ("haptic.lasa_mapping.haptic_rate_hz", None, "the rate is 1 / haptic.period_s"),
    ("haptic.synthetic.haptic_rate_hz", None, "the rate is 1 / haptic.period_s"),
    ("inverse_kinematics.max_iterations", "arm", ("space_arm",)),   # the planar IK is exact
    ("fifo.max_stop_duration_s", "fifo.on_collision", ("stop",)),
    ("smoother.reduced_q.rho", "smoother.reduced_q.step_rule", ("multiplicative",)),
    ("smoother.reduced_q.delta_sigma", "smoother.reduced_q.step_rule", ("additive",)),
    ("smoother.reduced_q.max_retries", "smoother.reduced_q.variant", ("B1", "B2")),
    ("onboard.arm", None, "the top-level arm sets it"),
    ("onboard.initial_position_rad", None,
     "the robot starts at initial_position_rad, else at the IK of the first pose"),
    ("onboard.integration_scheme", "onboard.time_step_s", _CONTINUOUS),
    ("onboard.integration_accuracy", "onboard.time_step_s", _CONTINUOUS),
    ("onboard.discrete_contact_approximation", "onboard.time_step_s", _DISCRETE),
    ("onboard.interpolator.ramp_duration_s", "onboard.interpolator.interpolation",
     ("linear",)),
    ("onboard.tracker.seed", "onboard.tracker.noise_m",
     (lambda noise: noise > 0.0, "> 0, a noisy tracker")),
)

_SET_ON_THE_COMMAND_LINE = {"fifo.on_collision": "--on-collision",
                            "onboard.time_step_s": "experiment --plant-step"}
"""Settings that a command-line option may still change after the scenario is loaded: a
rule they decide applies only where the scenario writes the setting itself (a key given for
``--on-collision stop`` is not refused because the scenario leaves the default 'hold')."""


def _written(data, path: str):
    """(True, value) if the mapping ``data`` gives the dotted ``path``, else (False, None)."""
    node = data
    for part in path.split("."):
        if not isinstance(node, Mapping) or part not in node:
            return False, None
        node = node[part]
    return True, node


def check_ignored_keys(data: Mapping, scenario: Scenario) -> None:
    """Refuses a key that the scenario's own settings leave unread.

    Some keys are read only under some value of another setting (``haptic.file`` only when
    ``haptic.source = 'file'``, ``onboard.integration_accuracy`` only for the continuous
    plant, ...; the table ``_KEYS_READ_ONLY_WHEN``), and a few never (the top-level ``arm``
    sets ``onboard.arm``). Given anyway, such a key would be silently ignored: the run would
    not be the one the user wrote. Whether a key was *given* can only be seen in ``data``,
    the mapping as the user wrote it (the scenario file's entry with ``--scenario-text``
    merged in, before defaults), since a dataclass cannot tell a default from a value the
    user gave; the deciding setting is read from ``scenario``, built from ``data`` (so
    validated, its default filled in). A key written as null is taken as not given.

    Raises:
        ValueError: naming the key path as written, its value, and the setting that leaves it
            unread with that setting's value, e.g. ``haptic.file = 'my.csv' is only read when
            haptic.source = 'file' (haptic.source is 'lasa', the default)``.
    """
    for key, setting, readers in _KEYS_READ_ONLY_WHEN:
        given, value = _written(data, key)
        if not given or value is None:
            continue
        if setting is None:
            raise ValueError(f"{key} = {quote(value)} is not read in a scenario: {readers}")
        setting_written, _ = _written(data, setting)
        if setting in _SET_ON_THE_COMMAND_LINE and not setting_written:
            continue
        current = scenario
        for part in setting.split("."):
            current = getattr(current, part)
        if isinstance(readers, tuple) and callable(readers[0]):
            test, when = readers
            reads = test(current)
        else:
            reads = current in readers
            when = "= " + " or ".join(repr(name) for name in readers)
        if not reads:
            default = "" if setting_written else ", the default"
            raise ValueError(f"{key} = {quote(value)} is only read when {setting} {when} "
                             f"({setting} is {current!r}{default})")


def LoadScenario(*, filename=None, scenario_name: str | None = None,
                  scenario_text: str | None = None,
                  option_names: Mapping[str, str] | None = None,
                  overrides: Mapping | None = None) -> Scenario:
    """Loads a scenario: file (a mapping of names to scenarios) → named entry → text overrides.

    Args:
        filename: YAML file; default the built-in ``diagrams/scenarios.yaml``.
        scenario_name: Entry to use; default ``"Defaults"``.
        scenario_text: YAML mapping merged on top (e.g. ``"{arm: space_arm}"``).
        option_names: How the caller's user spells ``filename``, ``scenario_name`` and
            ``scenario_text`` (e.g. ``{"filename": "--scenario"}`` on the command line), for
            messages; default the argument names.
        overrides: A mapping merged last, what the caller itself sets (e.g. ``teleop``'s
            live operator: ``{"haptic": {"source": "console"}}``).

    Raises:
        ValueError: the file cannot be read within the bounds of
            :func:`~telesmooth.typed_yaml.load_yaml_text` (a regular UTF-8 file of at
            most ``MAX_YAML_BYTES``), unknown scenario name (listing the known ones), an
            entry that is not a mapping, unknown keys, invalid values; each message names the
            source and the key path as written (``haptic.period_s``) and the value.
    """
    names = {"filename": "scenario file", "scenario_name": "scenario_name",
             "scenario_text": "scenario_text", **(option_names or {})}
    path = pathlib.Path(filename) if filename is not None else BUILTIN_SCENARIOS_FILE
    label = (f"{names['filename']} = {quote_path(str(path))}" if filename is not None
             else "the built-in scenario file")
    raw = read_file_bytes(path, what=label, max_bytes=MAX_YAML_BYTES)
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as error:
        line = 1 + raw.count(b"\n", 0, error.start)
        raise InputFileError(f"{label}: line {line}: byte(s) {raw[error.start:error.end]!r} "
                             "are not valid UTF-8; save the file as UTF-8") from None
    scenarios = load_yaml_text(text, source=label)
    name = scenario_name or "Defaults"
    if name not in scenarios:
        raise ValueError(
            f"{names['scenario_name']} = {quote(name)} is not in {label}; it has "
            f"{quote(sorted(scenarios), 150)}")
    data = scenarios[name]
    if data is None:
        data = {}
    if not isinstance(data, Mapping):
        raise ValueError(f"{label}: the entry {quote(name)} must be a mapping of scenario keys; "
                         f"got {quote(data)}")
    where = f"scenario {quote(name)}"
    if scenario_text:
        data = merge_data(data, load_yaml_text(scenario_text, source=names["scenario_text"]))
        where += f" with {names['scenario_text']}"
    if overrides:
        data = merge_data(data, overrides)
    try:
        scenario = config_from_data(Scenario, data, path="")
        check_ignored_keys(data, scenario)
        return scenario
    except ValueError as error:
        raise ValueError(f"{where}: {error}") from None
