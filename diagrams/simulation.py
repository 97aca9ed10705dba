"""Running a scenario headless and collecting what happened as plain arrays.

:func:`simulate` builds the in-process chain (:func:`MakeTeleoperationDiagram`), advances it
in chunks (reporting progress), and returns a :class:`SimulationRecord`: the operator's joint
targets at 100 Hz, every uplink packet at 4 Hz, the FIFO's raw delayed samples, σ, the
collision flags, and the robot's telemetry at 100 Hz. :func:`run_metrics` turns a record into
the docs/method.md §6 figures.
"""

from __future__ import annotations

import dataclasses
import functools
import time
from collections.abc import Callable

import numpy as np

from telesmooth.arms.joint_vectors import as_per_joint
from telesmooth.arms.planar import AIR_BEARING_ARM, planar_forward_kinematics
from telesmooth.diagrams.scenario import (
    Scenario,
    describe_chain,
    describe_operator,
    make_haptic_recording,
)
from telesmooth.diagrams.teleoperation import MakeTeleoperationDiagram, uplink_packets
from telesmooth.diagrams.visualization import save_meshcat_recording, start_meshcat_recording
from telesmooth.smoothing.metrics import smoothing_metrics, tracking_errors
from telesmooth.systems.flexible_arm import MakeSimulator
from telesmooth.systems.laser_tracker import tracker_record

__all__ = ["GuardRecord", "ResponseErrors", "SimulationRecord", "ground_fields", "guard_metrics",
           "guard_record", "guard_record_metrics", "plant_summary", "plant_text",
           "received_response_errors", "record_meshcat_html", "response_delay_s",
           "response_errors", "response_instants", "run_duration_s", "run_metrics", "sample_at",
           "simulate", "tool_positions"]


@dataclasses.dataclass(frozen=True, eq=False)
class GuardRecord:
    """What the onboard link guard of a deployed chain did, from its logs.

    Every logger publishes the state before the updates of its instant (Drake's x⁻): the row
    logged at t holds what the poll at t − poll_period_s decided. Each value here is dated
    at the poll that decided it.

    Attributes:
        poll_period_s: The guard's (and the receiver's) poll period, s.
        poll_t_s: The instant of every poll, s, (P,).
        mode: The guard's mode after each poll (index in
            :data:`~telesmooth.systems.link_guard.GUARD_MODES`), (P,).
        stream_distance_rad: max over joints of |command − newest accepted packet| after each
            poll, rad, (P,).
        command_t_s, q_commanded: Every command the guard issued (what reached the robot's
            interpolator) and the poll that issued it, s (K,) and rad (K, J).
        q_followed: The newest accepted packet at that poll, rad, (K, J): the packet the
            command followed (TRACK, RESUMING) or the stream while it stopped or held.
        limited_count: Commands that followed a packet but differ from it (the limiter cut
            them to keep the limits).
        accepted_count: Packets the receiver accepted.
    """

    poll_period_s: float
    poll_t_s: np.ndarray
    mode: np.ndarray
    stream_distance_rad: np.ndarray
    command_t_s: np.ndarray
    q_commanded: np.ndarray
    q_followed: np.ndarray
    limited_count: int
    accepted_count: int

    @property
    def num_commands(self) -> int:
        return int(self.command_t_s.size)


def guard_record(logs: dict, context, poll_period_s: float) -> GuardRecord:
    """The :class:`GuardRecord` of a run from the loggers of
    :func:`~telesmooth.diagrams.teleoperation.AddLinkLoggers` (logged every poll)."""
    def data(name):
        return logs[name].FindLog(context).data()

    count_log = logs["guard_command_count"].FindLog(context)
    # Row i was logged at t_i and holds the state the poll at t_i − poll decided.
    poll_t = count_log.sample_times()[1:] - poll_period_s
    count = count_log.data()[0][1:]
    commanded = data("guard_q_commanded").T[1:]
    accepted = data("q_accepted").T[1:]
    # A poll issues at most one command: the rows where the count grew.
    rows = np.flatnonzero(np.diff(np.r_[0.0, count]) > 0)
    return GuardRecord(
        poll_period_s=float(poll_period_s), poll_t_s=poll_t.copy(),
        mode=data("guard_mode")[0][1:].astype(int).copy(),
        stream_distance_rad=data("guard_stream_distance")[0][1:].copy(),
        command_t_s=poll_t[rows].copy(), q_commanded=commanded[rows].copy(),
        q_followed=accepted[rows].copy(),
        limited_count=int(data("guard_limited_count")[0][-1]) if count.size else 0,
        accepted_count=int(data("accepted_count")[0][-1]) if count.size else 0)


