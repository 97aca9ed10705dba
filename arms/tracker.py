"""The onboard measurement of one instant as a pure step: what the laser tracker and the joint
encoders report of a flexible-joint plant's state.

:class:`~telesmooth.systems.laser_tracker.LaserTracker` is the thin Drake system around
:func:`tracker_step`: it computes the tool point by the plant's forward kinematics (Drake's)
and hands it in with the state and the instant; the step assembles the sample. Sample k's
noise is σ·N(0, I₃) drawn from ``numpy.random.default_rng([seed, k])``, k = round(t_k/period),
so it depends only on (seed, k). A flexible joint ``name`` is the plant's joints
``name_motor`` and ``name_deflection``; the link angle is their sum.
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import numpy as np

__all__ = ["TrackerParams", "TrackerSample", "tracker_measurement", "tracker_noise",
           "tracker_step"]


@dataclasses.dataclass(frozen=True, eq=False)
class TrackerParams:
    """Where the joints are in the plant's state, and the noise.

    Attributes:
        period_s: The sampling period, s (k = round(t_k/period_s)).
        noise_m: σ of the tool point's noise per coordinate, m (0: exact).
        seed: The noise's seed.
        num_positions: The plant's number of positions (the state is [q; v]).
        motor_index, deflection_index: Each joint's motor and deflection position in q, (n,).
        motor_velocity_index, deflection_velocity_index: Their velocities in [q; v], (n,).
    """

    period_s: float
    noise_m: float
    seed: int
    num_positions: int
    motor_index: np.ndarray
    deflection_index: np.ndarray
    motor_velocity_index: np.ndarray
    deflection_velocity_index: np.ndarray


class TrackerSample(NamedTuple):
    """One sample, held until the next."""

    measurement: np.ndarray   # [t_k, p_WT (3), q_link (n), q_motor (n)]
    velocity: np.ndarray      # [v_link (n), v_motor (n)], rad/s


def tracker_noise(params: TrackerParams, time_s: float) -> np.ndarray:
    """Sample k's noise, k = round(t_k/period): σ·N(0, I₃) from ``default_rng([seed, k])``."""
    k = int(round(time_s / params.period_s))
    rng = np.random.default_rng([params.seed, k])
    return params.noise_m * rng.standard_normal(3)


def tracker_measurement(params: TrackerParams, plant_state, time_s: float,
                        tool_position) -> np.ndarray:
    """The measurement [t_k, p_WT (3), q_link (n), q_motor (n)] of ``plant_state`` ([q; v]) at
    ``time_s``, the tool point ``tool_position`` (3,) being p_WT of its positions."""
    n = params.motor_index.size
    positions = np.asarray(plant_state)[: params.num_positions]
    sample = np.empty(4 + 2 * n)
    sample[0] = time_s
    q_motor = sample[4 + n:]
    q_motor[:] = positions[params.motor_index]
    np.add(q_motor, positions[params.deflection_index], out=sample[4:4 + n])   # q_link
    sample[1:4] = tool_position
    if params.noise_m > 0.0:
        sample[1:4] += tracker_noise(params, time_s)
    return sample


def tracker_step(params: TrackerParams, plant_state, time_s: float,
                 tool_position) -> TrackerSample:
    """The sample taken of ``plant_state`` ([q; v]) at ``time_s`` (it replaces the one held:
    a sample does not depend on the previous): :func:`tracker_measurement` and the joints'
    velocities."""
    state = np.asarray(plant_state)
    v_motor = state[params.motor_velocity_index]
    return TrackerSample(
        measurement=tracker_measurement(params, state, time_s, tool_position),
        velocity=np.concatenate([v_motor + state[params.deflection_velocity_index], v_motor]))
