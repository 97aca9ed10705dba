"""Playback of a joint path: 4 Hz source → the scenario's Uplink → the onboard robot, logged.

:func:`AddPathPlayback` adds the stages for any 4 Hz path; :func:`play_path` builds and runs
one (the method comparison plays every method's packets with it), first without the plant's
collision geometry and again with it unless the run is certified free of self-contact
(:mod:`~telesmooth.arms.self_contact`); :func:`MakeOfflinePlaybackDiagram` builds it only
for a valid offline plan (:mod:`~telesmooth.diagrams.offline_planning`), re-checked against the
scene it is played in; :func:`run_offline` plans, and plays the plan if it is valid;
:func:`copy_logs` copies the loggers' records out of a finished simulation.

Playback timing. The source holds ``q_planned[k]`` on [t_k, t_{k+1}) and the last row afterwards;
the uplink's tick at t_k samples it, so packet k carries ``q_planned[k]`` exactly (a logger at
t_k still shows packet k−1). The uplink and the robot start at ``plan.q_start``, the committed
history the solver assumed, so the finite-difference limits hold across the start for what the
plant actually receives; after the last packet the uplink keeps re-sending the last (rest) pose.
There is no delay FIFO and no online smoother in playback: the plan is already smoothed and
checked, and the robot executes it from t = 0.

The laser tracker in playback. Nothing in a playback reads the tracker while it runs, so with
the (default) continuous plant the tracker is not a stage of the diagram:
:func:`simulate_playback` records the integrator's
dense output and the tracker takes its samples afterwards, at the same instants
t_k = k·period (t_k before the run's end) and with the same computation as its periodic event
(:meth:`~telesmooth.systems.laser_tracker.LaserTracker.Record`). Without a 100 Hz event the
integrator no longer stops every 10 ms, which was 40 % of a playback's time; its steps stay
capped at 10 ms (:data:`~telesmooth.systems.flexible_arm.MAX_INTEGRATOR_STEP_S`), so the
accuracy is that of the event-bound run (``tests/test_playback_tracker.py`` compares the two;
the steps are no longer than before, but they no longer end at the sample instants, which the
cubic interpolation reaches within the integration error).
A discrete plant (``onboard.time_step_s`` > 0) has no dense output; its tracker stays in the
diagram and samples with its own event.

The chain (``chain``). ``"paper"`` (default): the uplink's held command drives the robot
directly, its send time starting each ramp (the paper's set-up; what ``compare`` and
``experiment`` reproduce). ``"deployed"``: every packet goes the way it goes in the deployed
chain of one process (:func:`~telesmooth.diagrams.teleoperation.AddDeployedLink`, exactly as
:func:`~telesmooth.diagrams.teleoperation.MakeTeleoperationDiagram` builds it): formed by the
sender, carried by the link (``scenario.link.faults``: a perfect link by default), examined by
the onboard receiver and passed through the onboard link guard, which keeps what reaches the
robot within the limits; the robot is built as the onboard process builds it (its
interpolator polls every 10 ms and starts a ramp at the poll that sees a new command). The
guard's loggers (:func:`~telesmooth.diagrams.teleoperation.AddLinkLoggers`) and the ramp
starts are logged every receiver poll; :func:`playback_guard_record` reads what the guard did.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import LogVectorOutput

from telesmooth.arms.self_contact import SelfContactCheck, self_contact_certificate
from telesmooth.diagrams.offline_planning import OfflinePlan, plan_offline
from telesmooth.diagrams.offline_validation import (
    PERIOD_RTOL,
    describe_violations,
    validation_report,
)
from telesmooth.diagrams.scenario import CHAINS, Scenario
from telesmooth.diagrams.simulation import GuardRecord, guard_record
from telesmooth.diagrams.teleoperation import (
    AddDeployedLink,
    AddLinkLoggers,
    AddOnboardRobot,
    ConnectUplinkToRobot,
    GroundHandles,
)
from telesmooth.systems.flexible_arm import FlexibleJointArm, MakeSimulator
from telesmooth.systems.laser_tracker import tracker_record
from telesmooth.systems.planned_path_source import PlannedPathSource
from telesmooth.systems.uplink import Uplink
from telesmooth.user_input import unknown_choice

__all__ = [
    "AddPathPlayback",
    "MakeOfflinePlaybackDiagram",
    "OfflinePlaybackHandles",
    "SignalLog",
    "copy_logs",
    "RAMP_START_LOG",
    "play_path",
    "playback_guard_record",
    "ramp_start_times",
    "run_offline",
    "set_points",
    "simulate_playback",
    "tracker_sample_times",
]


@dataclasses.dataclass(frozen=True)
class SignalLog:
    """A copied VectorLog: sample times t_s (M,), s, and values (M, size)."""

    t_s: np.ndarray
    values: np.ndarray


@dataclasses.dataclass(frozen=True)
class OfflinePlaybackHandles:
    """A built playback diagram with its stages and loggers (name → VectorLogSink).

    Attributes:
        diagram: The diagram.
        source: The planned-path source.
        uplink: The 4 Hz uplink (same system as the online chain's).
        robot: The flexible-joint arm.
        logs: The loggers, all at the uplink period (a row at t_k shows the state before
            the tick at t_k): "sequence_number", "send_time", "q_sent", "state_sent" (packet
            k−1), and the robot's "command_rejected" and "command_ramp" (as set by the
            interpolator's poll after the previous tick; they change only at polls). The
            tracker's record is not among them (a discrete plant's playback also logs
            "tracker_measurement", its tracker's event): :func:`simulate_playback` returns it.
        plan: The plan played.
        duration_s: Suggested simulated time: the last packet plus ``scenario.settle_s``
            (and at least one tick more, so the loggers see the last packet), or
            ``scenario.simulation_duration_s`` if that is longer.
    """

    diagram: object
    source: PlannedPathSource
    uplink: Uplink
    robot: FlexibleJointArm
    logs: dict
    plan: OfflinePlan
    duration_s: float


def AddPathPlayback(builder: DiagramBuilder, scenario: Scenario, positions, *, q_start,
                    states=None, contact_geometry: bool = True, chain: str = "paper",
                    collision_model=None):
    """Adds a 4 Hz joint path → the scenario's Uplink → the onboard robot, with loggers.

    No check is made here: callers that command a real or a safety-relevant plant validate
    the path first (:func:`MakeOfflinePlaybackDiagram` does). Row k of ``positions`` is
    packet k, sent at t_k = k·Δt; the uplink and the robot start at rest at ``q_start``.

    Args:
        builder: The builder to add to.
        scenario: The uplink period, arm and onboard settings (and, deployed, the link, the
            receiver and the guard). Its own ``chain`` is not read: ``chain`` says.
        positions: The path, rad, (N, J).
        q_start: The robot's start pose, rad, (J,).
        states: Optional [q, q̇, q̈, q⃛] per row, (N, J, 4), sent with the packets.
        contact_geometry: False: the robot's plant has no collision geometry (continuous
            plant only; :func:`play_path` certifies such a run free of self-contact).
        chain: ``"paper"`` (default): the uplink drives the robot directly; ``"deployed"``:
            through the link, the onboard receiver and the link guard (module docstring).
        collision_model: Deployed only: an ``ArmCollisionModel`` of the scenario's arm and
            workspace for the guard to share (None builds one).

    Returns:
        (source, uplink, robot, logs): ``logs`` as :class:`OfflinePlaybackHandles`, and
        deployed also the loggers of
        :func:`~telesmooth.diagrams.teleoperation.AddLinkLoggers` and :data:`RAMP_START_LOG`,
        every receiver poll. Run the diagram with :func:`simulate_playback`, which returns the
        tracker's record (with the continuous plant the tracker is not a stage of the diagram).

    Raises:
        ValueError: An unknown ``chain``.
    """
    if chain not in CHAINS:
        raise ValueError(unknown_choice("chain", chain, CHAINS, noun="chains"))
    deployed = chain == "deployed"
    arm = scenario.arm_description
    period = scenario.uplink.period_s
    # Stage 1: the path, one row per uplink tick.
    source = builder.AddNamedSystem("planned_path_source", PlannedPathSource(
        positions, period_s=period, states=states))
    # Stage 2: the same 4 Hz uplink as the online chain, starting at the committed pose.
    uplink = builder.AddNamedSystem("uplink", Uplink(
        scenario.uplink, num_joints=arm.num_joints, initial_position_rad=q_start))
    builder.Connect(source.get_q_planned_output_port(), uplink.get_q_smoothed_input_port())
    builder.Connect(source.get_state_planned_output_port(),
                    uplink.get_state_smoothed_input_port())
    # Stage 3: the onboard robot, at rest at the committed pose.
    # A continuous plant's tracker is sampled after the run, from the integrator's dense
    # output; a discrete plant has none, and its tracker stays a stage of the diagram.
    # Deployed, the robot is built as the onboard process builds it (its interpolator polls
    # every 10 ms); driven by the uplink it polls only at the ticks.
    continuous = scenario.onboard.time_step_s == 0.0
    robot = AddOnboardRobot(builder, scenario, initial_position_rad=q_start,
                            command_period_s=None if deployed else period,
                            tracker_in_diagram=not continuous,
                            contact_geometry=contact_geometry)
    if deployed:
        # Stage 2½: sender → link → receiver → link guard, as AddDeployedLink builds it for
        # the live chain (the ground here is the uplink alone: no operator, FIFO or smoother).
        ground = GroundHandles(
            haptic=None, inverse_kinematics=None,
            collision_checker=_SharedCollisionModel(collision_model), period_mean=None,
            fifo=None, smoother=None, uplink=uplink, recording=None,
            initial_position_rad=np.asarray(q_start, dtype=float),
            joint_names=tuple(arm.joint_names))
        _, receiver, guard, _ = AddDeployedLink(builder, ground, scenario, robot)
    else:
        ConnectUplinkToRobot(builder, uplink, robot)
    ports = {"sequence_number": uplink.get_sequence_number_output_port(),
             "send_time": uplink.get_send_time_output_port(),
             "q_sent": uplink.get_q_sent_output_port(),
             "state_sent": uplink.get_state_sent_output_port(),
             "command_rejected": robot.GetOutputPort("command_rejected"),
             "command_ramp": robot.GetOutputPort("command_ramp")}
    logs = {name: LogVectorOutput(port, builder, period) for name, port in ports.items()}
    if deployed:
        poll = scenario.command_receiver.poll_period_s
        logs.update(AddLinkLoggers(builder, receiver, guard, poll))
        # The ramps start at the interpolator's 10 ms polls: logged at the receiver's.
        logs[RAMP_START_LOG] = LogVectorOutput(robot.GetOutputPort("command_ramp"), builder,
                                               poll)
    if not continuous:
        logs[_TRACKER_LOG] = LogVectorOutput(robot.GetOutputPort("tracker_measurement"),
                                             builder, scenario.onboard.tracker.period_s)
    return source, uplink, robot, logs


_TRACKER_LOG = "tracker_measurement"
"""The logger of a discrete plant's tracker in playback (its record is returned as "tracker")."""

