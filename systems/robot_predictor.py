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

Everything the predictor decides (the telemetry it keeps, the robot's clock, the
predictions awaiting measurement and their residuals, the packets given to the copy, when
the copy is built, re-synchronised, caught up and advanced, and what its outputs show) is
the pure step of :mod:`telesmooth.link.prediction`
(:func:`~telesmooth.link.prediction.receive_step`,
:func:`~telesmooth.link.prediction.advance_step`,
:func:`~telesmooth.link.prediction.record_step`), its immutable state kept in an abstract
state of the Context beside the view. The copies themselves are Drake Simulators of a Drake
diagram, which no pure state can hold: they live on this system, outside the Drake Context
(a Context cannot hold a Simulator), and do what the step's actions say. Run the diagram
that holds a :class:`RobotPredictor` once, in one Simulator, as
:func:`~telesmooth.diagrams.teleop.MakeTeleopDiagram` does. Its outputs are computed in its
periodic update and kept in an abstract state, so they are what the Context says.
"""

from __future__ import annotations

import dataclasses
import numbers
from collections.abc import Callable

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.analysis import InitializeParams
from pydrake.systems.framework import LeafSystem

from telesmooth.lcm_types import lcmt_teleop_joint_command
from telesmooth.link.prediction import (
    AdvanceAhead,
    AdvanceCatchup,
    AdvanceSynced,
    Append,
    Build,
    ClockParams,
    PredictorParams,
    PredictorView,
    RemoteClock,
    Residual,
    RestSynced,
    Resync,
    StartCatchup,
    Swap,
    TelemetrySample,
    advance_step,
    largest_recent,
    prediction_now,
    predictor_initial_state,
    receive_step,
    record_step,
    telemetry_sample,
)
from telesmooth.systems.packet_replay import PacketLog
from telesmooth.systems.timing import check_period

__all__ = ["PredictorReplica", "PredictorView", "RemoteClock", "Residual", "RobotPredictor",
           "TelemetrySample", "telemetry_sample"]


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
        check_period("RobotPredictor.residual_window_s", residual_window_s)
        if isinstance(residual_history, bool) or not isinstance(
                residual_history, numbers.Integral) or residual_history < 0:
            raise ValueError(f"RobotPredictor.residual_history = {residual_history!r} must be "
                             "an integer >= 0")
        self._factory = replica_factory
        self._n = int(num_joints)
        self._period = float(period_s)
        self._remote = bool(remote)
        self._wall_clock = wall_clock
        self._wall_minus_sim: float | None = None
        self._replica = self._synced = self._ahead = None
        self._catchup = self._spare = None
        start = None
        if initial_position_rad is not None:
            # Built now (a build takes about a second: not in the middle of a live run).
            start = np.asarray(initial_position_rad, dtype=float)
            self._build(start)
        elif not remote:
            raise ValueError("RobotPredictor: initial_position_rad is needed in one process")
        # Re-synchronising costs a run over the whole horizon; in between the look-ahead
        # only continues (the same model, the same commands).
        self._params = PredictorParams(
            num_joints=self._n, sample_period_s=float(sample_period_s),
            residual_window_s=float(residual_window_s),
            residual_history=int(residual_history),
            clock=ClockParams(float(poll_period_s), float(publish_offset_s),
                              float(period_s)) if remote else None,
            resync_period_s=float(period_s if resync_period_s is None else resync_period_s),
            catchup_budget_s=3.0 * float(period_s), uplink_period_s=float(uplink_period_s))
        initial = predictor_initial_state(self._params, start)
        self._last = initial
        """The state the last update wrote (what :attr:`newest_telemetry` and :attr:`clock`
        say after a run)."""
        self.residuals: list[Residual] = []
        """Every measured prediction, in order (the run's ``predicted.csv``)."""
        self.predictions: list[tuple[float, float, np.ndarray, np.ndarray]] = []
        """Every prediction: (instant, horizon, tool position, q_link)."""
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
        self._state = self.DeclareAbstractState(AbstractValue.Make(initial))
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
        return self._last.newest

    @property
    def clock(self) -> RemoteClock | None:
        """The robot's clock as the last update left it (None: in one process): a snapshot
        over the immutable :class:`~telesmooth.link.prediction.ClockState`; calling its
        methods changes the snapshot, never the predictor."""
        if self._params.clock is None:
            return None
        clock = self._params.clock
        return RemoteClock(poll_period_s=clock.poll_period_s,
                           publish_offset_s=clock.publish_offset_s,
                           batch_period_s=clock.batch_period_s, window=clock.window,
                           state=self._last.clock)

    def view(self, context) -> PredictorView:
        return context.get_abstract_state(self._view).get_value()

    def recent_residual(self) -> float:
        """The largest residual over the last ``residual_window_s`` (NaN before any)."""
        return largest_recent(self.residuals, self._params.residual_window_s)

    # -- the update -----------------------------------------------------------------------

    def _predicted(self, replica_context) -> tuple[np.ndarray, np.ndarray]:
        """The copy's tool position (m, (3,)) and link angles (rad, (J,)) in a context."""
        robot = self._replica.robot
        plant_context = robot.plant.GetMyContextFromRoot(replica_context)
        state = robot.plant.GetPositionsAndVelocities(plant_context)
        record = robot.tracker.Record(np.array([replica_context.get_time()]), state[None, :])
        return record.tool_position_m[0], record.q_link[0]

    def _local_time(self, context) -> float:
        """This process's now (s): its simulated time, or with a ``wall_clock`` the wall
        clock's, counted from the simulated time of the first update."""
        if self._wall_clock is None:
            return context.get_time()
        wall = float(self._wall_clock())
        if self._wall_minus_sim is None:
            self._wall_minus_sim = wall - context.get_time()
        return wall - self._wall_minus_sim

    def _update(self, context, state) -> None:
        """The step's receive, advance and record, the copies doing what it says between."""
        local = self._local_time(context)
        uplink = self._uplink_packets_input.Eval(context) if self._remote else ()
        message = None if self._remote else self._uplink_input.Eval(context)
        step, received = receive_step(
            self._params, context.get_abstract_state(self._state).get_value(),
            self._telemetry_input.Eval(context), uplink, local, message)
        self._carry_out(received.actions)
        self.residuals.extend(received.residuals)
        if len(self.residuals) > self._params.residual_history:
            del self.residuals[:len(self.residuals) - self._params.residual_history]
        local = self._local_time(context)
        now = prediction_now(self._params, step, local)
        if step.copies.built and now is not None:
            step, actions = advance_step(self._params, step, now)
            self._carry_out(actions)
            tool, q = self._predicted(self._ahead.get_context())
            # How far ahead of the telemetry the look-ahead was synchronised on.
            horizon = now - step.copies.ahead_horizon_from
            self.predictions.append((now, horizon, tool, q))
            step, view = record_step(self._params, step, now=now, horizon_s=horizon,
                                     tool=tool, q=q, local_t_s=local, view=self.view(context))
            state.get_mutable_abstract_state(self._view).set_value(view)
        state.get_mutable_abstract_state(self._state).set_value(step)
        self._last = step

    def _carry_out(self, actions) -> None:
        """The step's actions on the copies (Drake Simulators), in order."""
        suppress = InitializeParams(suppress_initialization_events=True)
        for action in actions:
            if isinstance(action, Build):
                self._build(action.q)
            elif isinstance(action, Append):
                self._replica.packets.append(action.send_t_s, action.message)
            elif isinstance(action, RestSynced):
                self._synced.get_mutable_context().SetTime(action.t_s)
                self._synced.Initialize(suppress)
            elif isinstance(action, AdvanceSynced):
                self._synced.AdvanceTo(action.t_s)
            elif isinstance(action, Resync):
                sample = action.sample
                self._replica.robot.SetMeasuredState(
                    self._synced.get_mutable_context(), q_link=sample.q_link,
                    q_motor=sample.q_motor, v_link=sample.v_link, v_motor=sample.v_motor)
            elif isinstance(action, StartCatchup):
                if self._spare is None:
                    self._spare = self._replica.MakeSimulator(self._replica.diagram)
                self._catchup, self._spare = self._spare, None
                self._catchup.get_mutable_context().SetTimeStateAndParametersFrom(
                    self._synced.get_context())
                self._catchup.Initialize(suppress)
            elif isinstance(action, AdvanceCatchup):
                self._catchup.AdvanceTo(action.t_s)
            elif isinstance(action, Swap):
                self._ahead, self._spare, self._catchup = self._catchup, self._ahead, None
            elif isinstance(action, AdvanceAhead):
                self._ahead.AdvanceTo(action.t_s)
