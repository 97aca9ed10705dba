"""The predicted robot as a pure step: telemetry, the robot's clock, the measured predictions,
what its copies of the onboard chain do, and what the display shows.

The ground's predicted robot (:class:`~telesmooth.systems.robot_predictor.RobotPredictor`)
runs copies of the onboard chain ahead of the delayed telemetry. Everything it decides is
here, in three parts of one update:

* :func:`receive_step`: the new telemetry (``lcmt_onboard_joint_status``) and the packets
  the ground sent (in one process its current message; on the bus the packets heard,
  decoded from a ``packets`` port's (arrival number, bytes) pairs); the robot's clock
  (:class:`ClockState`: robot minus this process from the telemetry's send times, robot
  minus ground from the packets the telemetry names as accepted); the packets given to the
  copies' log and, on the bus, a copy built where the first telemetry says the robot is;
  each prediction measured against the sample of its instant (a :class:`Residual`); the
  newest sample and the last 2 s of samples, by sample instant;
* :func:`prediction_now` and :func:`advance_step`: now on the robot's clock, on the
  telemetry's sample grid, and what the copies do to get there: the synchronised copy
  follows the newest telemetry it may use and is re-synchronised on it every
  ``resync_period_s``; a stale look-ahead is caught up from it over several updates while
  the shown one runs on;
* :func:`record_step`: the prediction made for now (the copy's tool position and link
  angles, which the system reads from the look-ahead after carrying out the actions) kept
  until its sample arrives, and the :class:`PredictorView`.

The copies themselves are Drake Simulators of a Drake diagram: they cannot be a value of a
pure state. The step tracks where they are (:class:`Copies`: their times, the log's last
packet) and returns *actions* (:class:`Build`, :class:`Append`, :class:`RestSynced`,
:class:`AdvanceSynced`, :class:`Resync`, :class:`StartCatchup`, :class:`AdvanceCatchup`,
:class:`Swap`, :class:`AdvanceAhead`) that the system carries out on them in order; a
Simulator advanced to a time is at that time, so the tracked times are theirs.

:class:`PredictorState` is immutable (tuples and :class:`FrozenMap`; a telemetry sample's
arrays are read-only, the predictions' arrays and the heard packets' LCM messages are never
written after they are made: :func:`for_the_copy` changes a copy): a deep copy of it is
itself. It holds telemetry samples and LCM
messages, not a float vector: the system keeps it in an abstract state.
"""

from __future__ import annotations

import copy
from collections.abc import Iterator, Mapping, Sequence
from typing import NamedTuple

import immutables
import numpy as np

from telesmooth.lcm_types import (
    decode_exact,
    lcmt_onboard_joint_status,
    lcmt_teleop_joint_command,
)

__all__ = ["AdvanceAhead", "AdvanceCatchup", "AdvanceSynced", "Append", "Build", "ClockParams",
           "ClockState", "Copies", "FrozenMap", "PredictorParams", "PredictorState",
           "PredictorView", "Received", "RemoteClock", "RestSynced", "Resync", "Residual",
           "StartCatchup", "Swap", "TelemetrySample", "advance_step", "clock_newest",
           "clock_packet", "clock_ready", "clock_telemetry", "decode_new", "for_the_copy",
           "largest_recent", "predictor_initial_state", "prediction_now", "receive_step",
           "record_step", "take_pending", "telemetry_sample"]

WINDOW_S = 2.0
"""The samples kept, s before the newest one's instant."""