RAMP_START_LOG = "ramp_start"
"""Deployed playback: the robot's ``command_ramp`` logged every receiver poll (its first
column is the start t₀ of the ramp in progress: every instant the robot began to move towards
a new command)."""


@dataclasses.dataclass(frozen=True)
class _SharedCollisionModel:
    """What :func:`~telesmooth.diagrams.teleoperation.AddDeployedLink` reads of the ground's
    collision checker: its collision model, shared with the guard (None: the guard builds
    its own)."""

    collision_model: object = None


class _CopiedLog:
    """A :class:`SignalLog` read as a VectorLogSink's log (``FindLog(context)`` → itself), so
    :func:`~telesmooth.diagrams.simulation.guard_record` reads copied playback logs as it reads
    a live run's."""

    def __init__(self, log: SignalLog):
        self._log = log

    def FindLog(self, context):  # noqa: N802 (Drake's name)
        return self

    def data(self) -> np.ndarray:
        return self._log.values.T

    def sample_times(self) -> np.ndarray:
        return self._log.t_s


def playback_guard_record(logs: dict, poll_period_s: float) -> GuardRecord:
    """What the link guard of a deployed playback did (:func:`play_path`'s ``logs``, with
    ``chain = "deployed"``), as :func:`~telesmooth.diagrams.simulation.guard_record` reads a
    live run: every command it issued, the packet each followed, its modes and counts."""
    return guard_record({name: _CopiedLog(log) for name, log in logs.items()
                         if isinstance(log, SignalLog)}, None, poll_period_s)


