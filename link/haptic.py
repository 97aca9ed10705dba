"""The live haptic device's stream as a pure step: which messages move the hand, and when the
clutch is off.

Every ``period_s`` the newest ``lcmt_teleop_haptic_command`` is examined
(:class:`~telesmooth.systems.haptic_command_receiver.HapticCommandReceiver` is the thin Drake
system around :func:`haptic_step`, and documents the ports):

* a message is new when its ``utime`` differs from the last one examined (any int64, compared
  exactly: it is kept as its high and low 32 bits, each exact in a float64); before any has
  been examined, every message but the default-constructed one (what a subscriber outputs
  while nothing has arrived) is new;
* a new message with the arm's number of axes and finite values becomes the pose, its clutch
  and its stop, stamped with the time it was examined; any other new message is rejected
  (clutch and stop off, the pose held);
* an undecodable newest packet flags the message rejected too (the pose holds).

The clutch and the stop read on while the last valid message is at most ``timeout_s`` old and
not rejected (:func:`haptic_flags`): a silent or broken device can never move the arm.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

__all__ = ["HapticInputs", "HapticState", "haptic_flags", "haptic_initial_state", "haptic_step"]


class HapticState(NamedTuple):
    """The stream after an examination."""

    pose: np.ndarray             # (m,) the last valid pose (the initial pose before any)
    enable: bool                 # the last valid message's clutch
    arrived_s: float             # when it was examined, s (−inf before any)
    have_message: bool           # a message has been examined
    utime_high: float            # its utime: the signed high 32 bits …
    utime_low: float             # … and the unsigned low 32 bits
    rejected: bool               # the newest message (or packet) was refused
    stop: bool                   # the last valid message's stop


class HapticInputs(NamedTuple):
    """One examination's inputs."""

    now: float
    message: object              # the newest lcmt_teleop_haptic_command
    undecodable: bool            # the newest packet on the channel could not be decoded


def haptic_initial_state(initial_pose) -> HapticState:
    """Before any message: the initial pose, clutch off."""
    return HapticState(pose=np.array(initial_pose, dtype=float), enable=False,
                       arrived_s=-np.inf, have_message=False, utime_high=0.0, utime_low=0.0,
                       rejected=False, stop=False)


def _split_utime(utime) -> tuple[float, float]:
    """An int64 as (signed high 32 bits, unsigned low 32 bits), both exact in a float64."""
    value = int(utime)
    return float(value >> 32), float(value & 0xFFFF_FFFF)


def _join_utime(high: float, low: float) -> int:
    """The int64 that :func:`_split_utime` split."""
    return (int(high) << 32) | int(low)


def _is_default_message(msg) -> bool:
    """True for the default-constructed message a subscriber outputs before any arrives."""
    return (msg.utime == 0 and msg.seq == 0 and msg.num_axes == 0
            and len(msg.pose_desired) == 0 and not msg.enable)


def haptic_step(state: HapticState, inputs: HapticInputs) -> HapticState:
    """The stream after examining ``inputs.message`` (module docstring)."""
    msg = inputs.message
    if state.have_message:
        is_new = int(msg.utime) != _join_utime(state.utime_high, state.utime_low)
    else:
        is_new = not _is_default_message(msg)
    if is_new:
        high, low = _split_utime(msg.utime)
        state = state._replace(have_message=True, utime_high=high, utime_low=low)
        m = state.pose.size
        pose = np.asarray(msg.pose_desired, dtype=float)
        if msg.num_axes == m and pose.shape == (m,) and np.all(np.isfinite(pose)):
            state = state._replace(pose=pose.copy(), enable=bool(msg.enable),
                                   arrived_s=float(inputs.now), stop=bool(msg.stop),
                                   rejected=False)
        else:
            state = state._replace(enable=False, stop=False, rejected=True)
    if inputs.undecodable:
        state = state._replace(enable=False, stop=False, rejected=True)
    return state


def haptic_flags(state: HapticState, now: float, timeout_s: float) -> tuple[bool, bool]:
    """(clutch, stop): the last valid message's, while it is at most ``timeout_s`` old and not
    rejected; else off."""
    fresh = now - state.arrived_s <= timeout_s and not state.rejected
    return state.enable and fresh, state.stop and fresh