@dataclasses.dataclass(frozen=True, eq=False)
class SimulationRecord:
    """What a headless run produced (all arrays time-major).

    A record of one side of the two processes (:mod:`telesmooth.scripts.process_report`)
    leaves None where that side does not know a quantity: the onboard process has no
    operator targets, collision flags or 4 Hz ticks (and its packet velocities are NaN).

    Attributes:
        scenario: The scenario run.
        joint_names: Joint order of every joint array.
        duration_s: Simulated time, s.
        wall_time_s: Wall-clock time of the simulation (the simulator's advance only: not the
            diagram's build before it nor the logs read after it), s.
        cpu_time_s: CPU time of this process over the same window as ``wall_time_s``, s.
        target_t_s, q_target: IK joint targets (the pre-simulator's newest command), 100 Hz.
        collision_detected, min_distance_m: pre-simulator flags at 100 Hz.
        packet_seq, packet_t_s, packet_state: every uplink packet: number, send time and
            [q, q̇, q̈, q⃛] (M, 4J) as sent.
        tick_t_s, q_delayed, holding, sigma: at each 4 Hz tick (logged before the tick's
            update, i.e. the values of the tick at that time).
        tracker_t_s, q_link, q_motor, tool_position_m: robot telemetry, 100 Hz, each sample
            at the time the tracker took it.
        stop_status, braking_distance: with ``fifo.on_collision = "stop"``, at each tick:
            the index in ``STOP_OUTCOMES`` of the last collision stop plan and its braking
            distance per joint, rad, (T, J); None with the hold.
        initial_position_rad: The robot's start pose, rad, (J,).
        ramp_start_t_s: Every instant at which the robot's interpolator started a ramp
            towards a new command, s (sorted); None if not logged.
        guard: In the deployed chain, what the onboard link guard did (:class:`GuardRecord`);
            None in the paper's chain.
    """

    scenario: Scenario
    joint_names: tuple[str, ...]
    duration_s: float
    wall_time_s: float
    cpu_time_s: float
    target_t_s: np.ndarray
    q_target: np.ndarray
    collision_detected: np.ndarray
    min_distance_m: np.ndarray
    packet_seq: np.ndarray
    packet_t_s: np.ndarray
    packet_state: np.ndarray
    tick_t_s: np.ndarray
    q_delayed: np.ndarray
    holding: np.ndarray
    sigma: np.ndarray
    tracker_t_s: np.ndarray
    q_link: np.ndarray
    q_motor: np.ndarray
    tool_position_m: np.ndarray
    stop_status: np.ndarray | None = None
    braking_distance: np.ndarray | None = None
    initial_position_rad: np.ndarray | None = None
    ramp_start_t_s: np.ndarray | None = None
    guard: GuardRecord | None = None

    @property
    def num_joints(self) -> int:
        return len(self.joint_names)

    @property
    def q_sent(self) -> np.ndarray:
        """Positions of the packets, (M, J)."""
        return self.packet_state[:, :self.num_joints]


@functools.lru_cache(maxsize=4)
def _space_arm_kinematics(arm):
    """One kinematics plant per arm description (building it parses the model)."""
    from telesmooth.arms.space_arm_ik import SpaceArmKinematics

    return SpaceArmKinematics(arm)


def tool_positions(scenario: Scenario, q) -> np.ndarray:
    """Tool point in the base frame for joint positions (…, J), m; (…, 3)."""
    q = np.asarray(q, dtype=float)
    if scenario.arm == "air_bearing_arm":
        xy = planar_forward_kinematics(q, AIR_BEARING_ARM.link_lengths_m)
        return np.concatenate([xy, np.zeros(xy.shape[:-1] + (1,))], axis=-1)
    kinematics = _space_arm_kinematics(scenario.arm_description)
    flat = q.reshape(-1, q.shape[-1])
    points = np.array([kinematics.tool_pose(row)[:3] for row in flat])
    return points.reshape(q.shape[:-1] + (3,))