def ramp_start_times(logs: dict) -> np.ndarray:
    """Deployed playback: every instant the robot began a ramp towards a new command, s
    (sorted; from :data:`RAMP_START_LOG`)."""
    return np.unique(logs[RAMP_START_LOG].values[:, 0])


def set_points(ramps, times_s, ramp_duration_s: float, *, lead_s: float = 0.0) -> np.ndarray:
    """The robot's desired joint positions at ``times_s``, from the ramps it ran.

    ``ramps`` are rows of the robot's ``command_ramp`` output, [t₀, q₀ (n), q₁ (n)], logged
    at least once per ramp, in time order (repeats are fine): the desired position at t is
    the ramp of
    the latest t₀ ≤ t + ``lead_s``, q₀ + s·(q₁ − q₀) with s = clip((t + lead − t₀)/T, 0, 1)
    (exactly q₁ at s = 1), as :func:`~telesmooth.systems.command_interpolator.\
ramp_desired_state` gives it; before the first t₀, the first ramp's q₀.

    Args:
        ramps: (R, 1 + 2n) rows.
        times_s: Instants, s, (M,).
        ramp_duration_s: T, s (> 0).
        lead_s: The robot's set-point lead, s (its plant step for a discrete plant, else 0).

    Returns:
        (M, n) desired positions, rad.
    """
    rows = np.asarray(ramps, dtype=float)[::-1]
    n = (rows.shape[1] - 1) // 2
    # The last row logged of each t₀: the robot's initial hold (t₀ = 0) is replaced by its
    # first ramp, which a command issued at t = 0 starts with the same t₀.
    start_times, last = np.unique(rows[:, 0], return_index=True)
    q0 = rows[last, 1:1 + n]
    q1 = rows[last, 1 + n:]
    at = np.asarray(times_s, dtype=float) + lead_s
    index = np.searchsorted(start_times, at, side="right") - 1
    before = index < 0
    index = np.maximum(index, 0)
    fraction = np.clip((at - start_times[index]) / ramp_duration_s, 0.0, 1.0)[:, None]
    out = np.where(fraction >= 1.0, q1[index], q0[index] + fraction * (q1[index] - q0[index]))
    out[before] = q0[0]
    return out