class FrozenMap(Mapping):
    """An immutable mapping: :meth:`set` and :meth:`without` return a new one.

    It is a persistent map (``immutables.Map``, the hash array mapped trie of Python's
    ``contextvars``): a new version shares all but O(log n) of the old one's nodes, so that
    adding a key costs the same after hours of a session (the clock's maps grow by a packet
    every uplink period) as at its start. Iteration order is not insertion order.
    """

    __slots__ = ("_items",)

    def __init__(self, items=()):
        self._items = items if isinstance(items, immutables.Map) else immutables.Map(items)

    def __getitem__(self, key):
        return self._items[key]

    def __iter__(self) -> Iterator:
        return iter(self._items)

    def __len__(self) -> int:
        return len(self._items)

    def __repr__(self) -> str:
        return f"FrozenMap({dict(self._items)!r})"

    def __deepcopy__(self, memo):
        return self

    def set(self, key, value) -> FrozenMap:
        """A copy with ``key`` → ``value`` (in place of an existing key's value)."""
        return FrozenMap(self._items.set(key, value))

    def without(self, keys) -> FrozenMap:
        """A copy without ``keys`` (itself when there are none)."""
        keys = list(keys)
        if not keys:
            return self
        with self._items.mutate() as items:
            for key in keys:
                del items[key]
            return FrozenMap(items.finish())


class TelemetrySample(NamedTuple):
    """One telemetry message as the predictor uses it (times in s: the sample's and the
    message's on the onboard clock, its arrival on the predictor's)."""

    sample_t_s: float
    sent_t_s: float
    arrival_t_s: float
    q_link: np.ndarray
    q_motor: np.ndarray
    v_link: np.ndarray
    v_motor: np.ndarray
    tool_position_m: np.ndarray
    guard_mode: int
    stream_distance_rad: float
    last_command_seq: int
    q_commanded: np.ndarray


class Residual(NamedTuple):
    """One measured prediction: the instant, how far ahead of its newest telemetry it was
    made (s), the predicted and the measured tool position (m, (3,) each) and their
    distance (m)."""

    t_s: float
    horizon_s: float
    predicted_m: np.ndarray
    measured_m: np.ndarray
    residual_m: float


class PredictorView(NamedTuple):
    """What the predictor's outputs show (the abstract state)."""

    q_predicted: np.ndarray
    tool_predicted: np.ndarray
    q_received: np.ndarray
    tool_received: np.ndarray
    telemetry_age_s: float       # now − the newest sample's instant (inf: none yet)
    telemetry_silence_s: float   # now − the newest message's arrival (inf: none yet)
    residual_m: float            # the largest residual measured over the last window (nan:
    # none yet)
    guard_mode: float            # the robot's guard mode (telemetry), −1: none yet
    stream_distance_rad: float


def telemetry_sample(msg, arrival_t_s: float, num_joints: int) -> TelemetrySample | None:
    """A decoded telemetry message as a :class:`TelemetrySample`, or None for one of another
    arm or without its state (NaN velocities: a sender that does not know them)."""
    if int(msg.num_joints) != num_joints:
        return None
    arrays = [np.array(v, dtype=float) for v in (
        msg.joint_position_link, msg.joint_position_motor, msg.joint_velocity_link,
        msg.joint_velocity_motor)]
    if any(a.shape != (num_joints,) or not np.all(np.isfinite(a)) for a in arrays):
        return None
    tool, commanded = (np.array(v, dtype=float) for v in (msg.tool_position_measured,
                                                          msg.joint_position_commanded))
    for array in (*arrays, tool, commanded):
        array.flags.writeable = False    # a sample is part of an immutable state
    return TelemetrySample(
        sample_t_s=msg.sample_utime * 1e-6, sent_t_s=msg.utime * 1e-6,
        arrival_t_s=float(arrival_t_s),
        q_link=arrays[0], q_motor=arrays[1], v_link=arrays[2], v_motor=arrays[3],
        tool_position_m=tool,
        guard_mode=int(msg.guard_mode), stream_distance_rad=float(msg.stream_distance_rad),
        last_command_seq=int(msg.last_command_seq), q_commanded=commanded)


def decode_new(packets, last_number: int, lcm_type) -> tuple[int, list]:
    """(the newest arrival number, the packets after ``last_number`` decoded; one that does
    not decode is skipped: garbage on a bus is nobody's message)."""
    decoded = []
    for number, data in packets:
        if number <= last_number:
            continue
        last_number = number
        try:
            decoded.append(decode_exact(lcm_type, data))
        except Exception:  # noqa: BLE001 - garbage on a bus is nobody's message
            continue
    return last_number, decoded