def plant_summary(scenario: Scenario, start_position_rad, *, num_modes: int = 3) -> dict:
    """The onboard plant of ``scenario``, JSON-ready: arm, drive preset, plant step, each
    joint's drive parameters, and the lowest ``num_modes`` vibration modes linearised about
    the start pose (:func:`telesmooth.arms.modes.plant_modes`)."""
    from telesmooth.arms.description import DRIVE_FIELDS
    from telesmooth.arms.modes import plant_modes

    arm = scenario.onboard.arm_description
    modes = plant_modes(arm, start_position_rad)
    return {"arm": scenario.arm, "drive_preset": scenario.onboard.drive.preset,
            "time_step_s": scenario.onboard.time_step_s,
            "start_position_rad": np.asarray(start_position_rad, dtype=float).tolist(),
            "drive": {field: [getattr(joint, field) for joint in arm.joints]
                      for field in DRIVE_FIELDS},
            "modes": modes.as_dict(num_modes), "modes_text": modes.describe(num_modes)}


def plant_text(summary: dict) -> str:
    """One sentence for a report: the plant and its lowest vibration modes."""
    step = summary["time_step_s"]
    stepping = f"{1000 * step:g} ms steps" if step > 0 else "continuous"
    return (f"Plant: `{summary['arm']}`, drive preset `{summary['drive_preset']}` "
            f"({stepping}); lightly damped vibration modes linearised about the start pose: "
            f"{summary['modes_text']}.")


def run_duration_s(scenario: Scenario, recording, duration_s: float | None = None) -> float:
    """How long to run: ``duration_s`` if given, else ``scenario.simulation_duration_s``,
    else the recording's length + ``settle_s`` (the source replays it from t = 0), else (a
    live operator) ``haptic.live_duration_s``.

    Raises:
        ValueError: if the duration is not positive and finite.
    """
    if duration_s is None:
        duration_s = scenario.simulation_duration_s
    if duration_s is None:
        duration_s = (scenario.haptic.live_duration_s if recording is None else
                      float(recording.t_s[-1] - recording.t_s[0]) + scenario.settle_s)
    if not (np.isfinite(duration_s) and duration_s > 0.0):
        raise ValueError(f"duration_s = {duration_s!r} must be positive and finite")
    return float(duration_s)


def simulate(scenario: Scenario, *, duration_s: float | None = None, meshcat=None,
             progress: Callable[[str], None] | None = None) -> SimulationRecord:
    """Builds and runs the in-process chain; returns the record.

    Args:
        scenario: What to run.
        duration_s: Simulated time; default ``scenario.simulation_duration_s`` or the
            recording length + ``settle_s``.
        meshcat: Optional Meshcat to draw the robot into.
        progress: Called with a one-line message about every 10 % of the run.
    """
    handles = MakeTeleoperationDiagram(scenario, meshcat=meshcat)
    duration_s = run_duration_s(scenario, handles.ground.recording, duration_s)
    simulator = MakeSimulator(handles.diagram, scenario.onboard)
    simulator.Initialize()
    start, cpu_start = time.perf_counter(), time.process_time()
    # Ticks at exactly duration_s are not run by AdvanceTo; advance just past the last one.
    end = duration_s + 1e-9
    chunks = 10
    for chunk in range(1, chunks + 1):
        simulator.AdvanceTo(end * chunk / chunks)
        if progress is not None:
            elapsed = time.perf_counter() - start
            progress(f"simulated {simulator.get_context().get_time():.1f} / {duration_s:.1f} s "
                     f"({100 * chunk // chunks:3d} %), wall {elapsed:6.1f} s")
    wall, cpu = time.perf_counter() - start, time.process_time() - cpu_start
    context = simulator.get_context()

    tracker = tracker_record(handles.logs["tracker"].FindLog(context).data().T)
    return SimulationRecord(
        scenario=scenario, joint_names=handles.ground.joint_names, duration_s=duration_s,
        wall_time_s=wall, cpu_time_s=cpu, **ground_fields(handles, context),
        tracker_t_s=tracker.t_s, q_link=tracker.q_link, q_motor=tracker.q_motor,
        tool_position_m=tracker.tool_position_m,
        ramp_start_t_s=np.unique(handles.logs["command_ramp"].FindLog(context).data()[0]),
        guard=(guard_record(handles.logs, context, scenario.command_receiver.poll_period_s)
               if handles.onboard.guard is not None else None),
    )


