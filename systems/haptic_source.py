"""The operator's haptic device: replays a recording of Cartesian pose commands and the clutch.

This is the first block of the teleoperation chain, on the ground side: it stands in for the
haptic master device sampled at its own rate (100 Hz by default) and feeds the desired
end-effector pose and the enable (clutch) flag to the inverse kinematics and, through it, to
the 4 Hz uplink. The recording comes from a LASA handwriting demonstration, the synthetic
operator model, or a CSV/NPZ file (:mod:`telesmooth.datasets.haptic_recording`).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from pydrake.systems.framework import EventStatus, LeafSystem

from telesmooth.datasets.haptic_recording import HapticRecording
from telesmooth.datasets.lasa import WorkspaceMapping
from telesmooth.datasets.operator_recordings import (
    lasa_haptic_recording,
    synthetic_haptic_recording,
)
from telesmooth.datasets.synthetic import SyntheticOperatorConfig

__all__ = ["HapticSource", "HapticSourceConfig"]

# Relative tolerance on recording period == config.period_s.
RECORDING_PERIOD_RTOL = 1e-9
# Added to t / period before flooring, so that a sample time computed by the simulator as
# k * period (which can land a few ulps below k when divided by period again) selects
# sample k, not k - 1.
_SAMPLE_INDEX_EPSILON = 1e-9


@dataclasses.dataclass(frozen=True)
class HapticSourceConfig:
    """Configuration of :class:`HapticSource`.

    Attributes:
        period_s: Sample period of the haptic device, s (> 0); the recording's period must
            equal it (relative 1e-9). 0.01 s is the 100 Hz haptic rate.

    Raises:
        ValueError: If ``period_s`` is not finite and positive (the message gives the value).
    """

    period_s: float = 0.01

    def __post_init__(self) -> None:
        if (isinstance(self.period_s, bool) or not isinstance(self.period_s, (int, float))
                or not math.isfinite(self.period_s) or self.period_s <= 0.0):
            raise ValueError(f"period_s = {self.period_s!r} must be finite and > 0")


class HapticSource(LeafSystem):
    """Replays a :class:`HapticRecording` as a sampled, piecewise-constant pose command.

    .. pydrake_system::

        name: HapticSource
        output_ports:
        - pose_desired
        - enable

    Ports (no inputs):

    * ``pose_desired``: the commanded Cartesian pose, shape (m,), entries named and united by
      :attr:`pose_names` (planar arm: x_m, y_m in m and phi_rad in rad).
    * ``enable``: the clutch, shape (1,): 1.0 while the operator commands the robot, 0.0
      while the clutch is released.

    Output equations (p = ``config.period_s``, K = number of samples):

        j(t) = clamp(floor(t / p + 1e-9), 0, K - 1)
        pose_desired(t) = recording.pose[j(t)]
        enable(t) = 1.0 if recording.enable[j(t)] else 0.0

    So sample j is held over [j p, (j + 1) p) (zero-order hold on the recording, sample
    time p, offset 0); the 1e-9 makes t = j p computed in floating point select sample j.
    At t = 0 (and any t < p) the outputs are sample 0 -- there is no "before the first
    sample". From t = (K - 1) p on, the outputs hold the last sample (pose and enable): the
    operator keeps the hand still. Times before 0 give sample 0.

    The recording is replayed from its first sample at simulation time 0; its own time
    stamps only fix the period (a recording with t_s[0] != 0 is shifted to start at 0).

    The system is stateless: outputs depend on the context's time only (they are cached
    on the time ticket). It declares a no-op periodic publish event at (p, offset 0) so
    that variable-step integrators downstream stop at every sample boundary instead of
    stepping across the output's discontinuities.
    """

    def __init__(
        self, recording: HapticRecording, config: HapticSourceConfig = HapticSourceConfig()
    ) -> None:
        """Declares the two output ports for ``recording``.

        Args:
            recording: The commands to replay; its period must equal ``config.period_s``.
            config: The sample period.

        Raises:
            ValueError: If ``recording`` is not a :class:`HapticRecording` or its period
                differs from ``config.period_s`` by more than 1e-9 relative (the message
                gives both values).
        """
        super().__init__()
        if not isinstance(recording, HapticRecording):
            raise ValueError(
                f"recording = {type(recording).__name__} object; expected a HapticRecording"
            )
        if not isinstance(config, HapticSourceConfig):
            raise ValueError(
                f"config = {config!r}; expected a HapticSourceConfig"
            )
        period_s = config.period_s
        if abs(recording.period_s - period_s) > RECORDING_PERIOD_RTOL * period_s:
            raise ValueError(
                f"recording period_s = {recording.period_s!r} (from its t_s) differs from "
                f"config.period_s = {period_s!r} by more than {RECORDING_PERIOD_RTOL:g} relative; "
                "resample the recording or set HapticSourceConfig(period_s=...) to match"
            )
        self._recording = recording
        self._period_s = period_s
        # Read-only arrays of an immutable record: constants, not simulation state.
        self._pose = recording.pose
        self._enable = np.where(recording.enable, 1.0, 0.0)

        time_only = {self.time_ticket()}
        self._pose_desired_output = self.DeclareVectorOutputPort(
            "pose_desired", recording.num_pose, self._calc_pose_desired,
            prerequisites_of_calc=time_only,
        )
        self._enable_output = self.DeclareVectorOutputPort(
            "enable", 1, self._calc_enable, prerequisites_of_calc=time_only,
        )
        self.DeclarePeriodicPublishEvent(period_s, 0.0, self._mark_sample_boundary)

    @classmethod
    def from_lasa(
        cls,
        shape: str,
        demo_index: int,
        mapping: WorkspaceMapping = WorkspaceMapping(),
        config: HapticSourceConfig | None = None,
    ) -> HapticSource:
        """A source replaying a LASA demonstration placed by ``mapping`` (planar pose).

        Args:
            shape: LASA shape name.
            demo_index: LASA demonstration index, 0..6.
            mapping: Placement in space and time; its ``haptic_rate_hz`` sets the samples.
            config: Defaults to ``period_s = 1 / mapping.haptic_rate_hz``.

        Raises:
            ValueError: As :func:`~telesmooth.datasets.lasa.lasa_operator_session` and
                :class:`HapticSource`.
        """
        recording = lasa_haptic_recording(shape, demo_index, mapping)
        if config is None:
            config = HapticSourceConfig(period_s=1.0 / mapping.haptic_rate_hz)
        return cls(recording, config)

    @classmethod
    def from_synthetic(
        cls,
        config: SyntheticOperatorConfig = SyntheticOperatorConfig(),
        *,
        source_config: HapticSourceConfig | None = None,
    ) -> HapticSource:
        """A source replaying a synthetic operator session (planar pose).

        Args:
            config: The synthetic operator model and seed.
            source_config: The source's configuration; defaults to
                ``period_s = 1 / config.haptic_rate_hz``.

        Raises:
            ValueError: If ``config`` is not a SyntheticOperatorConfig, or as
                :func:`~telesmooth.datasets.synthetic.synthetic_operator_session` and
                :class:`HapticSource`.
        """
        recording = synthetic_haptic_recording(config)
        if source_config is None:
            source_config = HapticSourceConfig(period_s=1.0 / config.haptic_rate_hz)
        return cls(recording, source_config)

    @property
    def pose_names(self) -> tuple[str, ...]:
        """Names (with units) of the ``pose_desired`` entries, shape (m,)."""
        return self._recording.pose_names

    @property
    def recording(self) -> HapticRecording:
        """The recording being replayed (immutable)."""
        return self._recording

    def get_pose_desired_output_port(self):
        """Returns the ``pose_desired`` output port (shape (m,), units per ``pose_names``)."""
        return self._pose_desired_output

    def get_enable_output_port(self):
        """Returns the ``enable`` output port (shape (1,), 1.0 engaged / 0.0 released)."""
        return self._enable_output

    def _sample_index(self, context) -> int:
        """j(t) = clamp(floor(t / period + 1e-9), 0, K - 1)."""
        j = math.floor(context.get_time() / self._period_s + _SAMPLE_INDEX_EPSILON)
        return min(max(j, 0), self._pose.shape[0] - 1)

    def _calc_pose_desired(self, context, output) -> None:
        output.SetFromVector(self._pose[self._sample_index(context)])

    def _calc_enable(self, context, output) -> None:
        output.SetAtIndex(0, self._enable[self._sample_index(context)])

    def _mark_sample_boundary(self, context) -> EventStatus:
        # Exists only so the simulator steps to every sample time (see class docstring).
        return EventStatus.DidNothing()
