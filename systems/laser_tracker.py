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

from telesmooth.systems.timing import check_period

__all__ = ["LaserTracker", "LaserTrackerConfig"]


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

    Ports (n = number of joints, joint order = ``joint_names``):

    - ``plant_state``: the whole plant's state [q; v] (``plant.get_state_output_port()``),
      shape (plant.num_multibody_states(),).
    - ``position_measured``: p_WT, the origin of the tool frame in the world frame, m,
      shape (3,), computed by the plant's forward kinematics from all positions (motor +
      deflection), plus noise if ``noise_m`` > 0.
    - ``q_link``: link-side joint angles q_link,i = q_motor,i + q_deflection,i, rad, (n,).
    - ``q_motor``: motor-side joint angles, rad, (n,).
    - ``sample_time``: t_k, the time at which the held sample was taken, s, (1,).

    State (discrete, updated at t_k = k·period_s, offset 0, and once at initialization):
    the outputs themselves, [p_WT (3), q_link (n), q_motor (n), t_k (1)]; the outputs are
    those state values (zero-order hold, no feedthrough). Sample k's noise is
    σ·N(0, I₃) drawn from ``default_rng([seed, k])``, k = round(t_k/period_s).

    Before the first sample (a context that was never initialized by a Simulator) the
    state is the sample of the plant's *default* positions at t = 0; an initialization
    event re-samples the actual initial state when the simulation starts.

    Forward kinematics uses a scratch plant context kept on ``self``; it is fully
    overwritten (positions and velocities) before every use, so it carries no state.
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
        for name in names:
            for suffix, indices in (("_motor", motor_index), ("_deflection", deflection_index)):
                if not plant.HasJointNamed(name + suffix, model_instance):
                    raise ValueError(
                        f"joint_names: the plant has no joint {name + suffix!r} in model "
                        f"instance {plant.GetModelInstanceName(model_instance)!r}"
                    )
                indices.append(plant.GetJointByName(name + suffix, model_instance)
                               .position_start())
        if not plant.HasFrameNamed(tool_frame_name, model_instance):
            raise ValueError(f"tool_frame_name = {tool_frame_name!r}: no such frame in the plant")
        self._config = config
        self._plant = plant
        self._joint_names = names
        self._num_positions = plant.num_positions()
        self._motor_index = np.array(motor_index)
        self._deflection_index = np.array(deflection_index)
        self._tool_frame = plant.GetFrameByName(tool_frame_name, model_instance)
        self._plant_context = plant.CreateDefaultContext()

        self._plant_state_input = self.DeclareVectorInputPort(
            "plant_state", plant.num_multibody_states())

        default_sample = self._sample(
            plant.GetPositionsAndVelocities(self._plant_context), 0.0)
        self._position_state = self.DeclareDiscreteState(default_sample[0])
        self._q_link_state = self.DeclareDiscreteState(default_sample[1])
        self._q_motor_state = self.DeclareDiscreteState(default_sample[2])
        self._sample_time_state = self.DeclareDiscreteState(np.zeros(1))
        self.DeclareInitializationDiscreteUpdateEvent(self._update_sample)
        self.DeclarePeriodicDiscreteUpdateEvent(config.period_s, 0.0, self._update_sample)

        self._position_output = self.DeclareStateOutputPort(
            "position_measured", self._position_state)
        self._q_link_output = self.DeclareStateOutputPort("q_link", self._q_link_state)
        self._q_motor_output = self.DeclareStateOutputPort("q_motor", self._q_motor_state)
        self._sample_time_output = self.DeclareStateOutputPort(
            "sample_time", self._sample_time_state)

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

    def Sample(self, context) -> None:
        """Takes a sample of ``plant_state`` now, as the periodic event would, into ``context``.

        Use after changing the plant's state in a context by hand (e.g. initial positions).
        """
        self._update_sample(context, context.get_mutable_discrete_state())

    # -- callbacks ------------------------------------------------------------------------

    def _sample(self, plant_state, time_s):
        """(p_WT (3,), q_link (n,), q_motor (n,)) of a plant state at ``time_s``."""
        positions = np.asarray(plant_state)[: self._num_positions]
        q_motor = positions[self._motor_index]
        q_link = q_motor + positions[self._deflection_index]
        self._plant.SetPositionsAndVelocities(self._plant_context, plant_state)
        position = self._plant.CalcPointsPositions(
            self._plant_context, self._tool_frame, np.zeros((3, 1)),
            self._plant.world_frame())[:, 0]
        if self._config.noise_m > 0.0:
            k = int(round(time_s / self._config.period_s))
            rng = np.random.default_rng([self._config.seed, k])
            position = position + self._config.noise_m * rng.standard_normal(3)
        return position, q_link, q_motor

    def _update_sample(self, context, discrete_state) -> None:
        position, q_link, q_motor = self._sample(
            self._plant_state_input.Eval(context), context.get_time())
        discrete_state.get_mutable_vector(self._position_state).SetFromVector(position)
        discrete_state.get_mutable_vector(self._q_link_state).SetFromVector(q_link)
        discrete_state.get_mutable_vector(self._q_motor_state).SetFromVector(q_motor)
        discrete_state.get_mutable_vector(self._sample_time_state).SetFromVector(
            [context.get_time()])