def ground_fields(handles, context) -> dict:
    """The ground station's part of a :class:`SimulationRecord` from the loggers of
    :func:`~telesmooth.diagrams.teleoperation.AddGroundLoggers` (one process or the ground
    process): the targets, collision flags, packets and the 4 Hz ticks, and the start pose."""
    def log(name):
        return handles.logs[name].FindLog(context)

    packet_seq, packet_t, packet_state = uplink_packets(handles, context)
    # A packet sent after the loggers' last publish (e.g. at exactly duration_s) is read from
    # the uplink's state directly.
    uplink = handles.ground.uplink
    uplink_context = uplink.GetMyContextFromRoot(context)
    last_seq = int(uplink.get_sequence_number_output_port().Eval(uplink_context)[0])
    if last_seq >= 0 and (packet_seq.size == 0 or last_seq > packet_seq[-1]):
        packet_seq = np.append(packet_seq, last_seq)
        packet_t = np.append(packet_t, uplink.get_send_time_output_port().Eval(uplink_context))
        packet_state = np.vstack(
            [packet_state, uplink.get_state_sent_output_port().Eval(uplink_context)])
    ticks = log("sigma")
    return dict(
        target_t_s=log("q_target").sample_times().copy(), q_target=log("q_target").data().T.copy(),
        collision_detected=log("collision_detected").data()[0].copy(),
        min_distance_m=log("min_distance").data()[0].copy(),
        packet_seq=packet_seq, packet_t_s=np.asarray(packet_t, dtype=float).copy(),
        packet_state=np.asarray(packet_state, dtype=float).copy(),
        tick_t_s=ticks.sample_times().copy(), q_delayed=log("q_delayed").data().T.copy(),
        holding=log("holding").data()[0].copy(), sigma=ticks.data().T.copy(),
        stop_status=(log("stop_status").data()[0].copy() if "stop_status" in handles.logs
                     else None),
        braking_distance=(log("braking_distance").data().T.copy()
                          if "braking_distance" in handles.logs else None),
        initial_position_rad=np.array(handles.ground.initial_position_rad, dtype=float))


def _collision_stops(record: SimulationRecord) -> dict | None:
    """With ``on_collision = "stop"``: how many stop plans of each outcome were made and the
    largest braking distance per joint, rad; None with the hold. A plan is counted where the
    logged outcome or braking distance changes, so two identical plans in a row (e.g. two
    hold fallbacks of the same kind, both with zero braking distance) count once."""
    if record.stop_status is None:
        return None
    from telesmooth.systems.collision_stop import STOP_OUTCOMES

    status = record.stop_status.astype(int)
    changed = np.r_[status[:1] != 0, (np.diff(status) != 0)
                    | np.any(np.diff(record.braking_distance, axis=0) != 0, axis=1)]
    plans = status[changed & (status != 0)]
    return {"plans": {name: int(np.count_nonzero(plans == k))
                      for k, name in enumerate(STOP_OUTCOMES) if k != 0},
            "max_braking_distance_rad": np.max(np.abs(record.braking_distance), axis=0,
                                               initial=0.0).tolist()}


def sample_at(times, values, at):
    """values at the last sample time <= each of ``at`` (sample-and-hold lookup)."""
    index = np.searchsorted(times, np.asarray(at) + 1e-9, side="right") - 1
    return values[np.clip(index, 0, len(times) - 1)]


def response_delay_s(scenario: Scenario) -> float:
    """How long after a command is issued the robot's response to it is read, s.

    With the linear interpolation (default), when the set-point has reached the command: its
    ramp's end, ``ramp_duration_s`` after the ramp started (the ramp starts at the command's
    send time, see the interpolator's ``command_time``). With a zero-order hold the set-point
    jumps at once, and the response is read at the end of the command's hold, one uplink
    period later, just before the next command: reading it at the jump would measure the
    step itself.
    """
    interpolator = scenario.onboard.interpolator
    return (interpolator.ramp_duration_s if interpolator.interpolation == "linear"
            else scenario.uplink.period_s)


