"""The predicted robot: where the robot is now, while its telemetry is still on the way.

The telemetry the ground receives is old by the downlink's delay; the commands the ground
sent take the uplink's delay and the 0.75 s FIFO before they move the robot. Bejczy's
phantom robot (and ROTEX, ETS-VII after it) shows the operator a model of the robot run
ahead of the telemetry. Here that model is a *copy of the deployed onboard chain* (the
receiver, the link guard, the command interpolator and the scenario's flexible plant, built
by the caller: :class:`PredictorReplica`) driven by the packets the ground has already sent
(:class:`~telesmooth.systems.packet_replay.PacketLog`), delivered after the link's nominal
delay:

* the copy is **re-synchronised from each telemetry sample**: advanced to the instant the
  robot was sampled (the sample's own time, ``sample_utime``), its plant's state (motor and
  link angles and rates) replaced by the measured one;
* from there it is **run ahead to now** (a second context, copied from the synchronised one),
  on the commands sent meanwhile: the predicted robot. Without new telemetry (an outage)
  the look-ahead keeps running on the commands sent.

**The prediction is measured.** Each prediction is kept with the instant it is for; when the
telemetry sample of that instant arrives, the residual ‖predicted − measured tool
position‖ is logged (:attr:`RobotPredictor.residuals`, with the horizon the prediction had:
how far ahead of its newest telemetry it ran). With the plant the robot really has and a
clean link it is the integrators' difference (micrometres); a model that is off, or a link
that does other than the nominal delay, shows in it.

The copy's simulators live outside the Drake Context (a Context cannot hold a Simulator):
run the diagram that holds a :class:`RobotPredictor` once, in one Simulator, as
:func:`~telesmooth.diagrams.teleop.MakeTeleopDiagram` does. Its outputs are computed in its
periodic update and kept in an abstract state, so they are what the Context says.
"""

from __future__ import annotations

import copy
import dataclasses
from collections.abc import Callable
from typing import NamedTuple

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.analysis import InitializeParams
from pydrake.systems.framework import LeafSystem

from telesmooth.lcm_types import (
    decode_exact,
    lcmt_onboard_joint_status,
    lcmt_teleop_joint_command,
)
from telesmooth.systems.packet_replay import PacketLog
from telesmooth.systems.timing import check_period

__all__ = ["PredictorReplica", "PredictorView", "Residual", "RobotPredictor",
           "TelemetrySample"]


