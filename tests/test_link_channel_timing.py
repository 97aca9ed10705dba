"""When the in-process link hands a packet to the onboard receiver (systems/link_channel.py,
``poll_offset_s``; diagrams/teleoperation.py: the deployed chain).

Oracle: the poll grids, worked out by hand. The receiver polls at i·poll (poll = 10 ms); a
channel polling every ``period`` from ``offset`` takes a packet at its first poll at or after
the instant the packet appears, and the receiver accepts it at its first poll strictly after
that (both are unrestricted updates: at one instant neither sees the other's). So

* channel (10 ms, offset 9 ms): a packet formed at a 4 Hz tick t_k = k·0.25 s is taken at
  t_k + 9 ms and accepted at t_k + 10 ms;
* channel (2 ms, offset 0): taken at t_k + 2 ms (at t_k itself it sees the sender's output
  before the tick's update), accepted at t_k + 10 ms: the same poll;
* channel (10 ms, offset 0): taken at t_k + 10 ms, accepted at t_k + 20 ms: one poll late.

The receiver's outputs are read half-way between polls (no logger involved): after poll i's
updates, before poll i + 1's.
"""

import math

import numpy as np
import pytest
from pydrake.common.value import AbstractValue
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder, LeafSystem

from telesmooth.diagrams.scenario import LoadScenario
from telesmooth.diagrams.teleoperation import MakeTeleoperationDiagram
from telesmooth.lcm_types import lcmt_teleop_joint_command
from telesmooth.systems.joint_command_receiver import (
    JointCommandReceiver,
    JointCommandReceiverConfig,
)
from telesmooth.systems.link_channel import LinkChannel

POLL = 0.01
TICK = 0.25
JOINTS = ("a", "b")


def _command(seq):
    msg = lcmt_teleop_joint_command()
    msg.seq = seq
    if seq >= 0:
        msg.num_joints = len(JOINTS)
        msg.joint_name = list(JOINTS)
        msg.joint_position_smoothed = [0.01 * seq, -0.01 * seq]
        msg.joint_velocity_smoothed = [0.0, 0.0]
    return msg


class TickSender(LeafSystem):
    """Forms packet k at the 4 Hz tick k·0.25 s (a discrete update, as the uplink's sender)."""

    def __init__(self):
        super().__init__()
        self._seq = self.DeclareDiscreteState([-1.0])
        self.DeclarePeriodicDiscreteUpdateEvent(TICK, 0.0, self._tick)
        self.DeclareAbstractOutputPort(
            "lcm_message", lambda: AbstractValue.Make(lcmt_teleop_joint_command()),
            lambda c, o: o.set_value(_command(int(c.get_discrete_state(self._seq)[0]))),
            {self.xd_ticket()})

    def _tick(self, context, state):
        state.get_mutable_vector(self._seq).SetAtIndex(
            0, context.get_discrete_state(self._seq)[0] + 1.0)


class PhaseSender(LeafSystem):
    """Packet k appears at ``times[k]`` (a function of time: any phase against the polls)."""

    def __init__(self, times):
        super().__init__()
        self._times = np.asarray(times)
        self.DeclareAbstractOutputPort(
            "lcm_message", lambda: AbstractValue.Make(lcmt_teleop_joint_command()),
            lambda c, o: o.set_value(_command(
                int(np.searchsorted(self._times, c.get_time(), "right")) - 1)))


def _accept_times(sender, period, offset, num_polls):
    """{seq: the instant of the receiver's poll that accepted it}."""
    builder = DiagramBuilder()
    builder.AddSystem(sender)
    link = builder.AddSystem(LinkChannel(lcm_type=lcmt_teleop_joint_command,
                                         poll_period_s=period, poll_offset_s=offset))
    receiver = builder.AddSystem(JointCommandReceiver(
        JointCommandReceiverConfig(poll_period_s=POLL), joint_names=JOINTS,
        lower_rad=[-3.0, -3.0], upper_rad=[3.0, 3.0], initial_position_rad=[0.0, 0.0]))
    builder.Connect(sender.get_output_port(0), link.get_lcm_message_input_port())
    builder.Connect(link.get_packets_output_port(), receiver.get_packets_input_port())
    simulator = Simulator(builder.Build())
    simulator.Initialize()
    receiver_context = receiver.GetMyContextFromRoot(simulator.get_context())
    accepted, count = {}, 0
    for i in range(num_polls):
        simulator.AdvanceTo((i + 0.5) * POLL)
        seq = int(receiver.get_last_command_seq_output_port().Eval(receiver_context)[0])
        new_count = int(receiver.get_accepted_count_output_port().Eval(receiver_context)[0])
        if new_count > count:
            assert new_count == count + 1, "one packet per poll here"
            accepted[seq] = i * POLL
            count = new_count
    return accepted