def response_instants(packet_t_s, ramp_start_t_s, ramp_s: float) -> np.ndarray:
    """When the robot's response to each packet is read, s: ``ramp_s`` after the robot began
    to move towards it.

    The robot begins at the first ramp start at or after the packet's send time and before
    the next packet's: the send time itself when the interpolator reads it (the uplink
    drives the robot), later behind a link (latency, the receiver's poll, the guard). A
    packet that started no ramp (its command equals the one before, or it was lost or
    rejected) is read as long after its send time as the packet before it was (its send
    time + ``ramp_s`` if none was). Without ramp starts (None) every packet is read at its
    send time + ``ramp_s``.
    """
    packet_t_s = np.asarray(packet_t_s, dtype=float)
    if ramp_start_t_s is None:
        return packet_t_s + ramp_s
    starts = np.asarray(ramp_start_t_s, dtype=float)
    tolerance = 1e-9
    first = np.searchsorted(starts, packet_t_s - tolerance, side="left")
    following = np.r_[packet_t_s[1:], np.inf] - tolerance
    begin = np.full(packet_t_s.shape, np.nan)
    found = first < starts.size
    begin[found] = starts[first[found]]
    begin[~(begin < following)] = np.nan
    lag = 0.0
    for k in range(packet_t_s.size):
        if np.isnan(begin[k]):
            begin[k] = packet_t_s[k] + lag
        else:
            lag = begin[k] - packet_t_s[k]
    return begin + ramp_s


@dataclasses.dataclass(frozen=True, eq=False)
class ResponseErrors:
    """The robot's response to each packet k, read when the set-point has reached it.

    Attributes:
        response_t_s: The instant the tracker is read, s, (M,): ``ramp_s`` after the robot
            began to move towards packet k (:func:`response_instants`; t_k + ramp when the
            uplink drives the robot).
        response_m: e(k) = ‖FK(q_sent,k) − x_tracker(response instant)‖, m, (M,).
        chain_t_s: The same instants for the packets that carry an operator sample, s, (C,).
        chain_m: ‖FK(q_operator(t_k − delay)) − x_tracker(t_k + ramp)‖, m, (C,).
        ramp_s: How long after its send time a command is read (:func:`response_delay_s`), s.
    """

    response_t_s: np.ndarray
    response_m: np.ndarray
    chain_t_s: np.ndarray
    chain_m: np.ndarray
    ramp_s: float


def response_errors(record: SimulationRecord) -> ResponseErrors:
    """e of every packet whose response instant lies in the tracker's record (the tracker
    sample taken at that instant: each record row is at its own sample time)."""
    scenario = record.scenario
    ramp = response_delay_s(scenario)
    sample_times = record.packet_t_s - scenario.fifo.delay_s
    response_times = response_instants(record.packet_t_s, record.ramp_start_t_s, ramp)
    inside = response_times <= record.tracker_t_s[-1]
    measured = sample_at(record.tracker_t_s, record.tool_position_m, response_times[inside])
    e_response = tracking_errors(tool_positions(scenario, record.q_sent[inside]), measured)
    both = inside & (sample_times >= 0.0)
    if record.target_t_s is None:    # the onboard side: no operator
        both[:] = False
        e_chain = np.zeros(0)
    else:
        operator = tool_positions(
            scenario, sample_at(record.target_t_s, record.q_target, sample_times[both]))
        e_chain = tracking_errors(operator, sample_at(record.tracker_t_s,
                                                      record.tool_position_m,
                                                      response_times[both]))
    return ResponseErrors(response_t_s=response_times[inside], response_m=e_response,
                          chain_t_s=response_times[both], chain_m=e_chain, ramp_s=ramp)


def guard_metrics(record: SimulationRecord) -> dict | None:
    """What the onboard link guard did to the commands of a deployed chain (None in the
    paper's chain), JSON-ready:

    * ``commands``, ``limited``: commands issued, and how many of those that followed a
      packet differ from it (the limiter cut them to keep the limits);
    * ``largest_cut_rad``: per joint, the largest |command − the packet it followed| over the
      commands issued while tracking or re-joining the stream, rad;
    * ``stream_distance_rad``: the largest distance (max over joints) of the robot's command
      from the newest accepted packet after any poll, rad;
    * ``time_in_mode_s``: how long the guard was in each mode;
    * ``received``: the FD acceleration and jerk of the command sequence the robot received
      (the guard's commands, after the robot's rest at its start pose), against the limits
      (:func:`~telesmooth.smoothing.metrics.limit_statistics`).
    """
    if record.guard is None:
        return None
    return guard_record_metrics(record.guard, record.scenario, record.joint_names,
                                record.initial_position_rad)