# -- the robot's clock --------------------------------------------------------------------


class ClockParams(NamedTuple):
    """The receiver's poll period, the telemetry's publish offset after its poll and the
    console's batch period (s), and how many offsets the medians take."""

    poll_period_s: float
    publish_offset_s: float
    batch_period_s: float = 0.04
    window: int = 50


class ClockState(NamedTuple):
    """The offsets measured (the last ``window`` of each, oldest first), their medians as
    :class:`RemoteClock` states them (None: none yet), and when each packet seq was accepted
    (robot's clock) and sent (ground's)."""

    offsets: tuple[float, ...] = ()
    ground_offsets: tuple[float, ...] = ()
    robot_minus_local: float | None = None
    robot_minus_ground: float | None = None
    accepted: FrozenMap = FrozenMap()
    sent: FrozenMap = FrozenMap()


def clock_newest(params: ClockParams, state: ClockState, sample: TelemetrySample) -> ClockState:
    """The newest message of a batch: its send time against when it was seen."""
    offsets = list(state.offsets)
    offsets.append(sample.sent_t_s - sample.arrival_t_s)
    del offsets[:-params.window]
    return state._replace(offsets=tuple(offsets), robot_minus_local=float(
        np.median(offsets)) + 0.5 * params.batch_period_s)


def clock_telemetry(params: ClockParams, state: ClockState,
                    sample: TelemetrySample) -> ClockState:
    """A telemetry message: the first that names a packet as accepted dates its
    acceptance."""
    k = sample.last_command_seq
    if k >= 0 and k not in state.accepted:
        # The first message that names it was published publish_offset_s after the poll
        # that accepted it.
        state = state._replace(accepted=state.accepted.set(
            k, sample.sent_t_s - params.publish_offset_s))
        return _match(params, state, k)
    return state


def clock_packet(params: ClockParams, state: ClockState, seq: int,
                 ground_t_s: float) -> ClockState:
    """A packet the ground sent at ``ground_t_s`` (its clock)."""
    return _match(params, state._replace(sent=state.sent.set(seq, ground_t_s)), seq)


def _match(params: ClockParams, state: ClockState, seq: int) -> ClockState:
    if seq in state.accepted and seq in state.sent:
        # The median over the last packets: a ground process that runs late and catches
        # up stamps some packets early against its steady offset (the smallest
        # offset, taken before, put the copy's commands 0.12 s ahead of the robot's
        # under load); acceptance falls anywhere in a poll, half a poll on average.
        ground = list(state.ground_offsets)
        ground.append(state.accepted[seq] - state.sent[seq])
        del ground[:-params.window]
        return state._replace(ground_offsets=tuple(ground), robot_minus_ground=float(
            np.median(ground)) - 0.5 * params.poll_period_s)
    return state


def clock_ready(state: ClockState) -> bool:
    """Both offsets are known."""
    return state.robot_minus_local is not None and state.robot_minus_ground is not None


