"""Onboard link guard (safety/guard.py, systems/link_guard.py): the limits enforced onboard,
pass-through of a stream within them, ramp-down on silence, converging re-join.

The guard is driven by a scripted receiver (``PacketScript``: packet k arrives at a given
poll) in a Simulator and logged at every poll. The command *sequence* is q_commanded at the
polls where ``command_count`` increases; the FD limits are checked on it with numpy
(Δt = period_s, ≤ limit·(1 + 1e-9)), with the robot's rest made explicit: before a command
issued from HELD the held pose is repeated twice (the guard's model: the robot rested there).
"""

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder, LeafSystem
from pydrake.systems.primitives import LogVectorOutput

from telesmooth.lcm_types import lcmt_teleop_joint_command
from telesmooth.safety.guard import (
    GuardInputs,
    GuardMode,
    guard_initial_state,
    guard_params,
    guard_step,
    passes_within_limits,
)
from telesmooth.safety.state_codec import VectorCodec
from telesmooth.safety.stop import (
    SAME_SIDE_TOLERANCE_RAD,
    STOP_OUTCOMES,
    STOPPABLE_ROUNDING_TOLERANCE,
    StopOutcome,
    fd_state,
    nudge_into_stoppable_set,
    stop_params,
)
from telesmooth.smoothing.online_hard import OnlineHardLimiter
from telesmooth.systems.joint_command_receiver import JointCommandReceiver
from telesmooth.systems.link_guard import (
    GUARD_MODES,
    MODE_HELD,
    MODE_RESUMING,
    MODE_STOPPING,
    MODE_TRACK,
    LinkGuard,
    LinkGuardConfig,
    fd_limits_ratio,
)

DT = 0.25
POLL = 0.01
PERIOD_POLLS = 25
TIMEOUT_POLLS = 63          # the default 0.625 s, rounded up to polls
A_MAX = 0.2
J_MAX = 0.5
RELATIVE = 1e-9
JOINTS = ("shoulder", "elbow")
LOWER = np.array([-3.0, -3.0])
UPPER = np.array([3.0, 3.0])
Q0 = np.array([0.1, -0.2])
STOP = STOP_OUTCOMES.index("stop")


def always_safe(q):
    return True


def make_guard(q0=Q0, config=LinkGuardConfig(), **kwargs):
    arguments = dict(joint_names=JOINTS, lower_rad=LOWER, upper_rad=UPPER,
                     initial_position_rad=q0, max_acceleration=A_MAX, max_jerk=J_MAX)
    arguments.update(kwargs)
    return LinkGuard(config, **arguments)


def make_planner(pose_is_safe=always_safe, *, allow_reverse=True):
    """The planner the guard should use, built independently."""
    return stop_params(dt_s=DT, max_acceleration=A_MAX, max_jerk=J_MAX,
                       pose_is_safe=pose_is_safe, joint_names=JOINTS,
                       allow_reverse=allow_reverse)


def limited_stream(q0, targets, *, scale=0.9, max_velocity=None):
    """A stream within the limits: a limiter at ``scale`` × (a_max, j_max) (a bounded jerk,
    integrated) from rest at q0, fed ``targets`` (N, J)."""
    limiter = OnlineHardLimiter(dt_s=DT, max_acceleration=scale * A_MAX,
                                max_jerk=scale * J_MAX, max_velocity=max_velocity,
                                q_start=q0)
    return np.array([limiter.step(target) for target in np.asarray(targets, dtype=float)])


def ratios(sequence):
    return fd_limits_ratio(sequence, DT, A_MAX, J_MAX)


def assert_within_limits(sequence):
    r = ratios(sequence)
    assert max(r.acceleration, r.jerk) <= 1.0 + RELATIVE, r


class PacketScript(LeafSystem):
    """Test source with the receiver's outputs: packet k (row k of ``positions``) is accepted
    at poll ``arrival_polls[k]``; ``accepted_count`` counts them, ``q_accepted`` holds the
    newest (q0 before the first), ``command_seq`` its seq (``seqs[k]``, default k; −1 before
    the first) and ``command_session`` 7."""

    def __init__(self, q0, arrival_polls, positions, seqs=None):
        super().__init__()
        self._seqs = np.arange(len(arrival_polls)) if seqs is None else np.asarray(seqs)
        self._q0 = np.asarray(q0, dtype=float)
        self._polls = np.asarray(arrival_polls, dtype=int)
        self._q = np.asarray(positions, dtype=float).reshape(len(self._polls), len(q0))
        assert np.all(np.diff(self._polls) >= 0)   # equal: accepted in the same poll
        self.DeclareVectorOutputPort("q_accepted", len(q0), self._calc_q)
        self.DeclareVectorOutputPort("accepted_count", 1, self._calc_count)
        self.DeclareVectorOutputPort(
            "command_seq", 1, lambda c, o: o.SetAtIndex(
                0, -1.0 if self._count(c) == 0 else float(self._seqs[self._count(c) - 1])))
        self.DeclareVectorOutputPort("command_session", 1, lambda c, o: o.SetAtIndex(0, 7.0))

    def _count(self, context):
        return int(np.searchsorted(self._polls, round(context.get_time() / POLL), "right"))

    def _calc_q(self, context, output):
        k = self._count(context)
        output.SetFromVector(self._q0 if k == 0 else self._q[k - 1])

    def _calc_count(self, context, output):
        output.SetAtIndex(0, float(self._count(context)))