def tracker_sample_times(period_s: float, duration_s: float) -> np.ndarray:
    """t_k = k·period for every k with t_k < ``duration_s``, s: the instants at which the
    tracker's periodic event samples a run that ends at ``duration_s`` (the event at the end
    itself would fire only if the run went on)."""
    times = period_s * np.arange(int(math.floor(duration_s / period_s)) + 2)
    return times[times < duration_s]


def simulate_playback(diagram, robot: FlexibleJointArm, loggers: dict, duration_s: float
                      ) -> tuple[object, dict]:
    """Runs a playback diagram to ``duration_s`` and takes the tracker's samples.

    Continuous plant (the default): the integrator's dense output (a cubic Hermite segment per
    step, steps of at most 10 ms) is evaluated at the tracker's instants
    (:func:`tracker_sample_times`) and the tracker samples the plant's state there
    (:meth:`~telesmooth.systems.laser_tracker.LaserTracker.Record`). Drake refuses a dense
    output with two step ends closer than 2.2e-16 s, which a step that ends one rounding error
    before an event produces (e.g. with the interpolator polling every 10 ms); the playback is
    then run again from the start, stopping the integrator at every sample instant instead:
    the steps, and the record, of the tracker as a periodic event (measured on Defaults with
    10 ms polls: the same values, 1.46 s for the whole playback against 1.50 s with the event).

    A discrete plant has no dense output: its tracker is a stage of the diagram
    (:func:`AddPathPlayback` puts it there) and its logged samples are returned, with the
    sample it holds at the end (taken at the last instant before the end, which no logger
    shows when ``duration_s`` is not a multiple of the period).

    Args:
        diagram: A diagram built with :func:`AddPathPlayback`.
        robot: Its robot.
        loggers: Its loggers (name → VectorLogSink).
        duration_s: Simulated time, s (> 0).

    Returns:
        (simulator, logs): the finished simulator, and ``logs`` as :func:`copy_logs` plus
        "tracker", a :class:`~telesmooth.systems.laser_tracker.TrackerRecord` (samples at
        t_k = k·period < ``duration_s``), and with the continuous plant "plant_state", a
        :class:`SignalLog` of the plant's [q; v] at the same instants.

    Raises:
        ValueError: If ``duration_s`` is not a finite time > 0.
    """
    if isinstance(duration_s, bool) or not isinstance(duration_s, (int, float)) \
            or not math.isfinite(duration_s) or duration_s <= 0.0:
        raise ValueError(f"duration_s = {duration_s!r} must be a finite time > 0 (s)")
    duration_s = float(duration_s)
    simulator = MakeSimulator(diagram, robot.config)
    simulator.Initialize()
    if robot.tracker_in_diagram:
        # A discrete plant (no dense output): the tracker's own event took the samples.
        simulator.AdvanceTo(duration_s)
        context = simulator.get_context()
        logs = copy_logs({k: v for k, v in loggers.items() if k != _TRACKER_LOG}, context)
        held = robot.GetOutputPort("tracker_measurement").Eval(
            robot.GetMyContextFromRoot(context))
        logs["tracker"] = tracker_record(np.vstack(
            [loggers[_TRACKER_LOG].FindLog(context).data().T, held]))
        return simulator, logs
    times = tracker_sample_times(robot.tracker.config.period_s, duration_s)
    indices = _plant_state_indices(diagram, robot)
    try:
        integrator = simulator.get_integrator()
        integrator.StartDenseIntegration()
        simulator.AdvanceTo(duration_s)
        states = integrator.StopDenseIntegration().vector_values(times).T[:, indices]
    except RuntimeError:
        # No dense output (see above): again from the start, stopping at every instant.
        simulator = MakeSimulator(diagram, robot.config)
        simulator.Initialize()
        context = simulator.get_context()
        states = np.empty((times.size, indices.size))
        for row, time_s in zip(states, times):
            simulator.AdvanceTo(float(time_s))
            row[:] = context.get_continuous_state_vector().CopyToVector()[indices]
        simulator.AdvanceTo(duration_s)
    logs = copy_logs(loggers, simulator.get_context())
    logs["tracker"] = robot.tracker.Record(times, states)
    logs["plant_state"] = SignalLog(t_s=times, values=states)
    return simulator, logs