class RemoteClock:
    """The clocks of three processes, as the operator's predictor sees them.

    The operator's console, the ground and the robot each run their own clock (each
    simulation starts at its process's start). The predicted robot runs on the robot's:

    * now on the robot's clock = the console's now + (the robot's time − the console's): the
      median over the last batches the console took of (their newest message's send time −
      the instant the console took the batch), plus half the console's period (the wait of a
      message in its batch, on average). Messages queued while the console was busy are
      older than their batch's newest; a median shrugs off a late batch;
    * a packet sent at g (ground clock) reaches the robot at g + (the median acceptance −
      send time over the last packets the telemetry names as accepted, less half a poll):
      the copy's packet is given that send time, so that the copy's receiver takes it in
      the poll the robot's took it.

    Until the telemetry has named an accepted packet, packets wait (:meth:`ready`). The
    rules are the pure functions :func:`clock_newest`, :func:`clock_telemetry` and
    :func:`clock_packet` on a :class:`ClockState`; this object holds one and replaces it.
    """

    def __init__(self, *, poll_period_s: float, publish_offset_s: float,
                 batch_period_s: float = 0.04, window: int = 50,
                 state: ClockState | None = None):
        self.params = ClockParams(float(poll_period_s), float(publish_offset_s),
                                  float(batch_period_s), int(window))
        self.state = ClockState() if state is None else state

    @property
    def robot_minus_local(self) -> float | None:
        return self.state.robot_minus_local

    @property
    def robot_minus_ground(self) -> float | None:
        return self.state.robot_minus_ground

    def newest(self, sample: TelemetrySample) -> None:
        """The newest message of a batch: its send time against when it was seen."""
        self.state = clock_newest(self.params, self.state, sample)

    def telemetry(self, sample: TelemetrySample) -> None:
        self.state = clock_telemetry(self.params, self.state, sample)

    def packet(self, seq: int, ground_t_s: float) -> None:
        self.state = clock_packet(self.params, self.state, seq, ground_t_s)

    def ready(self) -> bool:
        return clock_ready(self.state)

    def now(self, local_t_s: float) -> float:
        return local_t_s + self.state.robot_minus_local

    def send_time(self, ground_t_s: float) -> float:
        return ground_t_s + self.state.robot_minus_ground


# -- the predictor's state ----------------------------------------------------------------


class PredictorParams(NamedTuple):
    """The arm's joint count, the telemetry's sample period (the grid predictions are made
    on, s), the window the shown residual is the largest over (s), how many residuals the
    run keeps, the clock's settings (None: in one process, one clock; else on the bus), how
    often the copy is re-synchronised on the telemetry (s), how much copy-time a catch-up
    runs per update (s), and the uplink's period (s: when the next packet is due)."""

    num_joints: int
    sample_period_s: float
    residual_window_s: float
    residual_history: int
    clock: ClockParams | None
    resync_period_s: float = 0.04
    catchup_budget_s: float = 0.12
    uplink_period_s: float = 0.25


class Copies(NamedTuple):
    """Where the system's copies of the onboard chain are (their clock, s), as the step
    directs them: ``synced`` (re-synchronised on the telemetry), ``ahead`` (run ahead to
    now: the prediction shown), a ``catchup`` being brought up to now (None: none), and the
    packet log they read (how many, the last seq, the last send time).

    Attributes:
        built: A copy exists (on the bus without a start pose: from the first telemetry).
        start: The pose the copy was built at (rad, (J,)).
        synced_t, ahead_t, catchup_t: The copies' times.
        synced_sample_t: The instant of the sample last re-synchronised on (−inf: none).
        catchup_from, ahead_horizon_from: The synchronised copy's time the catch-up and the
            shown look-ahead started from.
        ahead_stale: The look-ahead must start again (a re-synchronisation, or a packet heard
            after it passed the packet's send time).
        log_count, log_last_seq, log_last_send_t: The packet log's length, newest seq (−1)
            and newest send time (−inf).
    """

    built: bool = False
    start: np.ndarray | None = None
    synced_t: float = 0.0
    ahead_t: float = 0.0
    catchup_t: float | None = None
    synced_sample_t: float = -np.inf
    catchup_from: float = 0.0
    ahead_horizon_from: float = 0.0
    ahead_stale: bool = False
    log_count: int = 0
    log_last_seq: int = -1
    log_last_send_t: float = -np.inf


class Build(NamedTuple):
    """Build the copies at rest at ``q`` (rad), at time 0, with an empty packet log."""

    q: np.ndarray


class Append(NamedTuple):
    """Append ``message`` (its own copy) to the copy's packet log, sent at ``send_t_s``."""

    send_t_s: float
    message: object


class RestSynced(NamedTuple):
    """Set the synchronised copy's time to ``t_s`` without running it (nothing sent yet)."""

    t_s: float


class AdvanceSynced(NamedTuple):
    """Advance the synchronised copy to ``t_s``."""

    t_s: float


class Resync(NamedTuple):
    """Set the synchronised copy's plant to the measured state of ``sample``."""

    sample: TelemetrySample


class StartCatchup(NamedTuple):
    """A catch-up copy from the synchronised one (time, state and parameters)."""