class GuardRun:
    """Per-poll record of one run: row i is the state *after* the update of poll i."""

    def __init__(self, q0, logs):
        self.q0 = np.asarray(q0, dtype=float)
        self.q = logs["q"]
        self.mode = logs["mode"][:, 0].astype(int)
        self.count = logs["count"][:, 0].astype(int)
        self.outcome = logs["outcome"][:, 0].astype(int)
        self.braking = logs["braking"]
        self.distance = logs["distance"][:, 0]
        self.mode_before = np.concatenate([[MODE_HELD], self.mode[:-1]])
        self.q_before = np.vstack([self.q0, self.q[:-1]])
        self.issued = np.diff(np.concatenate([[0], self.count])) > 0
        assert np.all(np.diff(np.concatenate([[0], self.count])) <= 1)
        self.events = np.flatnonzero(self.issued)

    @property
    def commands(self):
        return self.q[self.events]

    def assert_stop_commands_are_a_period_apart(self):
        """The stop's commands come at least one period after the previous command."""
        previous = np.concatenate([[-PERIOD_POLLS], self.events[:-1]])
        own = np.isin(self.events, np.flatnonzero(self.issued & (self.mode_before
                                                                == MODE_STOPPING)))
        assert np.all(self.events[own] - previous[own] >= PERIOD_POLLS)

    def fallbacks(self):
        """Polls at which a stop plan fell back to the hold (nothing issued, HELD)."""
        entered = (self.mode == MODE_HELD) & (self.mode_before != MODE_HELD)
        return np.flatnonzero(entered & ~self.issued & (self.outcome != STOP))

    def segments(self):
        """The command sequence with the rest made explicit (the held pose repeated twice
        before a command issued from HELD; three times at the start), split at the hold
        fallbacks (where the paper's hold knowingly breaks the limits)."""
        segments, current = [], [self.q0] * 3
        cuts = set(self.fallbacks().tolist())
        for poll in range(len(self.mode)):
            if poll in cuts:
                segments.append(np.array(current))
                current = [self.q[poll]] * 3
            if self.issued[poll]:
                if self.mode_before[poll] == MODE_HELD:
                    current += [self.q_before[poll]] * 2
                current.append(self.q[poll])
        segments.append(np.array(current))
        return segments


def run_guard(dut, arrival_polls, positions, duration_s, q0=Q0, *, seqs=None,
              connect_seq=False):
    builder = DiagramBuilder()
    source = builder.AddSystem(PacketScript(q0, arrival_polls, positions, seqs))
    guard = builder.AddSystem(dut)
    builder.Connect(source.GetOutputPort("q_accepted"), guard.get_q_accepted_input_port())
    builder.Connect(source.GetOutputPort("accepted_count"),
                    guard.get_accepted_count_input_port())
    if connect_seq or seqs is not None:
        builder.Connect(source.GetOutputPort("command_seq"), guard.get_command_seq_input_port())
        builder.Connect(source.GetOutputPort("command_session"),
                        guard.get_command_session_input_port())
    ports = {"q": guard.get_q_commanded_output_port(),
             "mode": guard.get_guard_mode_output_port(),
             "count": guard.get_command_count_output_port(),
             "outcome": guard.get_stop_outcome_output_port(),
             "braking": guard.get_braking_distance_output_port(),
             "distance": guard.get_stream_distance_output_port()}
    # Logged at every poll before its update (x⁻): row r is the state after poll r − 1.
    logs = {name: LogVectorOutput(port, builder, POLL) for name, port in ports.items()}
    simulator = Simulator(builder.Build())
    simulator.AdvanceTo(duration_s)
    context = simulator.get_context()
    return GuardRun(q0, {name: log.FindLog(context).data().T[1:] for name, log in logs.items()})


def on_the_grid(num_packets, first_tick=1):
    """Packet k arrives at t = (first_tick + k)·Δt."""
    return (np.arange(num_packets) + first_tick) * PERIOD_POLLS


def moving_stream(num_packets=14):
    """From rest at Q0 towards a far pose, still moving fast at the end (a real stop)."""
    return limited_stream(Q0, np.tile([2.5, -2.5], (num_packets, 1)))


