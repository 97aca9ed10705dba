"""Haptic recordings of the built-in operator sessions: LASA demonstrations, the synthetic one.

Both the haptic source system (:meth:`telesmooth.systems.haptic_source.HapticSource.from_lasa`,
``from_synthetic``) and the scenario (:func:`telesmooth.diagrams.scenario.make_haptic_recording`)
replay these sessions; they build the recording here, so the two cannot drift apart. The pose is
planar, (x, y, phi) named :data:`~telesmooth.datasets.haptic_recording.PLANAR_POSE_NAMES`, and
the clutch is engaged throughout (:meth:`HapticRecording.from_operator_session`).
"""

from __future__ import annotations

import dataclasses

from telesmooth.datasets.haptic_recording import HapticRecording
from telesmooth.datasets.lasa import WorkspaceMapping, lasa_operator_session
from telesmooth.datasets.synthetic import SyntheticOperatorConfig, synthetic_operator_session

__all__ = ["lasa_haptic_recording", "synthetic_haptic_recording"]


def lasa_haptic_recording(shape: str, demo_index: int,
                          mapping: WorkspaceMapping = WorkspaceMapping(), *,
                          period_s: float | None = None) -> HapticRecording:
    """The haptic recording of a LASA demonstration placed by ``mapping``.

    Args:
        shape: LASA shape name.
        demo_index: LASA demonstration index, 0..6.
        mapping: Placement in space and time.
        period_s: Sample period, s; None keeps ``mapping.haptic_rate_hz``, else the mapping's
            rate is replaced by 1 / period_s.

    Raises:
        ValueError: As :func:`~telesmooth.datasets.lasa.lasa_operator_session`.
    """
    if period_s is not None:
        mapping = dataclasses.replace(mapping, haptic_rate_hz=1.0 / period_s)
    return HapticRecording.from_operator_session(
        lasa_operator_session(shape, demo_index, mapping=mapping))


def synthetic_haptic_recording(config: SyntheticOperatorConfig = SyntheticOperatorConfig(), *,
                               period_s: float | None = None) -> HapticRecording:
    """The haptic recording of a synthetic operator session.

    Args:
        config: The synthetic operator model and seed.
        period_s: Sample period, s; None keeps ``config.haptic_rate_hz``, else the config's
            rate is replaced by 1 / period_s.

    Raises:
        ValueError: If ``config`` is not a SyntheticOperatorConfig (the message gives it), or
            as :func:`~telesmooth.datasets.synthetic.synthetic_operator_session`.
    """
    if not isinstance(config, SyntheticOperatorConfig):
        raise ValueError(f"config = {config!r}; expected a SyntheticOperatorConfig")
    if period_s is not None:
        config = dataclasses.replace(config, haptic_rate_hz=1.0 / period_s)
    return HapticRecording.from_operator_session(synthetic_operator_session(config))