class AdvanceCatchup(NamedTuple):
    """Advance the catch-up copy to ``t_s``."""

    t_s: float


class Swap(NamedTuple):
    """The catch-up copy becomes the look-ahead shown; the old look-ahead, the spare."""


class AdvanceAhead(NamedTuple):
    """Advance the look-ahead to ``t_s``."""

    t_s: float


class PredictorState(NamedTuple):
    """Immutable (a deep copy is itself).

    Attributes:
        newest: The newest telemetry sample by its instant (None: none yet).
        recent: The samples of the last :data:`WINDOW_S` before the newest, by instant.
        ledger: Predictions not yet measured: grid index of the instant → (horizon s, tool
            position (3,) m).
        residuals: The latest residuals measured (a suffix of the run's log: those the shown
            residual can still be taken over).
        clock: The robot's clock (None: in one process).
        last_arrival_t_s: When the newest telemetry message arrived (local clock; −inf).
        last_telemetry_number, last_uplink_number: The arrival numbers read so far.
        pending: Packets heard on the bus not yet given to the copy: (seq, ground send time
            s, message), in the order heard.
        copies: Where the copies of the onboard chain are.
    """

    newest: TelemetrySample | None = None
    recent: tuple[TelemetrySample, ...] = ()
    ledger: FrozenMap = FrozenMap()
    residuals: tuple[Residual, ...] = ()
    clock: ClockState | None = None
    last_arrival_t_s: float = -np.inf
    last_telemetry_number: int = 0
    last_uplink_number: int = 0
    pending: tuple[tuple[int, float, object], ...] = ()
    copies: Copies = Copies()

    def __deepcopy__(self, memo):
        return self


def predictor_initial_state(params: PredictorParams, start=None) -> PredictorState:
    """No telemetry, no prediction; the clock unknown; the copies built at ``start`` (rad,
    (J,); None: not yet)."""
    copies = Copies() if start is None else Copies(built=True,
                                                   start=np.array(start, dtype=float))
    return PredictorState(clock=None if params.clock is None else ClockState(), copies=copies)


class Received(NamedTuple):
    """What an update received: the new telemetry samples (arrival order), the residuals
    measured with them, and what the system does to its copies (:class:`Build`,
    :class:`Append`, in order)."""

    samples: tuple[TelemetrySample, ...]
    residuals: tuple[Residual, ...]
    actions: tuple = ()


def receive_step(params: PredictorParams, state: PredictorState, telemetry_packets,
                 uplink_packets, local_t_s: float,
                 uplink_message=None) -> tuple[PredictorState, Received]:
    """New telemetry and the ground's packets taken in at ``local_t_s``.

    Each valid sample sets the arrival time and goes to the clock; the batch's newest message
    (by send time) dates the robot's clock; on the bus each packet heard goes to the clock
    and waits (:attr:`PredictorState.pending`). The packets go to the copy's log
    (:func:`_to_the_copies`). Then each sample (arrival order) measures the prediction made
    for its instant, if one was (a sample off the grid measures none), and the newest sample
    and the window of samples follow.
    """
    state, samples = _receive(params, state, telemetry_packets, uplink_packets, local_t_s)
    state, actions = _to_the_copies(params, state, samples, uplink_message)
    state, received = _take_samples(params, state, samples)
    return state, received._replace(actions=actions)


def _receive(params: PredictorParams, state: PredictorState, telemetry_packets,
             uplink_packets, local_t_s: float) -> tuple[PredictorState, list]:
    """The telemetry decoded, the clock and the packets heard followed."""
    number, statuses = decode_new(telemetry_packets, state.last_telemetry_number,
                                  lcmt_onboard_joint_status)
    samples = []
    arrival, clock = state.last_arrival_t_s, state.clock
    for status in statuses:
        sample = telemetry_sample(status, local_t_s, params.num_joints)
        if sample is not None:
            samples.append(sample)
            arrival = local_t_s
            if clock is not None:
                clock = clock_telemetry(params.clock, clock, sample)
    if samples and clock is not None:
        clock = clock_newest(params.clock, clock, max(samples, key=lambda s: s.sent_t_s))
    state = state._replace(last_telemetry_number=number, last_arrival_t_s=arrival)
    if clock is not None:
        uplink, commands = decode_new(uplink_packets, state.last_uplink_number,
                                      lcmt_teleop_joint_command)
        pending = list(state.pending)
        for msg in commands:
            clock = clock_packet(params.clock, clock, int(msg.seq), msg.utime * 1e-6)
            pending.append((int(msg.seq), msg.utime * 1e-6, msg))
        state = state._replace(last_uplink_number=uplink, pending=tuple(pending))
    return state._replace(clock=clock), samples


