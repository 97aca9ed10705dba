"""Optional pre-filter of the FIFO: the mean of the last period's 100 Hz joint targets.

docs/method.md §5.1, step 1, option: instead of the latest IK sample, the FIFO may take the average
of the M samples of the last uplink period (M = 25 at 100 Hz / 4 Hz). If the hand noise is white
this divides its variance by M (use r/M in the smoother); it adds about (M−1)/2 fast samples
(0.12 s) of delay and attenuates, but does not remove, tremor above the 2 Hz Nyquist rate.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from pydrake.systems.framework import LeafSystem

from telesmooth.arms.joint_vectors import check_finite_per_joint
from telesmooth.systems.timing import check_period, samples_per_period

__all__ = ["PeriodMean", "PeriodMeanConfig"]


@dataclasses.dataclass(frozen=True)
class PeriodMeanConfig:
    """Settings of the period mean.

    Attributes:
        sample_period_s: Period of the input stream, s (0.01 s: the 100 Hz IK targets).
        window_s: Averaging window, s (the uplink period, 0.25 s); a whole number M of samples.
    """

    sample_period_s: float = 0.01
    window_s: float = 0.25

    def __post_init__(self) -> None:
        check_period("PeriodMeanConfig.sample_period_s", self.sample_period_s)
        check_period("PeriodMeanConfig.window_s", self.window_s)
        samples_per_period(self.window_s, self.sample_period_s,
                           slow_field="PeriodMeanConfig.window_s",
                           fast_field="PeriodMeanConfig.sample_period_s")

    @property
    def num_samples(self) -> int:
        """M, samples per window."""
        return samples_per_period(self.window_s, self.sample_period_s,
                                  slow_field="window_s", fast_field="sample_period_s")


class PeriodMean(LeafSystem):
    r"""Moving mean of the last M samples of a joint stream (a ring buffer in discrete state).

    .. pydrake_system::

        name: PeriodMean
        input_ports:
        - q_target
        output_ports:
        - q_mean

    - ``q_target``: joint targets, rad, (J,), sampled every ``sample_period_s``.
    - ``q_mean``: (1/M) Σ_{i<M} q_target(t_{j−i}) over the last M samples taken, rad, (J,).

    Update at t_j = j·sample_period_s: the ring slot j mod M ← q_target(t_j), unless the
    sample is not finite (then the previous sample is repeated, so the mean never turns NaN).
    At t = 0 the ring is filled with ``initial_position_rad``.
    """

    def __init__(self, config: PeriodMeanConfig = PeriodMeanConfig(), *, num_joints: int,
                 initial_position_rad=None):
        super().__init__()
        if not isinstance(num_joints, (int, np.integer)) or num_joints < 1:
            raise ValueError(f"num_joints = {num_joints!r} must be a positive integer")
        n, m = int(num_joints), config.num_samples
        q0 = np.zeros(n) if initial_position_rad is None else check_finite_per_joint(
            "initial_position_rad", initial_position_rad, n)
        self._num_joints, self._num_samples = n, m
        self._q_target_input = self.DeclareVectorInputPort("q_target", n)
        self._ring_state = self.DeclareDiscreteState(np.tile(q0, m))
        self._cursor_state = self.DeclareDiscreteState([0.0])  # [next slot]
        self._last_state = self.DeclareDiscreteState(q0.copy())
        self.DeclarePeriodicDiscreteUpdateEvent(config.sample_period_s, 0.0, self._update_ring)
        # A forced update runs the same tick on demand (CalcForcedDiscreteVariableUpdate).
        self.DeclareForcedDiscreteUpdateEvent(self._update_ring)
        self._q_mean_output = self.DeclareVectorOutputPort("q_mean", n, self._calc_q_mean)

    def get_q_target_input_port(self):
        return self._q_target_input

    def get_q_mean_output_port(self):
        return self._q_mean_output

    def _calc_q_mean(self, context, output):
        ring = context.get_discrete_state(self._ring_state).get_value()
        output.SetFromVector(ring.reshape(self._num_samples, self._num_joints).mean(axis=0))

    def _update_ring(self, context, discrete_state):
        sample = np.asarray(self._q_target_input.Eval(context), dtype=float)
        if not np.all(np.isfinite(sample)):
            sample = context.get_discrete_state(self._last_state).get_value()
        ring = context.get_discrete_state(self._ring_state).get_value().reshape(
            self._num_samples, self._num_joints).copy()
        cursor = int(context.get_discrete_state(self._cursor_state).get_value()[0])
        ring[cursor] = sample
        discrete_state.get_mutable_vector(self._ring_state).SetFromVector(ring.ravel())
        discrete_state.get_mutable_vector(self._cursor_state).SetFromVector(
            [float((cursor + 1) % self._num_samples)])
        discrete_state.get_mutable_vector(self._last_state).SetFromVector(sample)
