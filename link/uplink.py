"""The uplink's zero-order hold as a pure step: what the ground sends every 4 Hz tick.

Every ``period_s`` the smoothed command is sampled and held until the next tick, stamped with
a sequence number and the send time (:class:`~telesmooth.systems.uplink.Uplink` is the thin
Drake system around :func:`uplink_step`). A command that is not finite is never sent: the
previous packet's command is sent again, flagged rejected, and the packet is a hold. A packet
sampled while the ground holds the robot (the FIFO's collision hold or stop) is a hold too.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

__all__ = ["UplinkInputs", "UplinkState", "uplink_initial_state", "uplink_step"]


class UplinkState(NamedTuple):
    """The last packet sent (before the first: the start pose, sequence and time −1)."""

    state_sent: np.ndarray       # (4J,) [q, q̇, q̈, q⃛] of the last packet; q its first J
    sequence: int                # k of the last packet; −1 before the first
    send_time: float             # when it left, s; −1 before the first
    rejected: bool               # it re-sent the previous command (the input was not finite)
    holding: bool                # it is a hold (sampled while holding, or rejected)


class UplinkInputs(NamedTuple):
    """One tick's inputs."""

    now: float
    command: np.ndarray          # (J,) the smoothed command
    derivatives: np.ndarray      # (3J,) its [q̇, q̈, q⃛] (zeros when unknown)
    holding: bool                # the ground holds the robot at this tick


def uplink_initial_state(initial_position) -> UplinkState:
    """Before the first packet: at rest at ``initial_position`` (J,)."""
    q0 = np.array(initial_position, dtype=float)
    return UplinkState(state_sent=np.concatenate([q0, np.zeros(3 * q0.size)]), sequence=-1,
                       send_time=-1.0, rejected=False, holding=False)


def uplink_step(state: UplinkState, inputs: UplinkInputs) -> UplinkState:
    """The packet of this tick (module docstring)."""
    n = state.state_sent.size // 4
    command = np.asarray(inputs.command, dtype=float)
    derivatives = np.asarray(inputs.derivatives, dtype=float)
    valid = (command.shape == (n,) and bool(np.all(np.isfinite(command)))
             and bool(np.all(np.isfinite(derivatives))))
    sent = np.concatenate([command, derivatives]) if valid else state.state_sent
    return UplinkState(state_sent=sent, sequence=state.sequence + 1,
                       send_time=float(inputs.now), rejected=not valid,
                       holding=bool(inputs.holding) or not valid)