def _appended(copies: Copies, send_t_s: float, message) -> Copies:
    return copies._replace(log_count=copies.log_count + 1, log_last_seq=int(message.seq),
                           log_last_send_t=float(send_t_s))


def _to_the_copies(params: PredictorParams, state: PredictorState, samples,
                   uplink_message) -> tuple[PredictorState, tuple]:
    """In one process, the ground's new packet (a seq above the log's) into the copy's log,
    sent at its ``utime``. On the bus: a copy built at the robot's commanded pose if the
    first telemetry says it is not where the copy was built; once the clock is known, the
    packets heard (by seq, each above the log's) placed on the robot's clock, never before
    the log's last; one sent before the look-ahead's time makes it stale."""
    copies, actions = state.copies, []
    if state.clock is None:
        msg = uplink_message
        if msg is not None and msg.seq >= 0 and msg.seq > copies.log_last_seq:
            actions.append(Append(msg.utime * 1e-6, copy.deepcopy(msg)))
            copies = _appended(copies, msg.utime * 1e-6, msg)
        return state._replace(copies=copies), tuple(actions)
    if samples and copies.synced_sample_t == -np.inf and (
            not copies.built or np.max(np.abs(samples[-1].q_commanded - copies.start))
            > 1e-6):
        # The robot is not where the copy was built: a copy from its commanded pose.
        actions.append(Build(samples[-1].q_commanded))
        copies = copies._replace(built=True, start=np.array(samples[-1].q_commanded,
                                                            dtype=float),
                                 synced_t=0.0, ahead_t=0.0, catchup_t=None, log_count=0,
                                 log_last_seq=-1, log_last_send_t=-np.inf)
    if copies.built and clock_ready(state.clock):
        state, pending = take_pending(state)
        ahead = copies.ahead_t
        for seq, sent, msg in pending:
            if seq > copies.log_last_seq:
                send = max(sent + state.clock.robot_minus_ground, copies.log_last_send_t)
                actions.append(Append(send, for_the_copy(msg)))
                copies = _appended(copies, send, msg)
                # Heard after the look-ahead passed it: the look-ahead starts again.
                copies = copies._replace(ahead_stale=copies.ahead_stale | (send <= ahead))
    return state._replace(copies=copies), tuple(actions)


def for_the_copy(msg):
    """A packet as the copy's receiver takes it: the copy has no epoch, session or key (the
    operator already trusts what it heard the ground send)."""
    packet = copy.deepcopy(msg)
    packet.onboard_epoch = 0
    packet.session_id = 0
    packet.auth_tag_size = 0
    packet.auth_tag = b""
    return packet


def _take_samples(params: PredictorParams, state: PredictorState,
                  samples: list[TelemetrySample]) -> tuple[PredictorState, Received]:
    """The samples measured, the newest and the window followed."""
    ledger, newest, measured = state.ledger, state.newest, []
    recent = list(state.recent)
    for sample in samples:
        ledger, residual = _measure(params, ledger, sample)
        if residual is not None:
            measured.append(residual)
        if newest is None or sample.sample_t_s > newest.sample_t_s:
            newest = sample
        recent.append(sample)
    if recent:
        recent.sort(key=lambda sample: sample.sample_t_s)
        horizon_start = recent[-1].sample_t_s - WINDOW_S
        while recent and recent[0].sample_t_s < horizon_start:
            del recent[0]
    residuals = _residual_window(params, state.residuals + tuple(measured), ledger, newest)
    return (state._replace(ledger=ledger, newest=newest, recent=tuple(recent),
                           residuals=residuals),
            Received(tuple(samples), tuple(measured)))


