"""The onboard measurements: a 100 Hz "laser tracker" of the end effector plus joint encoders.

In the paper's experiment a laser tracker measures the end-effector position of the
flexible arm; this block samples the simulated plant's state at the tracker rate and
reports the tool-frame origin in world coordinates (computed from the link-side positions,
so it includes the joint deflections), and the link-side and motor-side joint angles of a
flexible-joint model (joints ``<name>_motor`` and ``<name>_deflection``, see
:mod:`telesmooth.arms.description`).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from pydrake.systems.framework import LeafSystem

from telesmooth.arms.chain_kinematics import ChainPoint
from telesmooth.arms.tracker import (
    TrackerParams,
    TrackerSample,
    tracker_measurement,
    tracker_noise,
    tracker_step,
)
from telesmooth.systems.codec_state import CodecState
from telesmooth.systems.timing import check_period

__all__ = ["LaserTracker", "LaserTrackerConfig", "TrackerRecord", "tracker_record"]


@dataclasses.dataclass(frozen=True)
class LaserTrackerConfig:
    """Settings of the laser tracker.

    Attributes:
        period_s: Sampling period, s (> 0); 0.01 s = 100 Hz.
        noise_m: Standard deviation of the white Gaussian noise added to each coordinate of
            ``position_measured``, m (≥ 0; 0 = exact). The joint angles are noise-free.
        seed: Seed of the noise (integer ≥ 0). Sample k's noise is drawn from
            ``numpy.random.default_rng([seed, k])``, so it depends only on (seed, k), not
            on how often or in which order contexts are simulated.
    """

    period_s: float = 0.01
    noise_m: float = 0.0
    seed: int = 0

    def __post_init__(self) -> None:
        check_period("LaserTrackerConfig.period_s", self.period_s)
        if not (isinstance(self.noise_m, (int, float)) and math.isfinite(self.noise_m)
                and self.noise_m >= 0.0):
            raise ValueError(
                f"LaserTrackerConfig.noise_m = {self.noise_m!r} must be finite and >= 0 (m)")
        if isinstance(self.seed, bool) or not isinstance(self.seed, (int, np.integer)) \
                or self.seed < 0:
            raise ValueError(f"LaserTrackerConfig.seed = {self.seed!r} must be an integer >= 0")


@dataclasses.dataclass(frozen=True, eq=False)
class TrackerRecord:
    """The laser tracker's samples, each at the instant it was measured (time-major).

    Attributes:
        t_s: t_k, when each sample was taken, s, (T,), strictly increasing.
        tool_position_m: p_WT at t_k, m, (T, 3).
        q_link: Link-side joint angles at t_k, rad, (T, n).
        q_motor: Motor-side joint angles at t_k, rad, (T, n).
    """

    t_s: np.ndarray
    tool_position_m: np.ndarray
    q_link: np.ndarray
    q_motor: np.ndarray


def tracker_record(measurements) -> TrackerRecord:
    """One row per tracker sample from logged ``measurement`` vectors.

    Args:
        measurements: Rows [t_k, p_WT (3), q_link (n), q_motor (n)] as logged, (R, 4 + 2n),
            in logging order. A logger shows a held sample once per publish, and the sample
            taken at initialization and the periodic one at t = 0 share t_k = 0: every
            sample time is kept once (its last row: at t = 0 the periodic sample, taken
            after anything set between initialization and the first step).

    Returns:
        The samples by their own time t_k (not the loggers' time stamps).

    Raises:
        ValueError: if the rows have no room for n ≥ 1 joints or the sample times go back.
    """
    rows = np.atleast_2d(np.asarray(measurements, dtype=float))
    width = rows.shape[1]
    if width < 6 or (width - 4) % 2:
        raise ValueError(f"tracker measurements have {width} columns; expected 4 + 2n, n >= 1")
    n = (width - 4) // 2
    t_s = rows[:, 0]
    if np.any(np.diff(t_s) < 0.0):
        raise ValueError("tracker sample times must not decrease")
    last = np.r_[np.diff(t_s) > 0.0, True] if len(t_s) else np.zeros(0, dtype=bool)
    rows = rows[last]
    return TrackerRecord(t_s=rows[:, 0].copy(), tool_position_m=rows[:, 1:4].copy(),
                         q_link=rows[:, 4:4 + n].copy(), q_motor=rows[:, 4 + n:].copy())


class LaserTracker(LeafSystem):
    r"""Samples a flexible-joint plant's state: end-effector position and joint angles.

    .. pydrake_system::

        name: LaserTracker
        input_ports:
        - plant_state
        output_ports:
        - position_measured
        - q_link
        - q_motor
        - sample_time
        - measurement
        - velocity_measured

    Ports (n = number of joints, joint order = ``joint_names``):

    - ``plant_state``: the whole plant's state [q; v] (``plant.get_state_output_port()``),
      shape (plant.num_multibody_states(),).
    - ``position_measured``: p_WT, the origin of the tool frame in the world frame, m,
      shape (3,), computed by the plant's forward kinematics from all positions (motor +
      deflection), plus noise if ``noise_m`` > 0.
    - ``q_link``: link-side joint angles q_link,i = q_motor,i + q_deflection,i, rad, (n,).
    - ``q_motor``: motor-side joint angles, rad, (n,).
    - ``sample_time``: t_k, the time at which the held sample was taken, s, (1,).
    - ``measurement``: the whole held sample with its time, [t_k, p_WT (3), q_link (n),
      q_motor (n)], (4 + 2n,). **Log this port**, not the others: a logger sampling at t
      runs before the tracker's own update at t (Drake publishes before the discrete
      update of the same instant), so the entry a 100 Hz logger stamps t holds the sample
      taken at t − period; only t_k tells when the sample was measured.
      :func:`tracker_record` turns such a log into one row per sample, by t_k.
    - ``velocity_measured``: the joint velocities of the same sample (the encoders'
      rates), [v_link (n), v_motor (n)], rad/s, (2n,): with the angles, the robot's state at
      t_k, which the telemetry carries for the ground's predicted robot.

    State (one discrete vector, updated at t_k = k·period_s, offset 0, and once at
    initialization): the pure step's :class:`~telesmooth.arms.tracker.TrackerSample`, the
    ``measurement`` vector and the velocities (:func:`~telesmooth.arms.tracker.tracker_step`
    assembles it from the plant's state and the tool point this system computes by Drake's
    forward kinematics); every output is a part of it
    (zero-order hold, no feedthrough). Sample k's noise is
    σ·N(0, I₃) drawn from ``default_rng([seed, k])``, k = round(t_k/period_s).

    Before the first sample (a context that was never initialized by a Simulator) the
    state is the sample of the plant's *default* positions at t = 0; an initialization
    event re-samples the actual initial state when the simulation starts.

    Forward kinematics uses a scratch plant context kept on ``self``; its positions are
    overwritten before every use and its velocities never read, so it carries no state.
    """

    def __init__(
        self,
        config: LaserTrackerConfig = LaserTrackerConfig(),
        *,
        plant,
        model_instance,
        joint_names,
        tool_frame_name: str = "tool",
    ):
        """Looks up the joints and the tool frame; declares ports, state and events.

        Args:
            config: Sampling settings.
            plant: The finalized MultibodyPlant holding the flexible arm.
            model_instance: The arm's model instance in ``plant``.
            joint_names: Joint names, base to tip; joint ``name`` must exist in the plant as
                ``name + "_motor"`` and ``name + "_deflection"``.
            tool_frame_name: Name of the tool frame in ``model_instance``.

        Raises:
            ValueError: if the plant is not finalized or a joint / the frame is missing.
        """
        super().__init__()
        if not isinstance(config, LaserTrackerConfig):
            raise ValueError(f"config = {config!r} must be a LaserTrackerConfig")
        if not plant.is_finalized():
            raise ValueError("plant must be finalized before building a LaserTracker")
        names = tuple(joint_names)
        if not names:
            raise ValueError(f"joint_names = {joint_names!r} must not be empty")
        motor_index, deflection_index = [], []
        motor_velocity, deflection_velocity = [], []
        for name in names:
            for suffix, indices, velocities in (
                    ("_motor", motor_index, motor_velocity),
                    ("_deflection", deflection_index, deflection_velocity)):
                if not plant.HasJointNamed(name + suffix, model_instance):
                    raise ValueError(
                        f"joint_names: the plant has no joint {name + suffix!r} in model "
                        f"instance {plant.GetModelInstanceName(model_instance)!r}"
                    )
                joint = plant.GetJointByName(name + suffix, model_instance)
                indices.append(joint.position_start())
                velocities.append(plant.num_positions() + joint.velocity_start())
        if not plant.HasFrameNamed(tool_frame_name, model_instance):
            raise ValueError(f"tool_frame_name = {tool_frame_name!r}: no such frame in the plant")
        self._config = config
        self._plant = plant
        self._joint_names = names
        self._params = TrackerParams(
            period_s=config.period_s, noise_m=config.noise_m, seed=config.seed,
            num_positions=plant.num_positions(), motor_index=np.array(motor_index),
            deflection_index=np.array(deflection_index),
            motor_velocity_index=np.array(motor_velocity),
            deflection_velocity_index=np.array(deflection_velocity))
        self._tool_frame = plant.GetFrameByName(tool_frame_name, model_instance)
        self._world_frame = plant.world_frame()
        self._tool_origin = np.zeros((3, 1))
        self._plant_context = plant.CreateDefaultContext()
        try:   # Record's forward kinematics, all samples at once (None: Drake's, one by one)
            self._tool_chain = ChainPoint(plant, self._tool_frame)
        except ValueError:
            self._tool_chain = None

        self._plant_state_input = self.DeclareVectorInputPort(
            "plant_state", plant.num_multibody_states())

        # One state vector per sample, [t_k, p_WT (3), q_link (n), q_motor (n), v (2n)]:
        # whatever reads or logs it gets the instant the sample was taken with the sample.
        n = len(names)
        default = plant.GetPositionsAndVelocities(self._plant_context)
        initial = TrackerSample(
            measurement=tracker_measurement(self._params, default, 0.0,
                                            self._tool_position(default)),
            velocity=np.zeros(2 * n))
        self._state = CodecState(self, initial)
        self.DeclareInitializationDiscreteUpdateEvent(self._update_sample)
        self.DeclarePeriodicDiscreteUpdateEvent(config.period_s, 0.0, self._update_sample)

        self._measurement_output = self._state.output("measurement", "measurement")
        measurement = self._state.codec.field_slice("measurement")
        parts = {"position_measured": slice(1, 4), "q_link": slice(4, 4 + n),
                 "q_motor": slice(4 + n, 4 + 2 * n), "sample_time": slice(0, 1)}
        ports = {name: self._state.output(name, slice(measurement.start + part.start,
                                                      measurement.start + part.stop))
                 for name, part in parts.items()}
        self._position_output = ports["position_measured"]
        self._q_link_output = ports["q_link"]
        self._q_motor_output = ports["q_motor"]
        self._sample_time_output = ports["sample_time"]
        self._velocity_output = self._state.output("velocity_measured", "velocity")

    # -- accessors ------------------------------------------------------------------------

    @property
    def config(self) -> LaserTrackerConfig:
        return self._config

    @property
    def joint_names(self) -> tuple[str, ...]:
        return self._joint_names

    def get_plant_state_input_port(self):
        return self._plant_state_input

    def get_position_measured_output_port(self):
        return self._position_output

    def get_q_link_output_port(self):
        return self._q_link_output

    def get_q_motor_output_port(self):
        return self._q_motor_output

    def get_sample_time_output_port(self):
        return self._sample_time_output

    def get_measurement_output_port(self):
        return self._measurement_output

    def get_velocity_measured_output_port(self):
        return self._velocity_output

    def Record(self, times_s, plant_states) -> TrackerRecord:
        """The samples the tracker takes of given plant states at given instants.

        The same computation as the periodic event (forward kinematics of the positions,
        link and motor angles, sample k's noise from ``(seed, k)``), for states obtained
        otherwise, e.g. a playback's integrator's dense output evaluated at t_k = k·period
        (:func:`~telesmooth.diagrams.offline_playback.simulate_playback`). The forward
        kinematics runs over all samples at once (``ChainPoint`` of
        :mod:`telesmooth.arms.chain_kinematics`, the plant's chain of fixed poses and joint
        rotations; about 1.6 µs a sample against 7 µs through Drake's bindings): it equals
        the event's, Drake's, to rounding (about 2e-16 m), not to the bit.

        Args:
            times_s: The sample instants t_k, s, (T,), strictly increasing.
            plant_states: The plant's [q; v] at each instant, (T, plant.num_multibody_states()).

        Raises:
            ValueError: if the shapes do not match or the instants do not increase.
        """
        times = np.asarray(times_s, dtype=float).reshape(-1)
        states = np.asarray(plant_states, dtype=float)
        params = self._params
        width = self._plant_state_input.size()
        if states.ndim != 2 or states.shape != (times.size, width):
            raise ValueError(f"plant_states has shape {states.shape}; expected "
                             f"({times.size}, {width})")
        if np.any(np.diff(times) <= 0.0):
            raise ValueError("times_s must be strictly increasing")
        positions = states[:, : params.num_positions]
        q_motor = positions[:, params.motor_index]
        if self._tool_chain is not None:
            tool = self._tool_chain.positions(positions)
        else:
            tool = np.array([self._tool_position(row) for row in positions]).reshape(-1, 3)
        if params.noise_m > 0.0:
            tool += np.array([tracker_noise(params, float(t)) for t in times]).reshape(-1, 3)
        return TrackerRecord(t_s=times.copy(), tool_position_m=tool,
                             q_link=q_motor + positions[:, params.deflection_index],
                             q_motor=q_motor)

    def Sample(self, context) -> None:
        """Takes a sample of ``plant_state`` now, as the periodic event would, into ``context``.

        Use after changing the plant's state in a context by hand (e.g. initial positions).
        """
        self._update_sample(context, context.get_mutable_discrete_state())

    # -- callbacks ------------------------------------------------------------------------

    def _tool_position(self, plant_state) -> np.ndarray:
        """p_WT of the plant's positions, m, (3,). The tool point depends on the positions
        only (the scratch context's velocities are never read)."""
        self._plant.SetPositions(self._plant_context,
                                 np.asarray(plant_state)[: self._params.num_positions])
        return self._plant.CalcPointsPositions(
            self._plant_context, self._tool_frame, self._tool_origin, self._world_frame)[:, 0]

    def _update_sample(self, context, discrete_state) -> None:
        state = self._plant_state_input.Eval(context)
        self._state.store(discrete_state, tracker_step(
            self._params, state, context.get_time(), self._tool_position(state)))
