"""The uplink's pure step (``telesmooth.link.uplink``): known packets by hand, and the Drake
system holding what the step returns.

* a finite command is sent with its derivatives, stamped k = 0, 1, … and the tick's time;
* a command or derivative that is not finite re-sends the previous packet's command and
  derivatives, flagged rejected, as a hold; the next finite one is sent again;
* ``holding`` makes the packet a hold without changing what is sent;
* the state round-trips through the Context's codec, the step does not change its argument,
  and Uplink's outputs are the step's.
"""

import numpy as np

from telesmooth.link.uplink import UplinkInputs, uplink_initial_state, uplink_step
from telesmooth.safety.state_codec import VectorCodec

Q0 = np.array([0.1, -0.2])


def _tick(state, now, command, derivatives=None, holding=False):
    derivatives = np.zeros(6) if derivatives is None else np.asarray(derivatives, float)
    return uplink_step(state, UplinkInputs(now, np.asarray(command, float), derivatives,
                                           holding))


def test_packets_by_hand():
    state = uplink_initial_state(Q0)
    assert (state.sequence, state.send_time) == (-1, -1.0)
    np.testing.assert_array_equal(state.state_sent, [0.1, -0.2, 0, 0, 0, 0, 0, 0])
    codec = VectorCodec(state)
    before = codec.pack(state)
    first = _tick(state, 0.0, [0.3, 0.4], [1, 2, 3, 4, 5, 6])
    np.testing.assert_array_equal(codec.pack(state), before)       # the argument unchanged
    np.testing.assert_array_equal(first.state_sent, [0.3, 0.4, 1, 2, 3, 4, 5, 6])
    assert (first.sequence, first.send_time, first.rejected, first.holding) == (
        0, 0.0, False, False)
    bad = _tick(first, 0.25, [np.nan, 0.0])
    np.testing.assert_array_equal(bad.state_sent, first.state_sent)
    assert (bad.sequence, bad.send_time, bad.rejected, bad.holding) == (1, 0.25, True, True)
    bad_rate = _tick(bad, 0.5, [0.5, 0.5], [np.inf, 0, 0, 0, 0, 0])
    np.testing.assert_array_equal(bad_rate.state_sent, first.state_sent)
    assert bad_rate.rejected and bad_rate.sequence == 2
    held = _tick(bad_rate, 0.75, [0.6, 0.6], holding=True)
    np.testing.assert_array_equal(held.state_sent[:2], [0.6, 0.6])
    assert held.holding and not held.rejected and held.sequence == 3
    np.testing.assert_array_equal(codec.pack(codec.unpack(codec.pack(held))), codec.pack(held))


def test_the_drake_system_holds_the_steps_packets():
    from pydrake.systems.framework import DiagramBuilder
    from pydrake.systems.primitives import ConstantVectorSource

    from telesmooth.systems.uplink import Uplink, UplinkConfig

    builder = DiagramBuilder()
    uplink = builder.AddSystem(Uplink(UplinkConfig(period_s=0.25), num_joints=2,
                                      initial_position_rad=Q0))
    source = builder.AddSystem(ConstantVectorSource(np.zeros(2)))
    builder.Connect(source.get_output_port(), uplink.get_q_smoothed_input_port())
    diagram = builder.Build()
    context = diagram.CreateDefaultContext()
    source_context = source.GetMyContextFromRoot(context)
    uplink_context = uplink.GetMyContextFromRoot(context)
    state = uplink_initial_state(Q0)
    for k, command in enumerate(([0.3, 0.4], [np.nan, 1.0], [0.5, 0.6])):
        source.get_mutable_source_value(source_context).SetFromVector(command)
        context.SetTime(0.25 * k)
        state = _tick(state, 0.25 * k, command)
        update = uplink.EvalUniquePeriodicDiscreteUpdate(uplink_context)
        uplink_context.SetDiscreteState(update)
        np.testing.assert_array_equal(uplink.get_q_sent_output_port().Eval(uplink_context),
                                      state.state_sent[:2])
        assert uplink.get_sequence_number_output_port().Eval(uplink_context)[0] == k
        assert uplink.get_holding_sent_output_port().Eval(uplink_context)[0] == float(
            state.holding)
