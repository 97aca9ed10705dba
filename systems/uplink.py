"""The 4 Hz uplink: zero-order hold of the smoothed command, stamped with time and sequence.

This is the last ground-station stage: whatever it holds is what the robot receives (through
LCM in the split set-up). It never passes a non-finite or wrong-sized command: it re-sends the
previous one and raises a flag, so the robot holds. A thin Drake system around the pure step
:func:`telesmooth.link.uplink.uplink_step`, whose state lives in the Context as one vector.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from pydrake.systems.framework import LeafSystem

from telesmooth.arms.joint_vectors import check_finite_per_joint
from telesmooth.link.uplink import UplinkInputs, UplinkState, uplink_initial_state, uplink_step
from telesmooth.systems.codec_state import CodecState
from telesmooth.systems.timing import check_period

__all__ = ["Uplink", "UplinkConfig"]


@dataclasses.dataclass(frozen=True)
class UplinkConfig:
    """Settings of the uplink.

    Attributes:
        period_s: Uplink period, s (0.25 s: 4 Hz).
    """

    period_s: float = 0.25

    def __post_init__(self) -> None:
        check_period("UplinkConfig.period_s", self.period_s)


class Uplink(LeafSystem):
    r"""Samples the smoothed command every ``period_s`` and holds it, with a stamp.

    .. pydrake_system::

        name: Uplink
        input_ports:
        - q_smoothed
        - state_smoothed (optional)
        - holding (optional)
        output_ports:
        - q_sent
        - state_sent
        - sequence_number
        - send_time
        - command_rejected
        - holding_sent

    Ports (J = num_joints):

    - ``q_smoothed``: the command to send, rad, (J,) (the smoother's ``q_smoothed``).
    - ``state_smoothed``: the smoother's [q, q̇, q̈, q⃛], (4J,), held with the packet so the
      velocity sent (LCM) belongs to the same instant as the position; unconnected = zeros.
    - ``q_sent``: the command last sent, rad, (J,); held between ticks.
    - ``state_sent``: [q_sent, q̇, q̈, q⃛] of the last packet, (4J,).
    - ``sequence_number``: k, the number of the last packet (0 for the first), (1,);
      −1 before the first tick.
    - ``send_time``: t_k, when the last packet left (simulation clock), s, (1,); −1 before the
      first.
    - ``holding``: 1 while the ground station holds the robot (the FIFO's ``holding``),
      sampled with the command, (1,); unconnected = never.
    - ``command_rejected``: 1 if the last packet re-sent the previous command because the
      input was not finite, (1,).
    - ``holding_sent``: 1 if the last packet is a hold: ``holding`` was 1 at its tick, or its
      command was rejected (the previous one re-sent), (1,). The LCM sender marks it
      ``MODE_HOLD``.

    Update at t_k = k·period_s (offset 0): q_sent ← q_smoothed(t_k) if finite, else
    q_sent (unchanged, flag raised); sequence ← sequence + 1; send_time ← t_k (the event time);
    holding_sent ← holding(t_k) or rejected. All outputs are
    state outputs: a tick at t_k is visible just after t_k (Drake's publish-before-update
    convention means a logger sampling exactly at t_k still sees packet k−1). Before the first
    tick q_sent is ``initial_position_rad``.
    """

    def __init__(self, config: UplinkConfig = UplinkConfig(), *, num_joints: int,
                 initial_position_rad=None):
        super().__init__()
        if not isinstance(num_joints, (int, np.integer)) or num_joints < 1:
            raise ValueError(f"num_joints = {num_joints!r} must be a positive integer")
        n = int(num_joints)
        q0 = np.zeros(n) if initial_position_rad is None else check_finite_per_joint(
            "initial_position_rad", initial_position_rad, n)
        self._config = config
        self._num_joints = n
        self._q_smoothed_input = self.DeclareVectorInputPort("q_smoothed", n)
        self._state_smoothed_input = self.DeclareVectorInputPort("state_smoothed", 4 * n)
        self._holding_input = self.DeclareVectorInputPort("holding", 1)
        initial = uplink_initial_state(q0)
        self._state = CodecState(self, initial)
        self.DeclarePeriodicDiscreteUpdateEvent(config.period_s, 0.0, self._update_packet)
        # A forced update runs the same tick on demand (CalcForcedDiscreteVariableUpdate).
        self.DeclareForcedDiscreteUpdateEvent(self._update_packet)
        sent = self._state.codec.field_slice("state_sent")
        self._q_sent_output = self._state.output("q_sent", slice(sent.start, sent.start + n))
        self._state_sent_output = self._state.output("state_sent", sent)
        self._sequence_output = self._state.output("sequence_number", "sequence")
        self._send_time_output = self._state.output("send_time", "send_time")
        self._rejected_output = self._state.output("command_rejected", "rejected")
        self._holding_sent_output = self._state.output("holding_sent", "holding")

    @property
    def config(self) -> UplinkConfig:
        return self._config

    def get_q_smoothed_input_port(self):
        return self._q_smoothed_input

    def get_state_smoothed_input_port(self):
        return self._state_smoothed_input

    def get_holding_input_port(self):
        return self._holding_input

    def get_holding_sent_output_port(self):
        return self._holding_sent_output

    def get_state_sent_output_port(self):
        return self._state_sent_output

    def get_q_sent_output_port(self):
        return self._q_sent_output

    def get_sequence_number_output_port(self):
        return self._sequence_output

    def get_send_time_output_port(self):
        return self._send_time_output

    def get_command_rejected_output_port(self):
        return self._rejected_output

    def uplink_state(self, context) -> UplinkState:
        """The last packet, as :func:`~telesmooth.link.uplink.uplink_step` left it."""
        return self._state.get(context)

    def _update_packet(self, context, discrete_state):
        n = self._num_joints
        derivatives = np.zeros(3 * n)
        if self._state_smoothed_input.HasValue(context):
            derivatives = np.asarray(self._state_smoothed_input.Eval(context), float)[n:]
        holding = (self._holding_input.HasValue(context)
                   and bool(self._holding_input.Eval(context)[0] > 0.5))
        inputs = UplinkInputs(now=context.get_time(), command=self._q_smoothed_input.Eval(context),
                              derivatives=derivatives, holding=holding)
        self._state.store(discrete_state, uplink_step(self.uplink_state(context), inputs))