def breaking_stream(n=80, factor=1.9, seed=3):
    """A stream that breaks the limits by up to ``factor``: a limiter at factor × the
    limits chasing random targets (like an Online-CKS stream, which meets them only
    approximately)."""
    rng = np.random.default_rng(seed)
    targets = np.repeat(rng.uniform(-1.5, 1.5, size=(n // 10 + 1, 2)), 10, axis=0)[:n]
    return limited_stream(Q0, targets, scale=factor)


# -- pass-through -----------------------------------------------------------------------------

def test_a_stream_within_the_limits_passes_through_exactly():
    z = limited_stream(Q0, np.array([[1.0, 0.5]] * 25 + [[-0.5, 1.0]] * 25))
    polls = on_the_grid(len(z))
    out = run_guard(make_guard(), polls, z, (polls[-1] + 10) * POLL)
    # Oracle: every packet is commanded bit for bit, at the poll it arrives.
    np.testing.assert_array_equal(out.commands, z)
    np.testing.assert_array_equal(out.events, polls)
    np.testing.assert_array_equal(out.distance, 0.0)
    # Joined through RESUMING (from rest at the initial pose), then TRACK.
    np.testing.assert_array_equal(out.mode[polls[:2]], MODE_RESUMING)
    np.testing.assert_array_equal(out.mode[polls[2]:], MODE_TRACK)
    # Before the first packet: held at the initial pose, silence does nothing.
    np.testing.assert_array_equal(out.mode[:polls[0]], MODE_HELD)
    np.testing.assert_array_equal(out.q[:polls[0]], np.tile(Q0, (polls[0], 1)))
    np.testing.assert_array_equal(out.outcome, 0)


def test_before_the_first_packet_the_guard_rests_at_the_initial_pose():
    out = run_guard(make_guard(), [10_000], [[1.0, 1.0]], 3.0)
    np.testing.assert_array_equal(out.q, np.tile(Q0, (len(out.q), 1)))
    np.testing.assert_array_equal(out.mode, MODE_HELD)
    assert out.events.size == 0


# -- the limits enforced onboard --------------------------------------------------------------

def test_an_authentic_step_of_03_rad_in_one_tick_never_reaches_the_robot_unchanged():
    # At rest, tracking; then one packet steps 0.3 rad (96× the FD acceleration limit of
    # the robot; here a_max = 0.2) and the stream stays there.
    z = np.vstack([np.tile(Q0, (8, 1)), np.tile(Q0 + [0.3, 0.0], (60, 1))])
    assert ratios(z).acceleration > 20.0
    polls = on_the_grid(len(z))
    out = run_guard(make_guard(), polls, z, (polls[-1] + 5) * POLL)
    step = polls[8]
    assert out.mode_before[step] == MODE_TRACK and out.issued[step]
    assert not np.array_equal(out.q[step], z[8])          # limited, in the poll it came
    assert out.distance[step] > 0.2                       # and reported
    assert_within_limits(np.vstack([np.tile(Q0, (3, 1)), out.commands]))
    # It keeps following the stream (TRACK) and arrives exactly.
    np.testing.assert_array_equal(out.mode[step:], MODE_TRACK)
    np.testing.assert_array_equal(out.q[-1], z[-1])
    assert out.distance[-1] == 0.0


@settings(derandomize=True, database=None, deadline=None, max_examples=12,
          suppress_health_check=[HealthCheck.too_slow])
@given(factor=st.floats(1.1, 4.0), seed=st.integers(0, 10_000))
def test_a_stream_that_breaks_the_limits_is_limited_while_tracking(factor, seed):
    z = breaking_stream(factor=factor, seed=seed)
    polls = on_the_grid(len(z))
    out = run_guard(make_guard(), polls, z, (polls[-1] + 40 * PERIOD_POLLS) * POLL)
    assert ratios(z).acceleration > 1.0 or ratios(z).jerk > 1.0
    # Every command the guard issued, the stop at the end included, within the limits.
    assert out.fallbacks().size == 0
    for segment in out.segments():
        assert_within_limits(segment)
    # Every packet was followed in the poll it arrived, as closely as the limits allow, and
    # the distance to it reported.
    for k, poll in enumerate(polls):
        assert out.issued[poll]
        assert out.distance[poll] == np.max(np.abs(out.q[poll] - z[k]))
    assert np.sum(out.distance[polls] > 0) > 10


# -- ramp-down --------------------------------------------------------------------------------

def test_silence_after_a_moving_stream_ramps_down_within_the_limits():
    z = moving_stream()
    polls = on_the_grid(len(z))
    out = run_guard(make_guard(), polls, z, (polls[-1] + 40 * PERIOD_POLLS) * POLL)
    stop_events = out.events[out.events > polls[-1]]
    history = z[-3:]
    plan = make_planner().plan(history, max_ticks=400)
    assert plan.is_stop and plan.ticks_to_rest > 5
    # Exactly the independently planned stop, the first command at the timeout, then one
    # per period.
    np.testing.assert_array_equal(out.q[stop_events], plan.commands)
    assert stop_events[0] == polls[-1] + TIMEOUT_POLLS
    np.testing.assert_array_equal(np.diff(stop_events), PERIOD_POLLS)
    # FD limits with the three commands before; at rest at the end (three equal commands).
    sequence = np.vstack([history, out.q[stop_events]])
    assert_within_limits(sequence)
    np.testing.assert_array_equal(sequence[-3], sequence[-1])
    np.testing.assert_array_equal(sequence[-2], sequence[-1])
    # Never outside [q_last, q_last + braking distance].
    excursion = out.q[stop_events] - z[-1]
    d = out.braking[-1]
    np.testing.assert_array_equal(d, plan.braking_distance)
    assert np.all(np.abs(excursion) <= np.abs(d))
    assert np.all(excursion * np.sign(d) >= -SAME_SIDE_TOLERANCE_RAD)
    assert np.all(np.abs(d) > 0.05)
    # Modes and reports: TRACK until the timeout, STOPPING, HELD after the last command.
    np.testing.assert_array_equal(out.mode[polls[2]:stop_events[0]], MODE_TRACK)
    np.testing.assert_array_equal(out.mode[stop_events[0]:stop_events[-1]], MODE_STOPPING)
    np.testing.assert_array_equal(out.mode[stop_events[-1]:], MODE_HELD)
    np.testing.assert_array_equal(out.outcome[:stop_events[0]], 0)
    np.testing.assert_array_equal(out.outcome[stop_events[0]:], StopOutcome.STOP)
    np.testing.assert_array_equal(out.braking[:stop_events[0]], 0.0)
    np.testing.assert_array_equal(out.q[stop_events[-1]:],
                                  np.tile(plan.rest_position, (len(out.q) - stop_events[-1], 1)))
    # The distance to the stream (its last packet) grows along the stop.
    np.testing.assert_allclose(out.distance[stop_events[-1]],
                               np.max(np.abs(plan.rest_position - z[-1])), rtol=0, atol=0)


def test_a_late_packet_within_the_timeout_is_followed_not_stopped_for():
    # One packet 0.6 s after the previous (a loaded ground), then on time again.
    z = limited_stream(Q0, np.tile([1.0, 0.5], (40, 1)))
    polls = on_the_grid(len(z))
    polls[20:] += 35                      # packet 20 arrives 0.35 s late
    out = run_guard(make_guard(), polls, z, (polls[-1] + 5) * POLL)
    assert polls[20] - polls[19] < TIMEOUT_POLLS
    np.testing.assert_array_equal(out.mode[polls[2]:], MODE_TRACK)
    np.testing.assert_array_equal(out.commands, z)
    np.testing.assert_array_equal(out.outcome, 0)


def test_a_stop_that_reverses_a_joint_is_planned_within_the_limits():
    # Joint 0 is just finishing its approach (v ≈ 2e-4 rad/s, braking) while joint 1 moves
    # at 0.56 rad/s: every admissible stop moves joint 0 back behind q_last. The collision
    # stop refuses that ("hold-reverses", a velocity step of joint 1 about elevenfold over
    # the limits); the guard's planner allows it, and the stop stays within the limits.
    z = limited_stream(Q0, np.tile([0.5, -2.5], (16, 1)))
    assert make_planner(allow_reverse=False).plan(z[-3:], max_ticks=400).outcome == \
        StopOutcome.HOLD_REVERSES
    assert ratios(np.vstack([z, z[-1:], z[-1:]])).acceleration > 10.0
    plan = make_planner().plan(z[-3:], max_ticks=400)
    assert plan.is_stop
    polls = on_the_grid(len(z))
    end = polls[-1] + TIMEOUT_POLLS + (plan.ticks_to_rest + 2) * PERIOD_POLLS
    out = run_guard(make_guard(), polls, z, end * POLL)
    assert out.outcome[-1] == StopOutcome.STOP
    np.testing.assert_array_equal(out.commands, np.vstack([z, plan.commands]))
    assert_within_limits(out.commands[3:])
    np.testing.assert_array_equal(out.mode[-1], MODE_HELD)


def test_a_rejected_braking_pose_holds_at_the_last_command_and_is_never_commanded():
    z = moving_stream()
    plan = make_planner().plan(z[-3:], max_ticks=400)
    wall = z[-1, 0] + 0.5 * plan.braking_distance[0]    # half way along joint 0's stop

    def below_wall(q):
        return q[0] < wall

    polls = on_the_grid(len(z))
    out = run_guard(make_guard(pose_is_safe=below_wall), polls, z,
                    (polls[-1] + 20 * PERIOD_POLLS) * POLL)
    assert out.outcome[-1] == StopOutcome.HOLD_POSE_REJECTED
    np.testing.assert_array_equal(out.commands, z)
    np.testing.assert_array_equal(out.q[-1], z[-1])
    assert np.all(out.q[:, 0] < wall)
    np.testing.assert_array_equal(out.mode[polls[-1] + TIMEOUT_POLLS:], MODE_HELD)


# -- re-join ----------------------------------------------------------------------------------

def test_resume_after_a_stop_reaches_a_far_target_within_the_limits_then_tracks():
    z = moving_stream()
    silence = 40                       # ticks without packets: the stop comes to rest
    far = np.array([-1.5, 1.0])
    tail = np.tile(far, (60, 1))       # the ground now holds a far pose
    polls = np.concatenate([on_the_grid(len(z)), on_the_grid(len(tail), len(z) + silence)])
    out = run_guard(make_guard(), polls, np.vstack([z, tail]), (polls[-1] + 5) * POLL)
    resumed = polls[len(z)]
    assert out.mode[resumed - 1] == MODE_HELD and out.outcome[resumed - 1] == StopOutcome.STOP
    assert out.mode[resumed] == MODE_RESUMING
    for segment in out.segments():
        assert_within_limits(segment)
    assert len(out.segments()) == 1
    # It reaches the far pose and hands back to TRACK once within the tolerance for three
    # commands in a row.
    track = np.flatnonzero((out.mode == MODE_TRACK) & (np.arange(len(out.mode)) > resumed))
    assert track.size and track[0] < polls[-1]
    rejoin = out.events[(out.events >= resumed) & (out.events <= track[0])]
    np.testing.assert_array_equal(np.diff(rejoin), PERIOD_POLLS)   # one per packet
    assert np.all(out.distance[rejoin[-3:]] <= LinkGuardConfig().rejoin_tolerance_rad)
    assert out.distance[rejoin[-4]] > LinkGuardConfig().rejoin_tolerance_rad
    np.testing.assert_array_equal(out.q[-1], far)


def test_resume_during_the_stop_is_within_the_limits_then_tracks():
    n = 70
    full = limited_stream(Q0, np.array([[1.5, -1.0]] * 20 + [[-1.0, 0.5]] * (n - 20)))
    keep = np.ones(n, dtype=bool)
    keep[18:23] = False                # 5 packets lost while moving: 1.5 s of silence
    polls = on_the_grid(n)[keep]
    out = run_guard(make_guard(), polls, full[keep], (polls[-1] + 5) * POLL)
    back = polls[18]
    assert out.mode[back - 1] == MODE_STOPPING   # the stop was still under way
    # The first re-join step replaces the next stop command (one period after the last).
    last_stop = out.events[out.events < back][-1]
    assert out.mode[last_stop] == MODE_STOPPING
    first_rejoin = out.events[out.events >= back][0]
    assert first_rejoin == last_stop + PERIOD_POLLS
    assert out.mode[first_rejoin] == MODE_RESUMING
    out.assert_stop_commands_are_a_period_apart()
    segments = out.segments()
    assert len(segments) == 1
    assert_within_limits(segments[0])
    # Back on the stream: TRACK again, and the stream (within the limits) passes bit for bit
    # once the robot's FD state is the stream's.
    track = np.flatnonzero((out.mode == MODE_TRACK) & (np.arange(len(out.mode)) > back))
    assert track.size
    np.testing.assert_array_equal(out.q[-1], full[-1])


def online_cks_stream(n=200, seed=0):
    """What the ground sends by default: Online-CKS of an operator-like recording (chained
    minimum-jerk reaches with noise), which meets the limits only approximately (here up to
    1.14× a_max and 1.23× j_max)."""
    from telesmooth.datasets.synthetic import synthetic_joint_motion
    from telesmooth.smoothing.methods import SmoothingSettings, smooth_recording

    z = synthetic_joint_motion(n, 2, seed=seed, reach_rad=0.4)
    settings_ = SmoothingSettings(max_acceleration=A_MAX, max_jerk=J_MAX)
    return smooth_recording(z + Q0, DT, "online-cks", settings_).positions


def test_a_rejoin_converges_on_an_online_cks_stream_that_breaks_the_limits():
    # The ground's default stream breaks the limits now and then; after 2 s of silence the
    # guard has stopped. It re-joins through the limiter and hands back to TRACK once three
    # commands in a row are within the tolerance of their packets (bit-for-bit equality may
    # never come); the whole sequence stays within the limits. Catching up with a stream
    # that moves near the limits takes time: here 3.5 s after the packets came back.
    z = online_cks_stream()
    assert ratios(np.vstack([np.tile(z[0], (3, 1)), z])).acceleration > 1.1
    keep = np.ones(len(z), dtype=bool)
    keep[60:68] = False
    polls = on_the_grid(len(z))[keep]
    out = run_guard(make_guard(), polls, z[keep], (polls[-1] + 5) * POLL)
    back = polls[60]
    assert out.mode[back - 1] in (MODE_STOPPING, MODE_HELD)
    first = out.events[out.events >= back][0]            # at the next guard tick
    assert first - back < PERIOD_POLLS and out.mode[first] == MODE_RESUMING
    track = np.flatnonzero((out.mode == MODE_TRACK) & (np.arange(len(out.mode)) > back))
    assert track.size, "never returned to TRACK"
    assert track[0] - back <= 32 * PERIOD_POLLS          # within 8 s of the packets' return
    rejoin = out.events[(out.events >= back) & (out.events <= track[0])]
    tolerance = LinkGuardConfig().rejoin_tolerance_rad
    assert np.all(out.distance[rejoin[-3:]] <= tolerance)
    assert out.fallbacks().size == 0
    for segment in out.segments():
        assert_within_limits(segment)
    # While the stream was present, TRACK on most of the ticks (the stop and re-join aside).
    on_stream = [p for p in polls if p > 2 * PERIOD_POLLS]
    share = np.mean(out.mode[on_stream] == MODE_TRACK)
    assert share > 0.7, share


def test_a_rejected_rejoin_command_is_never_commanded():
    wall = 0.6

    def below_wall(q):
        return q[0] < wall

    far = np.tile([1.5, -0.2], (40, 1))   # beyond the wall (the ground's model missed it)
    polls = on_the_grid(len(far))
    out = run_guard(make_guard(pose_is_safe=below_wall), polls, far, (polls[-1] + 5) * POLL)
    assert np.all(out.q[:, 0] < wall)
    assert out.events.size > 3
    # It tried: moved towards the target, then stopped or held short of the wall.
    assert out.q[-1, 0] > Q0[0] + 0.1
    assert STOP_OUTCOMES[out.outcome[-1]] in ("stop", "hold-pose-rejected")


def test_while_resuming_consecutive_packets_are_followed_at_once_a_burst_at_the_tick():
    # At rest at Q0 (so every re-join step equals its packet); packets 2 and 3 arrive in
    # one poll (a burst): the count jumps by two, which is a gap, so that packet waits for
    # the next guard tick; the others are followed in the poll they arrive.
    polls = [25, 50, 60, 60, 100, 125, 150]
    out = run_guard(make_guard(), polls, np.tile(Q0, (len(polls), 1)), 2.0)
    np.testing.assert_array_equal(out.events, [25, 50, 75, 100, 125, 150])
    np.testing.assert_array_equal(out.mode[[25, 50]], MODE_RESUMING)
    assert out.mode[75] == MODE_TRACK                    # three within the tolerance
    steady = run_guard(make_guard(), [25, 50, 75], np.tile(Q0, (3, 1)), 1.0)
    assert steady.mode[75] == MODE_TRACK


def test_after_a_hold_the_robot_is_at_rest_a_later_stop_starts_from_rest():
    # A joint model that rejects every pose beyond q_last on joint 0: the stop after the
    # stream is refused (pose rejected) and the guard holds; the next packet asks for more
    # of the same, its limited step is rejected, and the stop is planned from rest at the
    # held pose (one command, the pose itself), not from the motion before the hold.
    z = moving_stream()
    q_last = z[-1]

    def not_beyond(q):
        return q[0] <= q_last[0]

    polls = np.concatenate([on_the_grid(len(z)), [(len(z) + 12) * PERIOD_POLLS]])
    packets = np.vstack([z, q_last + [0.5, 0.0]])
    out = run_guard(make_guard(pose_is_safe=not_beyond), polls, packets,
                    (polls[-1] + 10) * POLL)
    held = polls[len(z) - 1] + TIMEOUT_POLLS
    assert out.outcome[held] == StopOutcome.HOLD_POSE_REJECTED
    assert out.outcome[polls[-1]] == StopOutcome.STOP
    np.testing.assert_array_equal(out.braking[polls[-1]], 0.0)
    np.testing.assert_array_equal(out.q[polls[-1]:], np.tile(q_last, (10, 1)))
    assert out.mode[-1] == MODE_HELD


# -- random streams with losses ---------------------------------------------------------------

@st.composite
def lossy_streams(draw):
    """A within-limit stream (J = 2) with random target changes, loss bursts of 1–10 ticks
    and 0–2 polls of arrival jitter."""
    n = draw(st.integers(40, 90))
    q0 = np.array(draw(st.lists(st.floats(-1.0, 1.0), min_size=2, max_size=2)))
    switches = draw(st.lists(st.tuples(st.integers(0, n - 1), st.floats(-2.0, 2.0),
                                       st.floats(-2.0, 2.0)), min_size=1, max_size=8))
    targets = np.tile(q0, (n, 1))
    for tick, first, second in sorted(switches):
        targets[tick:] = [first, second]
    bursts = draw(st.lists(st.tuples(st.integers(0, n - 1), st.integers(1, 10)), max_size=5))
    keep = np.ones(n, dtype=bool)
    for start, length in bursts:
        keep[start:start + length] = False
    jitter = np.array(draw(st.lists(st.integers(0, 2), min_size=n, max_size=n)))
    return q0, targets, keep, jitter


@settings(derandomize=True, database=None, deadline=None, max_examples=25,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
@given(case=lossy_streams())
def test_random_lossy_streams_stay_within_the_limits_and_track(case):
    q0, targets, keep, jitter = case
    z = limited_stream(q0, targets, max_velocity=0.6)
    assert np.all(np.abs(z) < 2.9)
    polls = on_the_grid(len(z)) + jitter
    polls, z = polls[keep], z[keep]
    if polls.size == 0:
        return
    out = run_guard(make_guard(q0), polls, z, (polls[-1] + 60 * PERIOD_POLLS) * POLL, q0=q0)
    # Every packet accepted while in TRACK is followed at once (no seq: every single new
    # packet counts as consecutive).
    for poll, _q in zip(polls, z):
        if out.mode_before[poll] == MODE_TRACK:
            assert out.issued[poll]
    for segment in out.segments():
        assert_within_limits(segment)
    # On a within-limit stream no stop falls back to the hold.
    assert out.fallbacks().size == 0, [STOP_OUTCOMES[out.outcome[p]] for p in out.fallbacks()]
    out.assert_stop_commands_are_a_period_apart()
    # Silence at the end: the guard comes to rest (HELD).
    assert out.mode[-1] == MODE_HELD


# -- gaps while tracking ----------------------------------------------------------------------

def test_a_packet_missing_while_tracking_is_limited_when_the_gap_breaks_the_limits():
    # A stream within the limits; packet 20 never reaches the guard (lost, or held back and
    # then dropped as stale by the receiver) while the others arrive on time.
    z = limited_stream(Q0, np.array([[1.0, 0.5]] * 12 + [[-0.5, 1.0]] * 60))
    seqs = np.delete(np.arange(len(z)), 20)
    polls = on_the_grid(len(z))[seqs]
    # Oracle of the harm: passed through, the gap breaks the jerk limit.
    assert ratios(np.delete(z, 20, axis=0)).jerk > 1.0 + 1e-3
    for identity in (None, seqs):      # with or without the packet's seq: the FD check
        out = run_guard(make_guard(), polls, z[seqs], (polls[-1] + 10) * POLL, seqs=identity)
        after = polls[20]
        # Up to the gap: exactly the stream. The packet after the gap: a limiter step, at
        # the poll it arrives (one period after the last command), still TRACK.
        np.testing.assert_array_equal(out.q[polls[:20]], z[:20])
        assert out.mode_before[after] == MODE_TRACK and out.mode[after] == MODE_TRACK
        assert out.issued[after] and not np.array_equal(out.q[after], z[21])
        for segment in out.segments():
            assert_within_limits(segment)
        # Back on the stream bit for bit once the limiter has caught up, and from then on.
        exact = [np.array_equal(out.q[p], z[k]) for k, p in zip(seqs, polls)]
        back = 21 + exact[21:].index(True)
        assert all(exact[back:]) and len(exact) - back > 10, exact


def test_two_packets_accepted_in_one_poll_while_tracking_wait_for_the_guard_tick():
    z = limited_stream(Q0, np.array([[1.0, 0.5]] * 60))
    polls = on_the_grid(len(z))
    polls[15] = polls[16]            # packet 15 late: accepted in the same poll as 16
    out = run_guard(make_guard(), polls, z, (polls[-1] + 5) * POLL)
    # Packet 15 was not used (the count jumped by two): the command at that poll follows
    # packet 16 (a guard tick, 2Δt after the last command), within the limits.
    assert out.issued[polls[16]] and out.mode[polls[16]] == MODE_TRACK
    for segment in out.segments():
        assert_within_limits(segment)
    assert out.mode[-1] == MODE_TRACK and np.array_equal(out.q[-1], z[-1])


@settings(derandomize=True, database=None, deadline=None, max_examples=15,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
@given(case=lossy_streams())
def test_random_gaps_below_the_timeout_stay_within_the_limits(case):
    # A long timeout, so that lost packets are gaps while tracking rather than silences.
    q0, targets, keep, jitter = case
    z = limited_stream(q0, targets, max_velocity=0.6)
    seqs = np.flatnonzero(keep)
    polls = (on_the_grid(len(z)) + jitter)[keep]
    if polls.size == 0:
        return
    out = run_guard(make_guard(q0, config=LinkGuardConfig(timeout_s=3.0)), polls, z[keep],
                    (polls[-1] + 60 * PERIOD_POLLS) * POLL, q0=q0, seqs=seqs)
    # Consecutive packets accepted in TRACK are commanded at once.
    for j, (poll, _q) in enumerate(zip(polls, z[keep])):
        if j and seqs[j] == seqs[j - 1] + 1 and out.mode_before[poll] == MODE_TRACK:
            assert out.issued[poll]
    assert out.fallbacks().size == 0
    for segment in out.segments():
        assert_within_limits(segment)
    out.assert_stop_commands_are_a_period_apart()
    assert out.mode[-1] == MODE_HELD


# -- the stoppable-set rounding ---------------------------------------------------------------

def saturated_histories():
    """Last three commands of a limiter chasing far targets (at its acceleration limit)."""
    limiter = OnlineHardLimiter(dt_s=DT, max_acceleration=A_MAX, max_jerk=J_MAX, q_start=Q0)
    sent = [Q0] * 3
    rng = np.random.default_rng(0)
    target = np.array([2.0, -2.0])
    for tick in range(200):
        if tick % 25 == 0:
            target = rng.uniform(-2.0, 2.0, size=2)
        sent.append(limiter.step(target))
        yield np.array(sent[-3:])


def test_histories_outside_the_stoppable_set_by_rounding_are_nudged_not_held():
    dut = make_guard()
    planner = make_planner()
    sets = OnlineHardLimiter(dt_s=DT, max_acceleration=A_MAX, max_jerk=J_MAX,
                             q_start=Q0).stoppable_sets
    rounding_only = 0
    for history in saturated_histories():
        nudged = nudge_into_stoppable_set(history, sets, DT)
        np.testing.assert_array_equal(nudged[2], history[2])
        v, a = fd_state(history, DT)
        bound = 2 * STOPPABLE_ROUNDING_TOLERANCE * (np.abs(v) * DT + np.abs(a) * DT**2)
        assert np.all(np.abs(nudged - history) <= bound + 1e-15)
        raw = planner.plan(history, max_ticks=400)
        plan = dut.plan_stop(history)
        assert plan.outcome != StopOutcome.HOLD_NOT_STOPPABLE
        if raw.outcome == StopOutcome.HOLD_NOT_STOPPABLE:
            rounding_only += plan.is_stop
            if plan.is_stop:  # within the limits with the *actual* history
                assert_within_limits(np.vstack([history, plan.commands]))
        else:
            np.testing.assert_array_equal(nudged, history)   # untouched when inside
            np.testing.assert_array_equal(plan.commands, raw.commands)
    assert rounding_only > 10   # the planner alone would hold on these
    # A state really outside the set is left alone (and held).
    breaking = np.array([Q0, Q0, Q0 + [0.5 * A_MAX * DT**2 * 3.0, 0.0]])
    np.testing.assert_array_equal(nudge_into_stoppable_set(breaking, sets, DT), breaking)
    assert dut.plan_stop(breaking).outcome == StopOutcome.HOLD_NOT_STOPPABLE


def test_fd_limits_ratio_on_a_hand_computed_sequence():
    # p = 0, 0, 0, 1 (rad), Δt = 0.5: v = 2, a = 4, u = 8 at the last sample.
    p = np.array([[0.0], [0.0], [0.0], [1.0]])
    r = fd_limits_ratio(p, 0.5, max_acceleration=8.0, max_jerk=4.0, max_velocity=1.0)
    assert r == (2.0, 0.5, 2.0)
    assert fd_limits_ratio(p[:2], 0.5, 1.0, 1.0) == (0.0, 0.0, 0.0)


def test_passes_within_limits_against_hand_computed_differences():
    params = make_guard().params
    rest = np.tile(Q0, (3, 1))
    # From rest, a step s gives v = s/Δt, a = s/Δt², u = s/Δt³ = 64 s: the jerk binds.
    s_max = J_MAX * DT**3
    assert passes_within_limits(params, rest, Q0 + [0.5 * s_max, 0.0])
    assert not passes_within_limits(params, rest, Q0 + [1.01 * s_max, 0.0])
    # Within the FD limits but not stoppable: at v = 0 the limits allow a = a_max only if
    # the jerk can bring it back; here a at the limit with the jerk needed to reverse it
    # beyond j_max is outside S.
    v_big = np.array([0.0, 0.0])
    assert passes_within_limits(params, rest, Q0 + v_big)


# -- contract, contexts, wiring ---------------------------------------------------------------

def test_ports_modes_and_initial_outputs():
    dut = make_guard()
    inputs = [dut.get_input_port(i).get_name() for i in range(dut.num_input_ports())]
    outputs = [dut.get_output_port(i).get_name() for i in range(dut.num_output_ports())]
    assert inputs == ["q_accepted", "accepted_count", "command_seq", "command_session"]
    assert outputs == ["q_commanded", "guard_mode", "braking_distance", "stop_outcome",
                       "command_count", "stream_distance", "limited_count"]
    assert [dut.get_output_port(i).size() for i in range(7)] == [2, 1, 2, 1, 1, 1, 1]
    for i in range(4):
        for j in range(7):
            assert not dut.HasDirectFeedthrough(i, j)
    assert dut.modes == GUARD_MODES == ("track", "stopping", "held", "resuming")
    assert (MODE_TRACK, MODE_STOPPING, MODE_HELD, MODE_RESUMING) == (0, 1, 2, 3)
    assert LinkGuard.MODE_RESUMING == 3
    context = dut.CreateDefaultContext()
    np.testing.assert_array_equal(dut.get_q_commanded_output_port().Eval(context), Q0)
    assert dut.get_guard_mode_output_port().Eval(context)[0] == MODE_HELD
    np.testing.assert_array_equal(dut.get_braking_distance_output_port().Eval(context), 0.0)
    assert dut.get_stop_outcome_output_port().Eval(context)[0] == 0
    assert dut.get_command_count_output_port().Eval(context)[0] == 0
    assert dut.get_stream_distance_output_port().Eval(context)[0] == 0.0
    assert dut.get_limited_count_output_port().Eval(context)[0] == 0


def forced_poll(dut, context, poll, count, q):
    """One poll by hand (no simulator): the periodic update's handler, forced."""
    context.SetTime(poll * POLL)
    dut.get_q_accepted_input_port().FixValue(context, np.asarray(q, dtype=float))
    dut.get_accepted_count_input_port().FixValue(context, [float(count)])
    update = dut.AllocateDiscreteVariables()
    dut.CalcForcedDiscreteVariableUpdate(context, update)
    context.SetDiscreteState(update)
    return dut.get_q_commanded_output_port().Eval(context).copy()


def script(z, num_polls):
    """(count, q) at each poll for packets on the grid, then silence."""
    polls = on_the_grid(len(z))
    for poll in range(num_polls):
        k = int(np.searchsorted(polls, poll, "right"))
        yield poll, k, (Q0 if k == 0 else z[k - 1])


def test_state_lives_in_the_context_two_contexts_interleaved_equal_separate_runs():
    dut = make_guard()
    first = moving_stream()
    second = limited_stream(Q0, np.tile([-1.0, 1.0], (14, 1)))
    num_polls = 15 * PERIOD_POLLS + 750
    alone = []
    for z in (first, second):
        context = dut.CreateDefaultContext()
        alone.append([forced_poll(dut, context, p, k, q) for p, k, q in script(z, num_polls)])
    contexts = [dut.CreateDefaultContext(), dut.CreateDefaultContext()]
    together = [[], []]
    for a, b in zip(script(first, num_polls), script(second, num_polls)):
        together[0].append(forced_poll(dut, contexts[0], *a))
        together[1].append(forced_poll(dut, contexts[1], *b))
    np.testing.assert_array_equal(np.array(together), np.array(alone))
    assert not np.array_equal(alone[0], alone[1])
    # The first stream ends moving: the forced polls played its stop too.
    assert dut.get_guard_mode_output_port().Eval(contexts[0])[0] == MODE_HELD
    assert dut.get_stop_outcome_output_port().Eval(contexts[0])[0] == StopOutcome.STOP
    # The system's polls are guard_step on the pure state, exactly.
    params, state = dut.params, guard_initial_state(dut.params)
    for poll, count, q in script(first, num_polls):
        state, command = guard_step(params, state, GuardInputs(poll, float(count), q))
    np.testing.assert_array_equal(command, alone[0][-1])
    assert state.mode == MODE_HELD


def test_guard_step_is_pure_and_its_state_round_trips_through_a_vector():
    params = make_guard().params
    state = guard_initial_state(params)
    z = moving_stream()
    codec = VectorCodec(state)
    for poll, count, q in script(z, 20 * PERIOD_POLLS):
        q = np.array(q)
        frozen = (codec.pack(state), q.copy())
        new_state, command = guard_step(params, state, GuardInputs(poll, float(count), q))
        np.testing.assert_array_equal(codec.pack(state), frozen[0])   # argument unchanged
        np.testing.assert_array_equal(q, frozen[1])
        again = codec.unpack(codec.pack(new_state))
        np.testing.assert_array_equal(codec.pack(again), codec.pack(new_state))
        assert again.mode is new_state.mode and again.stop_outcome is new_state.stop_outcome
        state = new_state
    assert state.mode == GuardMode.STOPPING and state.command_count > len(z)
    np.testing.assert_array_equal(command, state.history[-1])


def joint_command(seq, q):
    msg = lcmt_teleop_joint_command()
    msg.seq = seq
    msg.session_id = 0       # in process: epoch 0, session 0 (telesmooth.link.session)
    msg.num_joints = len(JOINTS)
    msg.joint_name = list(JOINTS)
    msg.joint_position_smoothed = [float(x) for x in q]
    msg.joint_velocity_smoothed = [0.0] * len(JOINTS)
    return msg


def test_wired_to_the_receiver_a_packet_is_commanded_in_the_poll_it_is_accepted():
    builder = DiagramBuilder()
    receiver = builder.AddSystem(JointCommandReceiver(
        joint_names=JOINTS, lower_rad=LOWER, upper_rad=UPPER, initial_position_rad=Q0))
    guard = builder.AddSystem(make_guard())
    builder.Connect(receiver.get_q_commanded_output_port(), guard.get_q_accepted_input_port())
    builder.Connect(receiver.get_accepted_count_output_port(),
                    guard.get_accepted_count_input_port())
    builder.ExportInput(receiver.get_lcm_message_input_port(), "lcm_message")
    diagram = builder.Build()
    simulator = Simulator(diagram)
    context = simulator.get_mutable_context()
    z = limited_stream(Q0, np.tile([0.8, 0.4], (12, 1)))
    diagram.get_input_port(0).FixValue(context, joint_command(-1, Q0))
    guard_context = guard.GetMyContextFromRoot(context)
    receiver_context = receiver.GetMyContextFromRoot(context)
    for k, q in enumerate(z):
        time = (k + 1) * DT
        simulator.AdvanceTo(time - 0.5 * POLL)   # the poll before the packet
        diagram.get_input_port(0).FixValue(context, joint_command(k, q))
        simulator.AdvanceTo(time + 0.5 * POLL)   # the poll at `time` has run
        np.testing.assert_array_equal(
            receiver.get_q_commanded_output_port().Eval(receiver_context), q)
        np.testing.assert_array_equal(guard.get_q_commanded_output_port().Eval(guard_context),
                                      q)
    assert guard.get_guard_mode_output_port().Eval(guard_context)[0] == MODE_TRACK


# -- validation -------------------------------------------------------------------------------

@pytest.mark.parametrize("make, message", [
    (lambda: LinkGuardConfig(timeout_s=0.0), r"LinkGuardConfig.timeout_s = 0.0 must be finite"),
    (lambda: LinkGuardConfig(timeout_s="0.3"), r"timeout_s = '0.3' must be a number"),
    (lambda: LinkGuardConfig(period_s=-0.25), r"period_s = -0.25 must be finite and > 0"),
    (lambda: LinkGuardConfig(poll_period_s=float("nan")), r"poll_period_s = nan must be"),
    (lambda: LinkGuardConfig(poll_period_s=0.5), r"poll_period_s = 0.5 must be <= period_s"),
    (lambda: LinkGuardConfig(poll_period_s=0.03),
     r"period_s = 0.25 must be a whole number of poll_period_s = 0.03"),
    (lambda: LinkGuardConfig(max_stop_ticks=0), r"max_stop_ticks = 0 must be an integer >= 1"),
    (lambda: LinkGuardConfig(max_stop_ticks=True), r"max_stop_ticks = True must be"),
    (lambda: LinkGuardConfig(resume_match_ticks=1.5), r"resume_match_ticks = 1.5 must be"),
    (lambda: LinkGuardConfig(rejoin_tolerance_rad=-1e-3),
     r"rejoin_tolerance_rad = -0.001 must be finite and >= 0"),
    (lambda: make_guard(config="fast"), r"config = 'fast' must be a LinkGuardConfig"),
    (lambda: make_guard(joint_names=()), r"joint_names = \(\) must name at least one joint"),
    (lambda: make_guard(joint_names="shoulder"), r"must be a sequence of names"),
    (lambda: make_guard(joint_names=("a", "a")), r"repeats \['a'\]"),
    (lambda: make_guard(lower_rad=[-3.0]),
     r"lower_rad = \[-3.0\] has shape \(1,\); expected \(2,\), one per joint of "
     r"\('shoulder', 'elbow'\)"),
    (lambda: make_guard(upper_rad=[3.0, -3.0]),
     r"lower_rad\[1\] = -3.0 for joint 1 \('elbow'\) must be < upper_rad\[1\] = -3.0"),
    (lambda: make_guard(upper_rad=[3.0, np.inf]),
     r"upper_rad\[1\] = inf for joint 1 \('elbow'\) must be finite"),
    (lambda: make_guard(q0=[5.0, 0.0]),
     r"initial_position_rad\[0\] = 5.0 for joint 0 \('shoulder'\) must be finite and "
     r"within \[-3.0, 3.0\] rad"),
    (lambda: make_guard(q0=[0.0, np.nan]),
     r"initial_position_rad\[1\] = nan for joint 1 \('elbow'\) must be finite"),
    (lambda: make_guard(max_acceleration=[0.2, -1.0]),
     r"max_acceleration\[1\] = -1.0 for joint 1 \('elbow'\) must be finite and > 0"),
    (lambda: make_guard(max_jerk=np.inf), r"max_jerk\[0\] = inf .* must be finite and > 0"),
    (lambda: make_guard(max_velocity=0.0), r"max_velocity\[0\] = 0.0 .* must be > 0"),
    (lambda: make_guard(pose_is_safe=3), r"pose_is_safe = 3 must be None or callable"),
])
def test_bad_values_are_named(make, message):
    with pytest.raises(ValueError, match=message):
        make()


def test_defaults_are_valid_and_rounded_to_polls():
    config = LinkGuardConfig()
    assert (config.period_polls, config.timeout_polls) == (PERIOD_POLLS, TIMEOUT_POLLS)
    assert LinkGuardConfig(timeout_s=0.305).timeout_polls == 31


def test_a_receiver_restart_drops_the_pending_packet_and_starts_a_gap():
    # A packet after a gap waits in TRACK for the guard tick; the receiver restarts before
    # it (count back to 0, q_accepted its initial pose far away): the guard must not steer
    # toward that pose, and the restarted receiver's first packet is joined as a gap.
    params = guard_params(LinkGuardConfig(), joint_names=JOINTS, lower_rad=LOWER,
                          upper_rad=UPPER, initial_position_rad=Q0, max_acceleration=A_MAX,
                          max_jerk=J_MAX)
    z = limited_stream(Q0, np.array([[1.0, 0.5]] * 20))
    state = guard_initial_state(params)

    def poll(state, i, count, q, packet_id):
        return guard_step(params, state, GuardInputs(i, count, q, packet_id))[0]

    for k in range(10):                        # packets 0..9 on the grid, then TRACK
        state = poll(state, PERIOD_POLLS * (k + 1), k + 1.0, z[k], (float(k), 7.0))
    assert state.mode == MODE_TRACK
    q_before = state.command.copy()
    # Packet 11 (10 lost) lands one poll after the last command: pending, no tick yet.
    state = poll(state, PERIOD_POLLS * 10 + 1, 11.0, z[11], (11.0, 7.0))
    assert state.pending and state.mode == MODE_TRACK
    far = np.array([2.5, 2.5])
    state = poll(state, PERIOD_POLLS * 10 + 2, 0.0, far, (-1.0, 0.0))   # the restart
    assert not state.pending
    for i in range(PERIOD_POLLS * 10 + 3, PERIOD_POLLS * 16):   # past the timeout
        state = poll(state, i, 0.0, far, (-1.0, 0.0))
    # Nothing steered toward the restarted receiver's initial pose: the guard stopped (or
    # holds) from what it had commanded.
    assert np.all(np.abs(state.command - q_before) < 0.5)
    assert state.mode in (MODE_STOPPING, MODE_HELD)
    assert np.isnan(state.used_seq)
