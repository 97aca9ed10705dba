"""The link guard's ``limited_count`` (safety/guard.py, systems/link_guard.py): the commands
that followed a packet but differ from it.

A LinkGuard system and the pure ``guard_step`` are driven side by side, poll by poll, by a
scripted receiver (a packet every 25 polls, seq k, session 0). The oracle is a count made
here: every command issued (the command count grew) compared with the packet the receiver
held at that poll. The stream never falls silent, so every command follows a packet.
"""

import numpy as np

from telesmooth.safety.guard import GuardInputs, GuardMode, guard_initial_state, guard_step
from telesmooth.systems.link_guard import LinkGuard, LinkGuardConfig

JOINTS = ("shoulder", "elbow")
LOWER, UPPER = np.array([-3.0, -3.0]), np.array([3.0, 3.0])
Q0 = np.array([0.1, -0.2])
A_MAX, J_MAX = 0.2, 0.5
DT, POLL, PERIOD_POLLS = 0.25, 0.01, 25


def _gentle(num_packets):
    """From rest at Q0, a slow 1 mrad swing: FD acceleration and jerk far inside the limits."""
    k = np.arange(num_packets)[:, None]
    return Q0 + 1e-3 * (1.0 - np.cos(2 * np.pi * k / 20.0)) * np.array([1.0, -0.5])


def _drive(packets):
    """Feeds ``packets`` (packet k accepted at poll 25 k + 1) and 3 s more; returns per poll
    (the system's limited_count, the pure state's, command issued?, command, packet, mode)."""
    guard = LinkGuard(LinkGuardConfig(), joint_names=JOINTS, lower_rad=LOWER, upper_rad=UPPER,
                      initial_position_rad=Q0, max_acceleration=A_MAX, max_jerk=J_MAX)
    assert guard.config.period_s == DT and guard.config.poll_period_s == POLL
    context = guard.CreateDefaultContext()
    params = guard.params
    state = guard_initial_state(params)
    rows = []
    for poll in range(PERIOD_POLLS * len(packets) + 1):
        count = min(len(packets), (poll + PERIOD_POLLS - 1) // PERIOD_POLLS)
        q = Q0 if count == 0 else packets[count - 1]
        seq = count - 1
        context.SetTime(poll * POLL)
        guard.get_q_accepted_input_port().FixValue(context, q)
        guard.get_accepted_count_input_port().FixValue(context, [float(count)])
        guard.get_command_seq_input_port().FixValue(context, [float(seq)])
        guard.get_command_session_input_port().FixValue(context, [0.0])
        update = guard.AllocateDiscreteVariables()
        guard.CalcForcedDiscreteVariableUpdate(context, update)
        context.SetDiscreteState(update)
        issued = state.command_count
        state, command = guard_step(params, state, GuardInputs(poll, float(count), q,
                                                               (float(seq), 0.0)))
        np.testing.assert_array_equal(guard.get_q_commanded_output_port().Eval(context),
                                      command)
        rows.append((guard.get_limited_count_output_port().Eval(context)[0],
                     state.limited_count, state.command_count > issued, command, q,
                     state.mode))
    return rows


def _own_count(rows):
    """Commands issued that differ from the packet the receiver held at their poll."""
    return sum(1 for _, _, issued, command, packet, _ in rows
               if issued and not np.array_equal(command, packet))


def test_a_stream_within_the_limits_is_never_limited():
    # Catches: a limited_count that counts every command (or every packet), or an output
    # port wired to another field of the state (command_count, the mode...): a stream within
    # the limits passes bit for bit, so nothing was limited.
    packets = _gentle(24)
    # The stream is within the limits after the robot's rest (checked here, not assumed).
    sequence = np.vstack([np.tile(Q0, (3, 1)), packets])
    assert np.max(np.abs(np.diff(sequence, 2, axis=0))) / DT**2 < 0.1 * A_MAX
    assert np.max(np.abs(np.diff(sequence, 3, axis=0))) / DT**3 < 0.1 * J_MAX
    rows = _drive(packets)
    assert sum(issued for _, _, issued, _, _, _ in rows) == len(packets)
    assert _own_count(rows) == 0
    assert all(system == pure == 0 for system, pure, *_ in rows)


def test_after_a_jump_it_counts_exactly_the_commands_that_differ_from_their_packet():
    # Catches: a count that misses cut commands (counting only the first after the jump, or
    # only the commands whose limiter outcome is not exact), one that keeps counting once the
    # guard has caught up (every command after the jump), and a system output that lags or
    # differs from the pure state at any poll.
    gentle = _gentle(10)
    jumped = np.tile(gentle[-1] + [0.3, -0.1], (40, 1))     # 0.3 rad in one tick, then held
    rows = _drive(np.vstack([gentle, jumped]))
    modes = [mode for *_, mode in rows]
    first = next(i for i, row in enumerate(rows) if row[2])
    assert all(mode in (GuardMode.TRACK, GuardMode.RESUMING) for mode in modes[first:])
    own = _own_count(rows)
    assert own >= 10                                  # the jump was cut over many ticks
    running = 0
    for system, pure, issued, command, packet, _ in rows:
        running += issued and not np.array_equal(command, packet)
        assert system == pure == running
    # It caught up: the last commands are their packets again, and were not counted.
    issued = [(command, packet) for _, _, flag, command, packet, _ in rows if flag]
    assert len(issued) == 50
    for command, packet in issued[-5:]:
        np.testing.assert_array_equal(command, packet)
    assert rows[-1][0] == own < 40