def play_path(scenario: Scenario, positions, *, q_start, duration_s: float, states=None,
              name: str = "playback", chain: str = "paper",
              collision_model=None) -> tuple[dict, SelfContactCheck | None]:
    """Plays a 4 Hz joint path through the scenario's uplink and robot and returns the logs.

    With the continuous plant, the run is made first without the plant's collision geometry
    (Drake then asks for no contacts at each derivative evaluation: measured, a quarter of
    the integration time on the air-bearing arm) and certified free of self-contact from its
    recorded states (:class:`~telesmooth.arms.self_contact.SelfContactCertificate`): no pair
    of links that could touch came within :data:`~telesmooth.arms.self_contact.CLEARANCE_M`.
    The geometry's force is then zero at every state the integrator evaluated (those lie within
    a step, at most 10 ms, of the recorded samples, and so within the same margin), and the run
    is the one the plant with geometry makes. If the run cannot be certified it is made again
    with the geometry, and that run is returned. A discrete plant always carries its geometry.

    Args:
        scenario, positions, q_start, states, chain, collision_model: As
            :func:`AddPathPlayback` (``chain = "deployed"``: through the onboard receiver
            and link guard; read the guard's record with :func:`playback_guard_record`).
        duration_s: Simulated time, s (> 0).
        name: The diagram's name.

    Returns:
        (logs, check): the logs of :func:`simulate_playback`, and the
        :class:`~telesmooth.arms.self_contact.SelfContactCheck` of the run without geometry
        (for an arm the certificate cannot bound, not made: ``check.reason`` says why; None
        for a discrete plant). The returned run had no geometry exactly when
        ``check.certified``.
    """
    check = None
    if scenario.onboard.time_step_s == 0.0:
        # The robot's own model (AddOnboardRobot builds it from these settings).
        arm = dataclasses.replace(scenario.onboard, arm=scenario.arm).arm_description
        certificate = self_contact_certificate(arm)
        check = certificate.refusal
        if check is None:
            logs = _play(scenario, positions, q_start, duration_s, states, name, False, chain,
                         collision_model)
            # [q; v] of the same model: check() refuses states of another width.
            plant_state = logs["plant_state"].values
            check = certificate.check(plant_state[:, :certificate.num_positions],
                                      plant_state[:, certificate.num_positions:],
                                      scenario.onboard.tracker.period_s)
            if check.certified:
                return logs, check
    return _play(scenario, positions, q_start, duration_s, states, name, True, chain,
                 collision_model), check


def _play(scenario, positions, q_start, duration_s, states, name, contact_geometry,
          chain="paper", collision_model=None) -> dict:
    builder = DiagramBuilder()
    _, _, robot, loggers = AddPathPlayback(builder, scenario, positions, states=states,
                                           q_start=q_start, contact_geometry=contact_geometry,
                                           chain=chain, collision_model=collision_model)
    diagram = builder.Build()
    diagram.set_name(name)
    return simulate_playback(diagram, robot, loggers, duration_s)[1]