def guard_record_metrics(guard: GuardRecord, scenario: Scenario, joint_names,
                         initial_position_rad) -> dict:
    """:func:`guard_metrics` of the guard's record of any run (a simulation's, a playback's):
    the scenario gives the limits and the uplink period, the robot started at
    ``initial_position_rad``."""
    from telesmooth.smoothing.metrics import finite_differences, limit_statistics
    from telesmooth.systems.link_guard import GUARD_MODES, MODE_RESUMING, MODE_TRACK

    names = tuple(joint_names)
    n = len(names)
    a_max = as_per_joint("max_acceleration_rad_per_s2",
                         scenario.smoother.max_acceleration_rad_per_s2, n, names, allow_inf=True)
    j_max = as_per_joint("max_jerk_rad_per_s3", scenario.smoother.max_jerk_rad_per_s3, n,
                         names, allow_inf=True)
    modes = guard.mode[np.searchsorted(guard.poll_t_s, guard.command_t_s)]
    following = (modes == MODE_TRACK) | (modes == MODE_RESUMING)
    cut = np.abs(guard.q_commanded - guard.q_followed)[following]
    rest = np.tile(np.asarray(initial_position_rad, dtype=float), (3, 1))
    sequence = np.vstack([rest, guard.q_commanded])
    period = scenario.uplink.period_s
    return {
        "commands": guard.num_commands,
        "limited": guard.limited_count,
        "accepted_packets": guard.accepted_count,
        "largest_cut_rad": (cut.max(axis=0) if cut.size else np.zeros(n)).tolist(),
        "stream_distance_rad": float(guard.stream_distance_rad.max(initial=0.0)),
        "time_in_mode_s": {name: float(np.count_nonzero(guard.mode == k) * guard.poll_period_s)
                           for k, name in enumerate(GUARD_MODES)},
        "received": {
            "fd_acceleration": limit_statistics(finite_differences(sequence, period, 2)[1:],
                                                a_max),
            "fd_jerk": limit_statistics(finite_differences(sequence, period, 3), j_max),
        },
    }


def received_response_errors(record: SimulationRecord) -> tuple[np.ndarray, np.ndarray] | None:
    """In a deployed chain, the robot's response to each command it received (the guard's):
    (instants, ‖FK(q_commanded,k) − x_tracker(instant)‖), read ``ramp_s`` after the robot
    began to move towards it (:func:`response_instants`); None in the paper's chain."""
    guard = record.guard
    if guard is None:
        return None
    ramp = response_delay_s(record.scenario)
    instants = response_instants(guard.command_t_s, record.ramp_start_t_s, ramp)
    inside = instants <= record.tracker_t_s[-1]
    measured = sample_at(record.tracker_t_s, record.tool_position_m, instants[inside])
    return instants[inside], tracking_errors(
        tool_positions(record.scenario, guard.q_commanded[inside]), measured)


