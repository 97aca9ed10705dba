"""A recorded operator session as joint samples at the uplink rate: what the FIFO would read.

The recording (``make_haptic_recording``) runs through the ground station's own operator stages
(haptic source → inverse kinematics at the haptic rate → the period mean when
``scenario.period_mean``), and one joint sample is taken per uplink tick t_k = k·Δt. Offline
planning (:mod:`~telesmooth.diagrams.offline_planning`) smooths these samples, and the method
comparison (:mod:`~telesmooth.studies.comparison`) gives them to every method.

Sampling convention. The sampling diagram logs the IK target at the uplink period; a logger
row at t_k shows the state before the updates at t_k (Drake's publish-before-update order), which
is exactly what the online chain's FIFO samples at t_k. So row k equals the online chain's z_k,
and the offline and online smoothers see the same data.
"""

from __future__ import annotations

import math

import numpy as np
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import LogVectorOutput

from telesmooth.diagrams.scenario import Scenario, initial_position, make_haptic_recording
from telesmooth.diagrams.teleoperation import AddOperatorTargets

__all__ = ["joint_targets_at_uplink_rate", "recording_ticks"]

# Added to t / Δt before flooring, so that a tick time computed as k·Δt selects row k.
_TICK_INDEX_EPSILON = 1e-9


def recording_ticks(scenario: Scenario, recording) -> int:
    """Uplink ticks that cover a recording: ceil((T_rec + p_haptic) / Δt) + 1, so the last one
    samples the IK target of the recording's last pose."""
    duration = float(recording.t_s[-1] - recording.t_s[0])
    return math.ceil((duration + scenario.haptic.period_s) / scenario.uplink.period_s
                     - _TICK_INDEX_EPSILON) + 1


def joint_targets_at_uplink_rate(scenario: Scenario, *, num_ticks: int | None = None):
    """Runs the scenario's recording through the ground station's IK; one sample per tick.

    Builds the ground station's operator stages (``AddOperatorTargets``: haptic source → IK →
    period mean when ``scenario.period_mean``)
    and logs the stream the FIFO would read at the uplink period, so row k is the FIFO's z_k.

    Args:
        scenario: Its recording, IK settings, arm, start pose and periods are used.
        num_ticks: N, samples to produce; default enough to include the IK target of the
            recording's last pose: ceil((T_rec + p_haptic) / Δt) + 1.

    Returns:
        (t_s (N,), z (N, J) rad, q_start (J,) rad, ik_failures): the tick times, the samples,
        the robot's start pose (the IK's initial target) and the number of haptic samples whose
        command the IK rejected.

    Raises:
        ValueError: If the scenario has no recording (``haptic.source = 'lcm'``) or
            ``num_ticks`` < 2.
    """
    recording = make_haptic_recording(scenario)
    if recording is None:
        raise ValueError("offline planning needs a recorded session; haptic.source = 'lcm' "
                         "is a live device")
    q0 = initial_position(scenario, recording)
    haptic_period = scenario.haptic.period_s
    tick = scenario.uplink.period_s
    if num_ticks is None:
        num_ticks = recording_ticks(scenario, recording)
    if isinstance(num_ticks, bool) or not isinstance(num_ticks, (int, np.integer)) \
            or num_ticks < 2:
        raise ValueError(f"num_ticks = {num_ticks!r} must be an integer >= 2")

    builder = DiagramBuilder()
    operator = AddOperatorTargets(builder, scenario, recording=recording,
                                  initial_position_rad=q0)
    ik, sampled = operator.inverse_kinematics, operator.q_sampled
    samples_log = LogVectorOutput(sampled, builder, tick)
    failed_log = LogVectorOutput(ik.get_ik_failed_output_port(), builder, haptic_period)
    diagram = builder.Build()
    diagram.set_name("offline_inverse_kinematics")
    simulator = Simulator(diagram)
    end = (num_ticks - 1) * tick
    simulator.AdvanceTo(end)
    context = simulator.get_context()
    log = samples_log.FindLog(context)
    times, values = log.sample_times(), log.data().T
    # One row per tick: k·Δt (the first tick may be logged twice: initialization + period).
    t_s = tick * np.arange(num_ticks)
    rows = np.searchsorted(times, t_s - 1e-9 * tick, side="left")
    if rows[-1] >= times.size or not np.allclose(times[rows], t_s, rtol=0.0, atol=1e-9):
        raise RuntimeError(  # an internal invariant of Drake's logging, not user input
            f"the tick logger did not sample at k·{tick} s: {times[:5]}…")
    z = values[rows]
    # One logger row per haptic update (each shows the flag of the update before it).
    ik_failures = int(np.count_nonzero(failed_log.FindLog(context).data()[0] > 0.5))
    return t_s, z, q0, ik_failures