def _plant_state_indices(diagram, robot: FlexibleJointArm) -> np.ndarray:
    """Where the plant's [q; v] sits in the diagram's continuous state vector."""
    context = diagram.CreateDefaultContext()
    continuous = context.get_mutable_continuous_state_vector()
    continuous.SetFromVector(np.arange(continuous.size(), dtype=float))
    plant = robot.plant
    return plant.GetPositionsAndVelocities(plant.GetMyContextFromRoot(context)).astype(int)


def MakeOfflinePlaybackDiagram(scenario: Scenario, plan: OfflinePlan) -> OfflinePlaybackHandles:
    """Playback of a valid plan: 4 Hz planned-path source → Uplink → onboard robot.

    The plan is checked again against ``scenario`` (its arm, workspace, margin and limits),
    so a plan made for one scene cannot be played in another where it is unsafe.

    Raises:
        ValueError: If the plan is not valid (the message gives the reason and the first
            violations), fails the check against ``scenario``, or does not match its arm or
            uplink period. Nothing is built then.
    """
    if not isinstance(plan, OfflinePlan):
        raise ValueError(f"plan = {type(plan).__name__} object; expected an OfflinePlan")
    arm = scenario.arm_description
    if tuple(plan.joint_names) != arm.joint_names:
        raise ValueError(f"the plan's joints {plan.joint_names!r} are not the scenario arm's "
                         f"{arm.joint_names!r}")
    period = scenario.uplink.period_s
    if abs(plan.period_s - period) > PERIOD_RTOL * period:
        raise ValueError(f"the plan's period {plan.period_s!r} s differs from the uplink "
                         f"period {period!r} s")
    if not plan.is_valid:
        raise ValueError("refusing to play back an invalid offline plan: " + plan.reason)
    # The plan was validated against its own scenario; re-check only against another one.
    recheck = None if scenario is plan.scenario else validation_report(
        plan.q_planned, plan.t_s, scenario, start_position=plan.q_start,
        check_fd_limits=plan.validation.fd_limits_enforced,
        max_velocity=plan.max_velocity_rad_per_s)
    if recheck is not None and recheck.violations:
        raise ValueError("refusing to play back an offline plan that fails the check against "
                         "this scenario: " + describe_violations(recheck.violations))

    builder = DiagramBuilder()
    source, uplink, robot, logs = AddPathPlayback(
        builder, scenario, plan.q_planned, states=plan.states_planned, q_start=plan.q_start)
    diagram = builder.Build()
    diagram.set_name("offline_playback")
    last_packet = float(plan.t_s[-1])
    duration = max(last_packet + max(scenario.settle_s, period),
                   scenario.simulation_duration_s or 0.0)
    return OfflinePlaybackHandles(diagram=diagram, source=source, uplink=uplink, robot=robot,
                                  logs=logs, plan=plan, duration_s=duration)


def run_offline(scenario: Scenario, *, constraint: str = "trajectory", max_velocity=None,
                duration_s: float | None = None):
    """Plans, validates and, if the plan is valid, plays it back.

    Args:
        scenario: The session and the set-up.
        constraint, max_velocity: As :func:`plan_offline`.
        duration_s: Simulated playback time, s; default the handles' ``duration_s``.

    Returns:
        (plan, logs): ``logs`` maps each logger name of :class:`OfflinePlaybackHandles` to a
        :class:`SignalLog` copy, with "tracker" and "plant_state" as
        :func:`simulate_playback` returns them; it is None when the plan is not valid
        (nothing is played).

    Raises:
        ValueError: As :func:`plan_offline` for invalid input.
    """
    plan = plan_offline(scenario, constraint=constraint, max_velocity=max_velocity)
    if not plan.is_valid:
        return plan, None
    handles = MakeOfflinePlaybackDiagram(scenario, plan)
    _, logs = simulate_playback(handles.diagram, handles.robot, handles.logs,
                                handles.duration_s if duration_s is None else duration_s)
    return plan, logs


def copy_logs(loggers: dict, root_context) -> dict[str, SignalLog]:
    """Copies each VectorLogSink's log out of a root context: name → :class:`SignalLog`."""
    copies = {}
    for name, logger in loggers.items():
        log = logger.FindLog(root_context)
        copies[name] = SignalLog(t_s=log.sample_times().copy(), values=log.data().T.copy())
    return copies
