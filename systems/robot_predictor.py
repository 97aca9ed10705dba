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
        make_simulator: diagram → a Simulator with the plant's integrator
            (:func:`~telesmooth.systems.flexible_arm.make_simulator`).
    """

    diagram: object
    robot: object
    packets: PacketLog
    make_simulator: Callable


class TelemetrySample(NamedTuple):
    """One telemetry message as the predictor uses it (times in s, onboard clock)."""

    sample_t_s: float
    arrival_t_s: float
    q_link: np.ndarray
    q_motor: np.ndarray
    v_link: np.ndarray
    v_motor: np.ndarray
    tool_position_m: np.ndarray
    guard_mode: int
    stream_distance_rad: float
    last_command_seq: int


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
        sample_t_s=msg.sample_utime * 1e-6, arrival_t_s=float(arrival_t_s),
        q_link=arrays[0], q_motor=arrays[1], v_link=arrays[2], v_motor=arrays[3],
        tool_position_m=np.array(msg.tool_position_measured, dtype=float),
        guard_mode=int(msg.guard_mode), stream_distance_rad=float(msg.stream_distance_rad),
        last_command_seq=int(msg.last_command_seq))


class RobotPredictor(LeafSystem):
    r"""Runs a copy of the onboard chain ahead of the telemetry (module docstring).

    .. pydrake_system::

        name: RobotPredictor
        input_ports:
        - uplink_message
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

    - ``uplink_message``: the ground's current ``lcmt_teleop_joint_command`` (the sender's
      output); a packet with a seq above the last one is appended to the copy's log, sent
      at its ``utime``.
    - ``telemetry_packets``: the telemetry delivered to the ground, as a ``LinkChannel``'s
      ``packets`` output (arrival number, encoded ``lcmt_onboard_joint_status``).
    - ``q_predicted`` (J, rad), ``tool_predicted`` (3, m): the copy at the last update's time.
    - ``q_received`` (J), ``tool_received`` (3): the newest telemetry (NaN before any).
    - ``telemetry_age`` (1, s): update time − the newest sample's instant; ``telemetry_silence``
      (1, s): update time − its arrival (inf before any telemetry).
    - ``residual`` (1, m): the largest residual measured over the last
      ``residual_window_s`` of predicted instants (NaN before any): a model that is off shows
      while the robot moves, not only at the instant it moved most.
    - ``robot_guard_mode`` (1): the robot's link-guard mode from its telemetry (−1: none yet);
      ``robot_stream_distance`` (1, rad): how far its command is from its newest packet.

    Update: periodic unrestricted, every ``period_s`` from 0 (the display's rate); the copy
    is re-synchronised from the newest telemetry at most every ``resync_period_s`` (default
    every update) and otherwise continues.
    """

    def __init__(self, replica: PredictorReplica, *, num_joints: int, period_s: float = 0.04,
                 resync_period_s: float | None = None, initial_position_rad,
                 residual_window_s: float = 2.0, residual_history: int = 100_000):
        super().__init__()
        check_period("RobotPredictor.period_s", period_s)
        if resync_period_s is not None:
            check_period("RobotPredictor.resync_period_s", resync_period_s)
        # Re-synchronising costs a run over the whole horizon; in between the look-ahead
        # only continues (the same model, the same commands).
        self._resync_period = float(period_s if resync_period_s is None else resync_period_s)
        self._replica = replica
        self._n = int(num_joints)
        self._period = float(period_s)
        q0 = np.asarray(initial_position_rad, dtype=float)
        self._synced = replica.make_simulator(replica.diagram)
        self._ahead = replica.make_simulator(replica.diagram)
        self._synced.Initialize()
        self._ahead.get_mutable_context().SetTimeStateAndParametersFrom(
            self._synced.get_context())
        self._ahead.Initialize(InitializeParams(suppress_initialization_events=True))
        self._synced_sample_t = -np.inf
        self._last_packet_number = 0
        self._last_arrival_t = -np.inf
        self._newest: TelemetrySample | None = None
        self._predictions: dict[int, tuple[float, np.ndarray]] = {}
        self.residuals: list[Residual] = []
        """Every measured prediction, in order (the run's ``predicted.csv``)."""
        self.predictions: list[tuple[float, float, np.ndarray, np.ndarray]] = []
        """Every prediction: (instant, horizon, tool position, q_link)."""
        self._residual_history = int(residual_history)
        self._residual_window = float(residual_window_s)
        tool0, _ = self._predicted(self._ahead.get_context())
        nan_q, nan_p = np.full(self._n, np.nan), np.full(3, np.nan)
        view = PredictorView(q_predicted=q0.copy(), tool_predicted=tool0, q_received=nan_q,
                             tool_received=nan_p, telemetry_age_s=np.inf,
                             telemetry_silence_s=np.inf, residual_m=np.nan, guard_mode=-1.0,
                             stream_distance_rad=np.nan)
        self._view = self.DeclareAbstractState(AbstractValue.Make(view))
        self._uplink_input = self.DeclareAbstractInputPort(
            "uplink_message", AbstractValue.Make(lcmt_teleop_joint_command()))
        self._telemetry_input = self.DeclareAbstractInputPort(
            "telemetry_packets", AbstractValue.Make(()))
        self.DeclarePeriodicUnrestrictedUpdateEvent(self._period, 0.0, self._update)

        def output(name, size, field, scalar=False):
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

    # -- accessors ------------------------------------------------------------------------

    def get_uplink_message_input_port(self):
        return self._uplink_input

    def get_telemetry_packets_input_port(self):
        return self._telemetry_input

    def get_output(self, name: str):
        """The output port ``name`` (see the class docstring)."""
        return self._outputs[name]

    @property
    def newest_telemetry(self) -> TelemetrySample | None:
        return self._newest

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

    def _ingest(self, context) -> list[TelemetrySample]:
        """Appends a new packet to the copy's log; decodes new telemetry (in arrival order)."""
        msg = self._uplink_input.Eval(context)
        if msg.seq >= 0 and msg.seq > self._replica.packets.last_seq():
            self._replica.packets.append(msg.utime * 1e-6, copy.deepcopy(msg))
        samples = []
        now = context.get_time()
        for number, data in self._telemetry_input.Eval(context):
            if number <= self._last_packet_number:
                continue
            self._last_packet_number = number
            try:
                status = decode_exact(lcmt_onboard_joint_status, data)
            except Exception:  # noqa: BLE001 - garbage on the downlink is not telemetry
                continue
            sample = telemetry_sample(status, now, self._n)
            if sample is not None:
                samples.append(sample)
                self._last_arrival_t = now
        return samples

    def _measure(self, sample: TelemetrySample) -> None:
        """The residual of the prediction made for this sample's instant, if one was."""
        key = int(round(sample.sample_t_s / self._period))
        if abs(key * self._period - sample.sample_t_s) > 1e-6:
            return    # a sample between two predictions
        made = self._predictions.pop(key, None)
        if made is None:
            return
        horizon, tool = made
        residual = float(np.linalg.norm(tool - sample.tool_position_m))
        self.residuals.append(Residual(sample.sample_t_s, horizon, tool,
                                       sample.tool_position_m.copy(), residual))
        if len(self.residuals) > self._residual_history:
            del self.residuals[0]

    def _update(self, context, state) -> None:
        now = context.get_time()
        samples = self._ingest(context)
        view = self.view(context)
        newest = self._newest
        for sample in samples:
            self._measure(sample)
            if newest is None or sample.sample_t_s > newest.sample_t_s:
                newest = sample
        self._newest = newest
        if newest is not None and newest.sample_t_s >= (
                self._synced_sample_t + self._resync_period - 1e-9):
            # Re-synchronise: the copy at the sample's instant, with the measured state.
            if newest.sample_t_s > self._synced.get_context().get_time():
                self._synced.AdvanceTo(newest.sample_t_s)
            self._replica.robot.SetMeasuredState(
                self._synced.get_mutable_context(), q_link=newest.q_link,
                q_motor=newest.q_motor, v_link=newest.v_link, v_motor=newest.v_motor)
            self._synced_sample_t = newest.sample_t_s
            self._ahead.get_mutable_context().SetTimeStateAndParametersFrom(
                self._synced.get_context())
            self._ahead.Initialize(InitializeParams(suppress_initialization_events=True))
        if now > self._ahead.get_context().get_time():
            self._ahead.AdvanceTo(now)
        tool, q = self._predicted(self._ahead.get_context())
        # How far ahead of the telemetry the copy was last synchronised on.
        horizon = now - (self._synced_sample_t if newest is not None else 0.0)
        self._predictions[int(round(now / self._period))] = (horizon, tool)
        self.predictions.append((now, horizon, tool, q))
        # Predictions older than the newest sample will never be measured.
        if newest is not None:
            stale = [k for k in self._predictions if k * self._period < newest.sample_t_s - 1e-9]
            for k in stale:
                del self._predictions[k]
        residual = self.recent_residual()
        state.get_mutable_abstract_state(self._view).set_value(PredictorView(
            q_predicted=q, tool_predicted=tool,
            q_received=view.q_received if newest is None else newest.q_link,
            tool_received=view.tool_received if newest is None else newest.tool_position_m,
            telemetry_age_s=np.inf if newest is None else now - newest.sample_t_s,
            telemetry_silence_s=now - self._last_arrival_t,
            residual_m=residual,
            guard_mode=-1.0 if newest is None else float(newest.guard_mode),
            stream_distance_rad=(np.nan if newest is None
                                 else newest.stream_distance_rad)))