def _measure(params: PredictorParams, ledger: FrozenMap, sample: TelemetrySample):
    """(the ledger, the residual of the prediction made for this sample's instant or
    None)."""
    grid = params.sample_period_s
    key = int(round(sample.sample_t_s / grid))
    if abs(key * grid - sample.sample_t_s) > 1e-6:
        return ledger, None    # a sample off the grid
    made = ledger.get(key)
    if made is None:
        return ledger, None
    horizon, tool = made
    residual = float(np.linalg.norm(tool - sample.tool_position_m))
    return ledger.without((key,)), Residual(sample.sample_t_s, horizon, tool,
                                            sample.tool_position_m.copy(), residual)


def _residual_window(params: PredictorParams, residuals: tuple[Residual, ...],
                     ledger: FrozenMap, newest: TelemetrySample | None) -> tuple[Residual, ...]:
    """The residuals :func:`largest_recent` can still reach: at most ``residual_history``,
    without those older than the window before any instant a residual is or will be
    measured at (the newest's, an instant in the ledger, the newest sample's: predictions
    before it are dropped unmeasured)."""
    residuals = residuals[-params.residual_history:] if params.residual_history > 0 else ()
    if not residuals:
        return residuals
    bound = min([residuals[-1].t_s] + ([] if newest is None else [newest.sample_t_s])
                + [key * params.sample_period_s for key in ledger])
    oldest = bound - params.residual_window_s - 1e-5
    start = 0
    while start < len(residuals) and residuals[start].t_s < oldest:
        start += 1
    return residuals[start:]


def largest_recent(residuals: Sequence[Residual], window_s: float) -> float:
    """The largest residual over the last ``window_s`` of the newest one's instant, going
    back from the newest to the first older one (NaN: none)."""
    if not residuals:
        return float("nan")
    newest = residuals[-1].t_s
    largest = 0.0
    for residual in reversed(residuals):
        if residual.t_s < newest - window_s:
            break
        largest = max(largest, residual.residual_m)
    return largest


def take_pending(state: PredictorState) -> tuple[PredictorState, tuple]:
    """(the state without its pending packets, those packets by seq)."""
    return (state._replace(pending=()),
            tuple(sorted(state.pending, key=lambda item: item[0])))


def prediction_now(params: PredictorParams, state: PredictorState,
                   local_t_s: float) -> float | None:
    """Now on the copy's clock (the robot's), on the sample grid; None if unknown."""
    if state.clock is None:
        now = local_t_s
    elif state.clock.robot_minus_local is None:
        return None
    else:
        now = local_t_s + state.clock.robot_minus_local
    # The next instant of the grid: a prediction is for an instant whose telemetry has
    # not been taken yet (three processes on one host hear the robot within a
    # millisecond of its publishing).
    grid = params.sample_period_s
    return grid * np.ceil(now / grid - 1e-9)


def _known_until(params: PredictorParams, copies: Copies, now: float) -> float:
    """Up to when (the copy's clock) the packets that reach the robot are known: in one
    process, always; on the bus, until the next packet is due (the last heard one's
    time + an uplink period), or now if the ground has gone quiet."""
    if params.clock is None:
        return np.inf
    if copies.log_count == 0:
        return now
    due = copies.log_last_send_t + params.uplink_period_s
    return now if now > due + params.uplink_period_s else due


def _usable_sample(params: PredictorParams, state: PredictorState,
                   now: float) -> TelemetrySample | None:
    """The newest telemetry sample the copy may be synchronised on: at most what the
    packets known let it reach (None if none is)."""
    limit = _known_until(params, state.copies, now)
    for sample in reversed(state.recent):
        if sample.sample_t_s <= limit + 1e-9:
            return sample
    return None