@pytest.mark.parametrize("period, offset, late", [
    (0.01, 0.009, 0),        # the deployed chain's channel
    (0.002, 0.0, 0),         # a fast channel: the same poll
    (0.01, 0.0, 1),          # the receiver's period without the offset: a poll late
])
def test_a_packet_formed_at_a_tick_is_accepted_one_poll_later(period, offset, late):
    # Catches: the offset ignored (the channel polling on the receiver's own grid makes every
    # packet a poll late: the third case shows that lateness is real), or applied as a
    # delay after the poll instead of as the grid's phase.
    accepted = _accept_times(TickSender(), period, offset, num_polls=150)
    assert sorted(accepted) == list(range(6))
    for k, t in accepted.items():
        assert t == pytest.approx(k * TICK + (1 + late) * POLL, abs=1e-12), k


def test_any_phase_is_accepted_at_the_poll_after_the_channels_and_never_later_than_fast():
    # Catches: a channel that takes a packet at a poll before it appears, or skips the poll
    # right after; and the claim of the docstring (as early as a faster channel) broken for
    # some phase of the packet against the polls.
    phases = [0.0003, 0.0042, 0.0087, 0.0089, 0.0091, 0.0099]
    times = [k * TICK + phase for k, phase in enumerate(phases)]
    slow = _accept_times(PhaseSender(times), 0.01, 0.009, num_polls=160)
    fast = _accept_times(PhaseSender(times), 0.002, 0.0, num_polls=160)
    assert sorted(slow) == sorted(fast) == list(range(len(phases)))
    for k, t in enumerate(times):
        taken = (math.ceil((t - 0.009) / POLL) * POLL) + 0.009   # first channel poll >= t
        assert slow[k] == pytest.approx(taken + 0.001, abs=1e-12), k
        assert slow[k] <= fast[k] + 1e-12, k
    # 0.0087 and 0.0089 are after the fast channel's poll at +8 ms: it takes them at +10 ms,
    # which the receiver sees a poll later; the offset channel is then a poll earlier.
    assert fast[2] - slow[2] == pytest.approx(POLL, abs=1e-12)


def test_in_the_deployed_chain_packet_k_is_accepted_at_k_tick_plus_one_poll():
    # Catches: the deployed chain built without the channel's offset (or with another
    # period): its packets would be taken a poll late, 20 ms after their tick.
    scenario = LoadScenario(scenario_text=(
        "{haptic: {source: synthetic, synthetic: {duration_s: 5.0, hold_start_s: 0.5, "
        "hold_end_s: 0.5}}, settle_s: 1.0}"))
    assert scenario.chain == "deployed" and scenario.command_receiver.poll_period_s == POLL
    handles = MakeTeleoperationDiagram(scenario)
    simulator = Simulator(handles.diagram)
    simulator.Initialize()
    receiver = handles.onboard.receiver
    context = receiver.GetMyContextFromRoot(simulator.get_context())
    accepted, count = {}, 0
    for i in range(300):
        simulator.AdvanceTo((i + 0.5) * POLL)
        new_count = int(receiver.get_accepted_count_output_port().Eval(context)[0])
        if new_count > count:
            seq = int(receiver.get_last_command_seq_output_port().Eval(context)[0])
            assert new_count == count + 1
            accepted[seq] = i * POLL
            count = new_count
    assert sorted(accepted) == list(range(12))
    for k, t in accepted.items():
        assert t == pytest.approx(k * TICK + POLL, abs=1e-12), k


@pytest.mark.parametrize("offset", [-0.001, 0.002, 0.0035, math.nan, math.inf])
def test_an_offset_outside_the_period_is_refused_naming_it(offset):
    # Catches: a negative offset or one of a period or more accepted (Drake would shift the
    # grid silently, or refuse with a message that does not name the setting), and NaN
    # slipping through a comparison.
    with pytest.raises(ValueError, match=r"LinkChannel\.poll_offset_s = .* must be >= 0 and "
                                         r"below poll_period_s = 0\.002"):
        LinkChannel(lcm_type=lcmt_teleop_joint_command, poll_period_s=0.002,
                    poll_offset_s=offset)


def test_offsets_inside_the_period_are_accepted():
    # Catches a bound off by one side: 0 and just below the period are valid phases.
    for offset in (0.0, 0.0019):
        LinkChannel(lcm_type=lcmt_teleop_joint_command, poll_period_s=0.002,
                    poll_offset_s=offset)
