"""Optional pre-filter of the FIFO: the mean of the last period's 100 Hz joint targets.

docs/method.md §5.1, step 1, option: instead of the latest IK sample, the FIFO may take the average
of the M samples of the last uplink period (M = 25 at 100 Hz / 4 Hz). If the hand noise is white
this divides its variance by M (use r/M in the smoother); it adds about (M−1)/2 fast samples
(0.12 s) of delay and attenuates, but does not remove, tremor above the 2 Hz Nyquist rate.
A thin Drake system around the pure step :func:`telesmooth.smoothing.period_mean.period_mean_step`.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from pydrake.systems.framework import LeafSystem

from telesmooth.arms.joint_vectors import check_finite_per_joint
from telesmooth.smoothing.period_mean import (
    PeriodMeanState,
    period_mean,
    period_mean_initial_state,
    period_mean_step,
)
from telesmooth.systems.codec_state import CodecState
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
        self._q_target_input = self.DeclareVectorInputPort("q_target", n)
        initial = period_mean_initial_state(m, q0)
        self._state = CodecState(self, initial)
        self.DeclarePeriodicDiscreteUpdateEvent(config.sample_period_s, 0.0, self._update_ring)
        # A forced update runs the same tick on demand (CalcForcedDiscreteVariableUpdate).
        self.DeclareForcedDiscreteUpdateEvent(self._update_ring)
        self._q_mean_output = self.DeclareVectorOutputPort("q_mean", n, self._calc_q_mean)

    def get_q_target_input_port(self):
        return self._q_target_input

    def get_q_mean_output_port(self):
        return self._q_mean_output

    def period_mean_state(self, context) -> PeriodMeanState:
        """The ring in ``context``."""
        return self._state.get(context)

    def _calc_q_mean(self, context, output):
        output.SetFromVector(period_mean(self.period_mean_state(context)))

    def _update_ring(self, context, discrete_state):
        state = period_mean_step(self.period_mean_state(context),
                                 self._q_target_input.Eval(context))
        self._state.store(discrete_state, state)