def _follow_telemetry(params: PredictorParams, state: PredictorState, now: float,
                      actions: list) -> Copies:
    """The synchronised copy kept at the newest telemetry it may use (a little each update),
    its plant re-synchronised there every ``resync_period_s``."""
    copies = state.copies
    sample = _usable_sample(params, state, now)
    if sample is None:
        return copies
    if params.clock is not None and copies.log_count == 0:
        # Nothing sent yet: the copy rests until the robot's clock reads this (its clock
        # started long before the console's).
        if sample.sample_t_s > copies.synced_t:
            actions.append(RestSynced(sample.sample_t_s))
            copies = copies._replace(synced_t=sample.sample_t_s)
    elif sample.sample_t_s > copies.synced_t:
        actions.append(AdvanceSynced(sample.sample_t_s))
        copies = copies._replace(synced_t=sample.sample_t_s)
    due = sample.sample_t_s >= copies.synced_sample_t + params.resync_period_s - 1e-9
    if due and copies.catchup_t is None and abs(copies.synced_t - sample.sample_t_s) < 1e-9:
        # Re-synchronise: the copy at the sample's instant, with the measured state.
        actions.append(Resync(sample))
        copies = copies._replace(synced_sample_t=sample.sample_t_s, ahead_stale=True)
    return copies


def advance_step(params: PredictorParams, state: PredictorState,
                 now: float) -> tuple[PredictorState, tuple]:
    """What the copies do to reach ``now`` (the copy's clock): the synchronised copy follows
    the telemetry; a stale look-ahead starts a catch-up from it, brought up to now by at
    most ``catchup_budget_s`` of copy-time per update (a long horizon is caught up over
    several updates instead of one late tick) while the shown look-ahead runs on, and shown
    once it is there; the look-ahead advanced to now."""
    actions = []
    copies = _follow_telemetry(params, state, now, actions)
    if copies.catchup_t is None and copies.ahead_stale:
        actions.append(StartCatchup())
        copies = copies._replace(catchup_t=copies.synced_t, catchup_from=copies.synced_t,
                                 ahead_stale=False)
    if copies.catchup_t is not None:
        target = min(now, copies.catchup_t + params.catchup_budget_s)
        if target > copies.catchup_t:
            actions.append(AdvanceCatchup(target))
            copies = copies._replace(catchup_t=target)
        if copies.catchup_t >= now - 1e-9:
            actions.append(Swap())
            copies = copies._replace(ahead_t=copies.catchup_t, catchup_t=None,
                                     ahead_horizon_from=copies.catchup_from)
    if now > copies.ahead_t:
        actions.append(AdvanceAhead(now))
        copies = copies._replace(ahead_t=now)
    return state._replace(copies=copies), tuple(actions)


def record_step(params: PredictorParams, state: PredictorState, *, now: float,
                horizon_s: float, tool: np.ndarray, q: np.ndarray, local_t_s: float,
                view: PredictorView) -> tuple[PredictorState, PredictorView]:
    """The prediction for ``now`` (the copy's tool position and link angles, ``horizon_s``
    ahead of the telemetry it was synchronised on) kept until its sample comes, those older
    than the newest sample dropped (never to be measured), and what the outputs show
    (``view``: the last shown, for what no telemetry has said yet)."""
    grid = params.sample_period_s
    ledger = state.ledger.set(int(round(now / grid)), (horizon_s, tool))
    newest = state.newest
    if newest is not None:
        ledger = ledger.without(
            [k for k in ledger if k * grid < newest.sample_t_s - 1e-9])
    return state._replace(ledger=ledger), PredictorView(
        q_predicted=q, tool_predicted=tool,
        q_received=view.q_received if newest is None else newest.q_link,
        tool_received=view.tool_received if newest is None else newest.tool_position_m,
        telemetry_age_s=np.inf if newest is None else now - newest.sample_t_s,
        telemetry_silence_s=local_t_s - state.last_arrival_t_s,
        residual_m=largest_recent(state.residuals, params.residual_window_s),
        guard_mode=-1.0 if newest is None else float(newest.guard_mode),
        stream_distance_rad=(np.nan if newest is None else newest.stream_distance_rad))