def run_metrics(record: SimulationRecord) -> dict:
    """docs/method.md §6 figures of a run, JSON-ready.

    * ``commands``: the sent packets against the operator's joint targets of the same instant
      (the IK target at t_k − delay): FD and state acceleration/jerk against the limits, joint
      and Cartesian deformation.
    * ``tracking``: e(k) = ‖FK(q_sent,k) − x_tracker(t_k + ramp)‖, the robot's response to each
      command (tracker sampled when the interpolator has reached the command), and
      ‖x_operator(t_k − delay) − x_tracker(t_k + ramp)‖, the whole chain's error.
    """
    scenario = record.scenario
    n = record.num_joints
    delay = scenario.fifo.delay_s
    period = scenario.uplink.period_s
    names = record.joint_names
    a_max = as_per_joint("max_acceleration_rad_per_s2",
                         scenario.smoother.max_acceleration_rad_per_s2, n, names, allow_inf=True)
    j_max = as_per_joint("max_jerk_rad_per_s3", scenario.smoother.max_jerk_rad_per_s3, n,
                         names, allow_inf=True)
    sample_times = record.packet_t_s - delay
    valid = sample_times >= 0.0
    original = sample_at(record.target_t_s, record.q_target, sample_times[valid])
    sent = record.q_sent[valid]
    states = record.packet_state[valid].reshape(-1, 4, n).transpose(0, 2, 1)

    def fk(q):
        return tool_positions(scenario, q)

    commands = smoothing_metrics(
        smoothed_positions=sent, original_positions=original, dt_s=period,
        max_acceleration=a_max, max_jerk=j_max, smoothed_states=states,
        forward_kinematics=fk, joint_names=names)
    response = response_errors(record)
    e_response, e_chain, ramp = response.response_m, response.chain_m, response.ramp_s
    received = received_response_errors(record)
    deflection = record.q_link - record.q_motor
    return {
        "scenario": {"arm": scenario.arm, "chain": scenario.chain,
                     "chain_text": describe_chain(scenario),
                     "haptic_source": scenario.haptic.source,
                     "operator": describe_operator(scenario),
                     "method": scenario.smoother.method,
                     "on_collision": scenario.fifo.on_collision},
        "duration_s": record.duration_s,
        "wall_time_s": record.wall_time_s,
        "realtime_factor": record.duration_s / max(record.wall_time_s, 1e-9),
        "num_packets": int(record.packet_seq.size),
        "collision_ticks": int(np.count_nonzero(record.holding > 0.5)),
        "collision_stops": _collision_stops(record),
        "min_distance_m": float(np.min(record.min_distance_m)),
        "distance_horizon_m": record.scenario.collision_checker.distance_horizon_m,
        "final_sigma": record.sigma[-1].tolist() if record.sigma.size else None,
        "commands": commands,
        "tracking": {
            "response_error_m": {"mean": float(np.mean(e_response)),
                                 "max": float(np.max(e_response))},
            "chain_error_m": {"mean": float(np.mean(e_chain)), "max": float(np.max(e_chain))},
            "received_response_error_m": (
                None if received is None or received[1].size == 0 else
                {"mean": float(np.mean(received[1])), "max": float(np.max(received[1]))}),
            "ramp_s": ramp,
        },
        "guard": guard_metrics(record),
        "link_deflection_rad": {"max_abs": np.abs(deflection).max(axis=0).tolist()},
        "plant": plant_summary(scenario, record.initial_position_rad),
    }


def record_meshcat_html(scenario, out_path, *, duration_s: float | None = None,
                        port: int | None = None,
                        progress: Callable[[str], None] | None = None) -> dict:
    """Simulates ``scenario`` in one process with Meshcat recording; writes one offline HTML.

    The chain is :func:`~telesmooth.diagrams.teleoperation.MakeTeleoperationDiagram` with a
    localhost Meshcat; the workspace boxes and the commanded tool path are drawn as static
    objects; the robot is recorded at 30 frames per simulated second. The HTML embeds
    three.js, the scene and the animation (no external scripts), so it plays offline.

    Args:
        scenario: A :class:`~telesmooth.diagrams.scenario.Scenario` with a recorded or
            synthetic haptic source (not ``"lcm"``).
        out_path: The HTML file to write (parent folders are created).
        duration_s: Simulated time, s; None = ``scenario.simulation_duration_s``, else the
            operator recording's length + ``scenario.settle_s``.
        port: Meshcat port on localhost; None = the first free port from 7000.
        progress: Called with a one-line status message at each stage and every 10 % of the
            run.

    Returns:
        Figures of the run: ``html_path``, ``html_bytes``, ``simulated_time_s``,
        ``simulation_wall_time_s`` (simulation with recording on), ``wall_time_s`` (build,
        simulate and write), ``frames`` (recorded animation frames), ``meshcat_url``.

    Raises:
        ValueError: if ``duration_s`` is not positive, or the scenario has no recording and
            no ``simulation_duration_s``.
    """
    report = progress or (lambda message: None)
    start = time.perf_counter()
    meshcat = start_meshcat_recording(scenario, make_haptic_recording(scenario), port=port)
    report(f"meshcat on {meshcat.web_url()}; simulating")
    record = simulate(scenario, duration_s=duration_s, meshcat=meshcat, progress=report)
    saved = save_meshcat_recording(meshcat, out_path, record.duration_s)
    report(f"wrote {saved['html_path']} ({saved['html_bytes'] / 1e6:.2f} MB)")
    return {
        **saved,
        "simulated_time_s": record.duration_s,
        "simulation_wall_time_s": record.wall_time_s,
        "wall_time_s": time.perf_counter() - start,
        "meshcat_url": meshcat.web_url(),
    }