@dataclasses.dataclass(frozen=True)
class PredictorReplica:
    """The copy of the onboard chain the predictor runs.

    Attributes:
        diagram: A built diagram: ``PacketReplay(packets)`` → link → receiver → guard →
            ``robot`` (the same builders as the deployed chain).
        robot: Its :class:`~telesmooth.systems.flexible_arm.FlexibleJointArm` (the ground's
            model of the plant; its tracker noise-free).
        packets: The log the replay reads: the predictor appends each packet the ground sends.
        MakeSimulator: diagram → a Simulator with the plant's integrator
            (:func:`~telesmooth.systems.flexible_arm.MakeSimulator`).
    """

    diagram: object
    robot: object
    packets: PacketLog
    MakeSimulator: Callable


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
    return TelemetrySample(
        sample_t_s=msg.sample_utime * 1e-6, sent_t_s=msg.utime * 1e-6,
        arrival_t_s=float(arrival_t_s),
        q_link=arrays[0], q_motor=arrays[1], v_link=arrays[2], v_motor=arrays[3],
        tool_position_m=np.array(msg.tool_position_measured, dtype=float),
        guard_mode=int(msg.guard_mode), stream_distance_rad=float(msg.stream_distance_rad),
        last_command_seq=int(msg.last_command_seq),
        q_commanded=np.array(msg.joint_position_commanded, dtype=float))


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

    Until the telemetry has named an accepted packet, packets wait (:meth:`ready`).
    """

    def __init__(self, *, poll_period_s: float, publish_offset_s: float,
                 batch_period_s: float = 0.04, window: int = 50):
        self._poll = float(poll_period_s)
        self._publish = float(publish_offset_s)
        self._batch = float(batch_period_s)
        self._offsets: list[float] = []
        self._ground_offsets: list[float] = []
        self._window = int(window)
        self.robot_minus_local: float | None = None
        self.robot_minus_ground: float | None = None
        self._accepted: dict[int, float] = {}
        self._sent: dict[int, float] = {}

    def newest(self, sample: TelemetrySample) -> None:
        """The newest message of a batch: its send time against when it was seen."""
        self._offsets.append(sample.sent_t_s - sample.arrival_t_s)
        del self._offsets[:-self._window]
        self.robot_minus_local = float(np.median(self._offsets)) + 0.5 * self._batch

    def telemetry(self, sample: TelemetrySample) -> None:
        k = sample.last_command_seq
        if k >= 0 and k not in self._accepted:
            # The first message that names it was published publish_offset_s after the poll
            # that accepted it.
            self._accepted[k] = sample.sent_t_s - self._publish
            self._match(k)

    def packet(self, seq: int, ground_t_s: float) -> None:
        self._sent[seq] = ground_t_s
        self._match(seq)

    def _match(self, seq: int) -> None:
        if seq in self._accepted and seq in self._sent:
            # The median over the last packets: a ground process that runs late and catches
            # up stamps some packets early against its steady offset (the smallest
            # offset, taken before, put the copy's commands 0.12 s ahead of the robot's
            # under load); acceptance falls anywhere in a poll, half a poll on average.
            self._ground_offsets.append(self._accepted[seq] - self._sent[seq])
            del self._ground_offsets[:-self._window]
            self.robot_minus_ground = float(np.median(self._ground_offsets)) - 0.5 * self._poll

    def ready(self) -> bool:
        return self.robot_minus_local is not None and self.robot_minus_ground is not None

    def now(self, local_t_s: float) -> float:
        return local_t_s + self.robot_minus_local

    def send_time(self, ground_t_s: float) -> float:
        return ground_t_s + self.robot_minus_ground





class RobotPredictor(LeafSystem):
    r"""Runs a copy of the onboard chain ahead of the telemetry (module docstring).

    .. pydrake_system::

        name: RobotPredictor
        input_ports:
        - uplink_message
        - uplink_packets
        - telemetry_packets
        output_ports:
        - q_predicted
        - tool_predicted
        - q_received
        - tool_received
        - telemetry_age
        - telemetry_silence
        - residual
        - robot_guard_mode
        - robot_stream_distance

    - ``uplink_message``: in one process, the ground's current ``lcmt_teleop_joint_command``
      (the sender's output); a packet with a seq above the last one is appended to the
      copy's log, sent at its ``utime``. ``uplink_packets``: with ``remote=True`` (the
      operator's own process), the packets the ground sent as heard on the bus (a
      subscriber's ``packets``), placed on the robot's clock by a :class:`RemoteClock`.
    - ``telemetry_packets``: the telemetry delivered to the ground, as a ``LinkChannel``'s
      ``packets`` output (arrival number, encoded ``lcmt_onboard_joint_status``).
    - ``q_predicted`` (J, rad), ``tool_predicted`` (3, m): the copy at the last update's time.
    - ``q_received`` (J), ``tool_received`` (3): the newest telemetry (NaN before any).
    - ``telemetry_age`` (1, s): now − the newest sample's instant; ``telemetry_silence``
      (1, s): now − the newest message's arrival (inf before any telemetry).
    - ``residual`` (1, m): the largest residual measured over the last
      ``residual_window_s`` of predicted instants (NaN before any): a model that is off shows
      while the robot moves, not only at the instant it moved most.
    - ``robot_guard_mode`` (1): the robot's link-guard mode from its telemetry (−1: none yet);
      ``robot_stream_distance`` (1, rad): how far its command is from its newest packet.

    Update: periodic unrestricted, every ``period_s`` from 0 (the display's rate); the copy
    is re-synchronised from the newest telemetry at most every ``resync_period_s`` (default
    every update) and otherwise continues. Predictions are made for instants on the
    telemetry's sample grid (``sample_period_s``), so that each can be measured.
    """

    def __init__(self, replica_factory: Callable[[np.ndarray], PredictorReplica], *,
                 num_joints: int, period_s: float = 0.04, resync_period_s: float | None = None,
                 initial_position_rad=None, remote: bool = False,
                 sample_period_s: float = 0.01, poll_period_s: float = 0.01,
                 publish_offset_s: float = 0.001, uplink_period_s: float = 0.25,
                 residual_window_s: float = 2.0, residual_history: int = 100_000,
                 wall_clock: Callable[[], float] | None = None):
        """Args:
            replica_factory: start pose (J,) → the :class:`PredictorReplica` to run.
            initial_position_rad: The robot's start pose: the copy is built at once (in one
                process it is required); with ``remote=True`` a robot whose first telemetry
                says it is commanded elsewhere gets a copy built there (without a start
                pose, at the first telemetry).
            wall_clock: On the bus, in a live process: a monotonic clock (s), e.g.
                ``time.perf_counter``. The robot's clock is then estimated against it
                instead of this process's simulated time, which lags the wall clock by
                however late the process runs (a busy machine): predicting on that lag
                put the copy up to a few hundred milliseconds ahead of the robot, past the
                packets it had heard. None: the simulated time (one process, tests).
        """
        super().__init__()
        check_period("RobotPredictor.period_s", period_s)
        check_period("RobotPredictor.sample_period_s", sample_period_s)
        if resync_period_s is not None:
            check_period("RobotPredictor.resync_period_s", resync_period_s)
        # Re-synchronising costs a run over the whole horizon; in between the look-ahead
        # only continues (the same model, the same commands).
        self._resync_period = float(period_s if resync_period_s is None else resync_period_s)
        self._factory = replica_factory
        self._n = int(num_joints)
        self._period = float(period_s)
        self._grid = float(sample_period_s)
        self._remote = bool(remote)
        self._clock = (RemoteClock(poll_period_s=poll_period_s, publish_offset_s=publish_offset_s,
                                   batch_period_s=period_s) if remote else None)
        self._uplink_period = float(uplink_period_s)
        self._wall_clock = wall_clock
        self._wall_minus_sim: float | None = None
        self._recent: list[TelemetrySample] = []   # the last seconds of telemetry
        self._ahead_stale = False
        self._pending: list[tuple[int, float, object]] = []
        self._replica = self._synced = self._ahead = None
        self._catchup = self._spare = None
        self._catchup_from = self._ahead_horizon_from = 0.0
        self._catchup_budget = 3.0 * float(period_s)
        self._start = None
        if initial_position_rad is not None:
            # Built now (a build takes about a second: not in the middle of a live run).
            self._build(np.asarray(initial_position_rad, dtype=float))
        elif not remote:
            raise ValueError("RobotPredictor: initial_position_rad is needed in one process")
        self._synced_sample_t = -np.inf
        self._last_packet_number = 0
        self._last_uplink_number = 0
        self._last_arrival_t = -np.inf
        self._newest: TelemetrySample | None = None
        self._predictions: dict[int, tuple[float, np.ndarray]] = {}
        self.residuals: list[Residual] = []
        """Every measured prediction, in order (the run's ``predicted.csv``)."""
        self.predictions: list[tuple[float, float, np.ndarray, np.ndarray]] = []
        """Every prediction: (instant, horizon, tool position, q_link)."""
        self._residual_history = int(residual_history)
        self._residual_window = float(residual_window_s)
        nan_q, nan_p = np.full(self._n, np.nan), np.full(3, np.nan)
        if self._ahead is not None:
            tool0, q0 = self._predicted(self._ahead.get_context())
        else:
            tool0, q0 = nan_p, nan_q
        view = PredictorView(q_predicted=q0, tool_predicted=tool0, q_received=nan_q,
                             tool_received=nan_p, telemetry_age_s=np.inf,
                             telemetry_silence_s=np.inf, residual_m=np.nan, guard_mode=-1.0,
                             stream_distance_rad=np.nan)
        self._view = self.DeclareAbstractState(AbstractValue.Make(view))
        self._uplink_input = self.DeclareAbstractInputPort(
            "uplink_message", AbstractValue.Make(lcmt_teleop_joint_command()))
        self._uplink_packets_input = self.DeclareAbstractInputPort(
            "uplink_packets", AbstractValue.Make(()))
        self._telemetry_input = self.DeclareAbstractInputPort(
            "telemetry_packets", AbstractValue.Make(()))
        self.DeclarePeriodicUnrestrictedUpdateEvent(self._period, 0.0, self._update)

        def output(name, size, field):
            def calc(context, out):
                value = getattr(context.get_abstract_state(self._view).get_value(), field)
                out.SetFromVector(np.atleast_1d(np.asarray(value, dtype=float)))
            return self.DeclareVectorOutputPort(name, size, calc, {self.all_state_ticket()})

        self._outputs = {
            "q_predicted": output("q_predicted", self._n, "q_predicted"),
            "tool_predicted": output("tool_predicted", 3, "tool_predicted"),
            "q_received": output("q_received", self._n, "q_received"),
            "tool_received": output("tool_received", 3, "tool_received"),
            "telemetry_age": output("telemetry_age", 1, "telemetry_age_s"),
            "telemetry_silence": output("telemetry_silence", 1, "telemetry_silence_s"),
            "residual": output("residual", 1, "residual_m"),
            "robot_guard_mode": output("robot_guard_mode", 1, "guard_mode"),
            "robot_stream_distance": output("robot_stream_distance", 1, "stream_distance_rad"),
        }

    def _build(self, q0: np.ndarray) -> None:
        self._start = np.array(q0, dtype=float)
        self._replica = self._factory(q0)
        self._synced = self._replica.MakeSimulator(self._replica.diagram)
        self._ahead = self._replica.MakeSimulator(self._replica.diagram)
        self._spare = self._replica.MakeSimulator(self._replica.diagram)
        self._catchup = None
        self._synced.Initialize()
        self._ahead.get_mutable_context().SetTimeStateAndParametersFrom(
            self._synced.get_context())
        self._ahead.Initialize(InitializeParams(suppress_initialization_events=True))

    # -- accessors ------------------------------------------------------------------------

    def get_uplink_message_input_port(self):
        return self._uplink_input

    def get_uplink_packets_input_port(self):
        return self._uplink_packets_input

    def get_telemetry_packets_input_port(self):
        return self._telemetry_input

    def get_output(self, name: str):
        """The output port ``name`` (see the class docstring)."""
        return self._outputs[name]

    @property
    def newest_telemetry(self) -> TelemetrySample | None:
        return self._newest

    @property
    def clock(self) -> RemoteClock | None:
        return self._clock

    def view(self, context) -> PredictorView:
        return context.get_abstract_state(self._view).get_value()

    def recent_residual(self) -> float:
        """The largest residual over the last ``residual_window_s`` (NaN before any)."""
        if not self.residuals:
            return float("nan")
        newest = self.residuals[-1].t_s
        largest = 0.0
        for residual in reversed(self.residuals):
            if residual.t_s < newest - self._residual_window:
                break
            largest = max(largest, residual.residual_m)
        return largest

    # -- the update -----------------------------------------------------------------------

    def _predicted(self, replica_context) -> tuple[np.ndarray, np.ndarray]:
        """The copy's tool position (m, (3,)) and link angles (rad, (J,)) in a context."""
        robot = self._replica.robot
        plant_context = robot.plant.GetMyContextFromRoot(replica_context)
        state = robot.plant.GetPositionsAndVelocities(plant_context)
        record = robot.tracker.Record(np.array([replica_context.get_time()]), state[None, :])
        return record.tool_position_m[0], record.q_link[0]

    def _decode_new(self, packets, last_number: int, lcm_type):
        """(the newest arrival number, the new packets decoded)."""
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

    def _local_time(self, context) -> float:
        """This process's now (s): its simulated time, or with a ``wall_clock`` the wall
        clock's, counted from the simulated time of the first update."""
        if self._wall_clock is None:
            return context.get_time()
        wall = float(self._wall_clock())
        if self._wall_minus_sim is None:
            self._wall_minus_sim = wall - context.get_time()
        return wall - self._wall_minus_sim

    def _ingest(self, context) -> list[TelemetrySample]:
        """New packets into the copy's log; new telemetry decoded (in arrival order)."""
        now = self._local_time(context)
        self._last_packet_number, statuses = self._decode_new(
            self._telemetry_input.Eval(context), self._last_packet_number,
            lcmt_onboard_joint_status)
        samples = []
        for status in statuses:
            sample = telemetry_sample(status, now, self._n)
            if sample is not None:
                samples.append(sample)
                self._last_arrival_t = now
                if self._clock is not None:
                    self._clock.telemetry(sample)
        if samples and self._clock is not None:
            self._clock.newest(max(samples, key=lambda sample: sample.sent_t_s))
        if not self._remote:
            msg = self._uplink_input.Eval(context)
            if msg.seq >= 0 and msg.seq > self._replica.packets.last_seq():
                self._replica.packets.append(msg.utime * 1e-6, copy.deepcopy(msg))
            return samples
        self._last_uplink_number, commands = self._decode_new(
            self._uplink_packets_input.Eval(context), self._last_uplink_number,
            lcmt_teleop_joint_command)
        for msg in commands:
            self._clock.packet(int(msg.seq), msg.utime * 1e-6)
            self._pending.append((int(msg.seq), msg.utime * 1e-6, msg))
        if samples and self._synced_sample_t == -np.inf and (
                self._replica is None or np.max(np.abs(samples[-1].q_commanded - self._start))
                > 1e-6):
            # The robot is not where the copy was built: a copy from its commanded pose.
            self._build(samples[-1].q_commanded)
        if self._replica is not None and self._clock.ready():
            log = self._replica.packets
            ahead = self._ahead.get_context().get_time()
            for seq, sent, msg in sorted(self._pending, key=lambda item: item[0]):
                if seq > log.last_seq():
                    send = max(self._clock.send_time(sent), log.last_send_time())
                    log.append(send, _for_the_copy(msg))
                    # Heard after the look-ahead passed it: the look-ahead starts again.
                    self._ahead_stale |= send <= ahead
            self._pending.clear()
        return samples

    def _follow_telemetry(self, now: float) -> None:
        """Keeps the synchronised copy at the newest telemetry it may use (a little each
        update), and re-synchronises its plant there every ``resync_period_s``."""
        sample = self._usable_sample(now)
        if sample is None:
            return
        synced = self._synced.get_context()
        if self._remote and len(self._replica.packets) == 0:
            # Nothing sent yet: the copy rests until the robot's clock reads this (its clock
            # started long before the console's).
            if sample.sample_t_s > synced.get_time():
                self._synced.get_mutable_context().SetTime(sample.sample_t_s)
                self._synced.Initialize(InitializeParams(suppress_initialization_events=True))
        elif sample.sample_t_s > synced.get_time():
            self._synced.AdvanceTo(sample.sample_t_s)
        due = sample.sample_t_s >= self._synced_sample_t + self._resync_period - 1e-9
        if due and self._catchup is None and abs(
                self._synced.get_context().get_time() - sample.sample_t_s) < 1e-9:
            # Re-synchronise: the copy at the sample's instant, with the measured state.
            self._replica.robot.SetMeasuredState(
                self._synced.get_mutable_context(), q_link=sample.q_link,
                q_motor=sample.q_motor, v_link=sample.v_link, v_motor=sample.v_motor)
            self._synced_sample_t = sample.sample_t_s
            self._ahead_stale = True

    def _start_catchup(self) -> None:
        """A new look-ahead from the synchronised copy, brought up to now over the next
        updates (:attr:`_catchup`); the shown one runs on until it is."""
        if self._spare is None:
            self._spare = self._replica.MakeSimulator(self._replica.diagram)
        self._catchup, self._spare = self._spare, None
        self._catchup.get_mutable_context().SetTimeStateAndParametersFrom(
            self._synced.get_context())
        self._catchup.Initialize(InitializeParams(suppress_initialization_events=True))
        self._catchup_from = self._synced.get_context().get_time()
        self._ahead_stale = False

    def _known_until(self, now: float) -> float:
        """Up to when (the copy's clock) the packets that reach the robot are known: in one
        process, always; on the bus, until the next packet is due (the last heard one's
        time + an uplink period), or now if the ground has gone quiet."""
        if not self._remote:
            return np.inf
        log = self._replica.packets
        if len(log) == 0:
            return now
        due = log.last_send_time() + self._uplink_period
        return now if now > due + self._uplink_period else due

    def _usable_sample(self, now: float) -> TelemetrySample | None:
        """The newest telemetry sample the copy may be synchronised on: at most what the
        packets known let it reach (None if none is)."""
        limit = self._known_until(now)
        for sample in reversed(self._recent):
            if sample.sample_t_s <= limit + 1e-9:
                return sample
        return None

    def _measure(self, sample: TelemetrySample) -> None:
        """The residual of the prediction made for this sample's instant, if one was."""
        key = int(round(sample.sample_t_s / self._grid))
        if abs(key * self._grid - sample.sample_t_s) > 1e-6:
            return    # a sample off the grid
        made = self._predictions.pop(key, None)
        if made is None:
            return
        horizon, tool = made
        residual = float(np.linalg.norm(tool - sample.tool_position_m))
        self.residuals.append(Residual(sample.sample_t_s, horizon, tool,
                                       sample.tool_position_m.copy(), residual))
        if len(self.residuals) > self._residual_history:
            del self.residuals[0]

    def _now(self, local_t: float) -> float | None:
        """Now on the copy's clock (the robot's), on the sample grid; None if unknown."""
        if self._clock is None:
            now = local_t
        elif self._clock.robot_minus_local is None:
            return None
        else:
            now = self._clock.now(local_t)
        # The next instant of the grid: a prediction is for an instant whose telemetry has
        # not been taken yet (three processes on one host hear the robot within a
        # millisecond of its publishing).
        return self._grid * np.ceil(now / self._grid - 1e-9)

    def _update(self, context, state) -> None:
        samples = self._ingest(context)
        local = self._local_time(context)
        view = self.view(context)
        newest = self._newest
        for sample in samples:
            self._measure(sample)
            if newest is None or sample.sample_t_s > newest.sample_t_s:
                newest = sample
            self._recent.append(sample)
        self._newest = newest
        if self._recent:
            self._recent.sort(key=lambda sample: sample.sample_t_s)
            horizon_start = self._recent[-1].sample_t_s - 2.0
            while self._recent and self._recent[0].sample_t_s < horizon_start:
                del self._recent[0]
        now = self._now(local)
        if self._replica is None or now is None:
            return
        self._follow_telemetry(now)
        if self._catchup is None and self._ahead_stale:
            self._start_catchup()
        if self._catchup is not None:
            # At most the budget of copy-time per update: a long horizon (a slow downlink)
            # is caught up over several updates instead of one late tick.
            target = min(now, self._catchup.get_context().get_time() + self._catchup_budget)
            if target > self._catchup.get_context().get_time():
                self._catchup.AdvanceTo(target)
            if self._catchup.get_context().get_time() >= now - 1e-9:
                self._ahead, self._spare, self._catchup = self._catchup, self._ahead, None
                self._ahead_horizon_from = self._catchup_from
        if now > self._ahead.get_context().get_time():
            self._ahead.AdvanceTo(now)
        tool, q = self._predicted(self._ahead.get_context())
        # How far ahead of the telemetry the look-ahead was synchronised on.
        horizon = now - self._ahead_horizon_from
        self._predictions[int(round(now / self._grid))] = (horizon, tool)
        self.predictions.append((now, horizon, tool, q))
        # Predictions older than the newest sample will never be measured.
        if newest is not None:
            stale = [k for k in self._predictions if k * self._grid < newest.sample_t_s - 1e-9]
            for k in stale:
                del self._predictions[k]
        state.get_mutable_abstract_state(self._view).set_value(PredictorView(
            q_predicted=q, tool_predicted=tool,
            q_received=view.q_received if newest is None else newest.q_link,
            tool_received=view.tool_received if newest is None else newest.tool_position_m,
            telemetry_age_s=np.inf if newest is None else now - newest.sample_t_s,
            telemetry_silence_s=local - self._last_arrival_t,
            residual_m=self.recent_residual(),
            guard_mode=-1.0 if newest is None else float(newest.guard_mode),
            stream_distance_rad=(np.nan if newest is None
                                 else newest.stream_distance_rad)))


def _for_the_copy(msg):
    """A packet as the copy's receiver takes it: the copy has no epoch, session or key (the
    operator already trusts what it heard the ground send)."""
    packet = copy.deepcopy(msg)
    packet.onboard_epoch = 0
    packet.session_id = 0
    packet.auth_tag_size = 0
    packet.auth_tag = b""
    return packet
