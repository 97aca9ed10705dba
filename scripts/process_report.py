"""The reports of the two processes: ``report.md`` of `telesmooth onboard` and `telesmooth
ground`, with the figures of `telesmooth simulate` for what each side knows.

* The onboard process knows every packet it accepted (when, and its positions), every
  command its link guard issued, the guard's modes and the robot's own telemetry, all on its
  own clock. It does not know the operator. Its report: the joints (accepted packets, the
  guard's commands, the robot), the FD acceleration and jerk of the accepted stream and of
  what the robot received against the limits, the tool's track against the commands, the
  response error to each command, and the guard's modes over time.
* The ground process knows the operator's targets, the packets it sent, σ and the
  pre-simulator, and what the robot reported in its telemetry (ONBOARD_JOINT_STATUS) as it
  arrived. Its report: the figures of `simulate` from the ground's view, with the robot's
  track, guard modes and link status as reported. The robot's times are on the robot's
  clock; they are mapped onto the ground's by the smallest difference (arrival on the
  ground − onboard time) over the run, so each lies within one telemetry period (and the
  link's latency) of the ground instant it happened at.

Both are written at the end of the run, also after SIGINT/SIGTERM (the processes stop their
simulation cleanly and then write everything).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from telesmooth.atomic_files import write_text
from telesmooth.diagrams.simulation import (
    SimulationRecord,
    ground_fields,
    guard_metrics,
    guard_record,
    plant_summary,
    plant_text,
    received_response_errors,
    response_errors,
    run_metrics,
)
from telesmooth.scripts.simulate_report import (
    _and,
    _over_limits,
    limits_text,
    record_limits,
    write_received_csv,
    write_record_report,
)
from telesmooth.systems.laser_tracker import tracker_record

__all__ = ["ground_record", "onboard_record", "write_ground_report", "write_onboard_report"]


def _accepted_packets(logs, context, poll_period_s: float):
    """(seq, accept time, q) of every packet the receiver accepted, dated at the poll that
    accepted it (a logger shows the state before its instant's updates: the row at t holds
    what the poll at t − poll decided). A poll that accepted a burst keeps the newest."""
    count_log = logs["accepted_count"].FindLog(context)
    count = count_log.data()[0][1:]
    times = count_log.sample_times()[1:] - poll_period_s
    rows = np.flatnonzero(np.diff(np.r_[0.0, count]) > 0)
    seq = logs["last_command_seq"].FindLog(context).data()[0][1:][rows].astype(int)
    q = logs["q_accepted"].FindLog(context).data().T[1:][rows]
    return seq, times[rows], q


def onboard_record(handles, context, *, wall_time_s: float) -> SimulationRecord:
    """The onboard process's run as a :class:`SimulationRecord` (no operator side): the
    accepted packets as its packets (their times: when accepted, on the onboard clock; their
    velocities unknown, NaN), the guard's record and the robot's telemetry."""
    scenario = handles.scenario
    logs = handles.logs
    poll = scenario.command_receiver.poll_period_s
    seq, accepted_t, q = _accepted_packets(logs, context, poll)
    n = q.shape[1] if q.ndim == 2 else len(handles.onboard.arm.joint_names)
    state = np.full((seq.size, 4 * n), np.nan)
    state[:, :n] = q.reshape(seq.size, n)
    tracker = tracker_record(logs["tracker"].FindLog(context).data().T)
    arm = handles.onboard.arm
    q0 = (np.zeros(n) if arm.config.initial_position_rad is None
          else np.asarray(arm.config.initial_position_rad, dtype=float))
    return SimulationRecord(
        scenario=scenario, joint_names=tuple(arm.joint_names), duration_s=context.get_time(),
        wall_time_s=wall_time_s, cpu_time_s=float("nan"), target_t_s=None, q_target=None,
        collision_detected=None, min_distance_m=None, packet_seq=seq,
        packet_t_s=accepted_t, packet_state=state, tick_t_s=None, q_delayed=None,
        holding=None, sigma=None, tracker_t_s=tracker.t_s, q_link=tracker.q_link,
        q_motor=tracker.q_motor, tool_position_m=tracker.tool_position_m,
        initial_position_rad=q0,
        ramp_start_t_s=np.unique(logs["command_ramp"].FindLog(context).data()[0]),
        guard=guard_record(logs, context, poll))


def _stream_statistics(record: SimulationRecord) -> dict:
    """FD acceleration and jerk of the accepted packets (after the robot's rest), against
    the limits."""
    from telesmooth.smoothing.metrics import finite_differences, limit_statistics

    scenario = record.scenario
    names = record.joint_names
    a_max, j_max = record_limits(record)
    sequence = np.vstack([np.tile(record.initial_position_rad, (3, 1)), record.q_sent])
    period = scenario.uplink.period_s
    return {"joint_names": list(names),
            "fd_acceleration": limit_statistics(finite_differences(sequence, period, 2)[1:],
                                                a_max),
            "fd_jerk": limit_statistics(finite_differences(sequence, period, 3), j_max)}


def onboard_metrics(record: SimulationRecord) -> dict:
    """The onboard report's figures, JSON-ready: the accepted stream against the limits,
    what the guard did (:func:`~telesmooth.diagrams.simulation.guard_metrics`), and the
    robot's response to the accepted packets and to the commands it received."""
    response = response_errors(record)
    received = received_response_errors(record)

    def stats(values):
        return None if values.size == 0 else {"mean": float(np.mean(values)),
                                              "max": float(np.max(values))}

    return {
        "side": "onboard",
        "duration_s": record.duration_s,
        "wall_time_s": record.wall_time_s,
        "accepted_packets": int(record.packet_seq.size),
        "stream": _stream_statistics(record),
        "guard": guard_metrics(record),
        "tracking": {"response_error_m": stats(response.response_m),
                     "received_response_error_m": (None if received is None
                                                   else stats(received[1])),
                     "ramp_s": response.ramp_s},
        "link_deflection_rad": {"max_abs": np.abs(record.q_link - record.q_motor)
                                .max(axis=0).tolist()},
        "plant": plant_summary(record.scenario, record.initial_position_rad),
    }


def _onboard_text(metrics: dict, extra: dict, figures) -> str:
    stream = metrics["stream"]
    names = stream["joint_names"]
    over = (_over_limits(stream["fd_acceleration"], names, "acceleration")
            + _over_limits(stream["fd_jerk"], names, "jerk"))
    guard_part = limits_text({"commands": {**stream, "joint_names": names},
                              "guard": metrics["guard"]})
    if over:
        # limits_text speaks of what the ground sent; onboard, it is what arrived.
        guard_part = guard_part.replace("The commands the ground sent break",
                                        "The packets accepted from the ground break")
    else:
        guard_part = guard_part.replace("The commands the ground sent stay",
                                        "The packets accepted from the ground stay")
    tracking = metrics["tracking"]
    lines = [
        "# telesmooth onboard",
        "",
        "Chain: the onboard side of the two processes: every uplink packet from LCM is "
        "examined by the receiver (authentication "
        f"{extra['authentication']}, epoch {extra['onboard_epoch']:013x}) and passes the "
        "link guard, which keeps what reaches the robot within the limits. The operator's "
        "side is in the ground process's report.",
        "",
        f"{metrics['duration_s']:.2f} s run in {metrics['wall_time_s']:.1f} s wall time; "
        f"{metrics['accepted_packets']} packets accepted; packets by class: "
        + ", ".join(f"{k} {v}" for k, v in extra["packets"].items() if v is not None) + ".",
        "",
        plant_text(metrics["plant"]),
        "",
        "## Limits",
        "",
        guard_part,
        "",
        "## Accuracy",
        "",
    ]
    response, received = tracking["response_error_m"], tracking["received_response_error_m"]
    if response is not None:
        lines.append(
            f"Robot response error against the accepted packets (mean / max): "
            f"{1000 * response['mean']:.2f} / {1000 * response['max']:.2f} mm"
            + ("" if received is None else
               f"; against the commands it received from the guard: "
               f"{1000 * received['mean']:.2f} / {1000 * received['max']:.2f} mm") + ".")
    else:
        lines.append("No packet was accepted: the robot held its start pose.")
    lines.append("")
    for title, name in figures:
        lines += [f"## {title}", "", f"![{title}]({name})", ""]
    return "\n".join(lines)


def write_onboard_report(out: Path, handles, context, *, wall_time_s: float,
                         extra: dict) -> Path:
    """Writes the onboard process's ``report.md`` (and its figures, ``metrics.json``,
    ``received.csv``) into ``out``; ``extra``: ``authentication``, ``onboard_epoch`` and
    ``packets`` (counts by class) for the text."""
    record = onboard_record(handles, context, wall_time_s=wall_time_s)
    metrics = onboard_metrics(record)
    write_text(out / "metrics.json", json.dumps(metrics, indent=2) + "\n")
    write_received_csv(out, record)
    return write_record_report(out, record,
                               lambda figures: _onboard_text(metrics, extra, figures),
                               packets="accepted packets", tables=False)


# -- the ground process -----------------------------------------------------------------------

def _telemetry(handles, context):
    """The telemetry rows the ground logged, one per message (the first row that shows it):
    (ground time of that row, the decoded vectors), or None if none arrived."""
    from telesmooth.systems.joint_status_decoder import telemetry_layout

    log = handles.logs["telemetry"].FindLog(context)
    values = log.data().T
    times = log.sample_times()
    layout = telemetry_layout(len(handles.ground.joint_names))
    seq = values[:, layout["seq"]][:, 0]
    valid = np.isfinite(seq)
    if not np.any(valid):
        return None
    values, times, seq = values[valid], times[valid], seq[valid]
    first = np.flatnonzero(np.r_[True, np.diff(seq) != 0])
    return times[first], values[first], layout


def ground_record(handles, context, *, wall_time_s: float):
    """The ground process's run as a :class:`SimulationRecord` (the robot as its telemetry
    reported it, on the ground clock; no guard record: the guard runs onboard), and the
    telemetry view for the link figure: a dict with ``t_s`` (ground clock), ``guard_mode``,
    ``stream_distance_rad``, ``clock_offset_s`` (ground − onboard), or None without
    telemetry."""
    scenario = handles.scenario
    fields = ground_fields(handles, context)
    n = len(handles.ground.joint_names)
    telemetry = _telemetry(handles, context)
    if telemetry is None:
        empty = np.zeros((0, n))
        tracker = dict(tracker_t_s=np.zeros(0), q_link=empty, q_motor=empty,
                       tool_position_m=np.zeros((0, 3)))
        view, ramp = None, None
    else:
        arrival, values, layout = telemetry
        onboard_t = values[:, layout["utime_s"]][:, 0]
        offset = float(np.min(arrival - onboard_t))
        t = onboard_t + offset
        # The robot publishes each sample publish_offset_s after its tracker took it.
        tracker = dict(tracker_t_s=t - scenario.publish_offset_s,
                       q_link=values[:, layout["q_link"]],
                       q_motor=values[:, layout["q_motor"]],
                       tool_position_m=values[:, layout["tool_position"]])
        # When the robot began to move towards each packet: the first message that names
        # it as accepted (published publish_offset_s after the poll that accepted it).
        accepted = values[:, layout["last_command_seq"]][:, 0]
        firsts = np.flatnonzero(np.r_[accepted[:1] >= 0, np.diff(accepted) > 0])
        ramp = np.unique(t[firsts] - scenario.publish_offset_s)
        view = {"t_s": t, "guard_mode": values[:, layout["guard_mode"]][:, 0].astype(int),
                "stream_distance_rad": values[:, layout["stream_distance_rad"]][:, 0],
                "q_commanded": values[:, layout["q_commanded"]], "clock_offset_s": offset}
    record = SimulationRecord(
        scenario=scenario, joint_names=tuple(handles.ground.joint_names),
        duration_s=context.get_time(), wall_time_s=wall_time_s, cpu_time_s=float("nan"),
        **fields, **tracker, ramp_start_t_s=ramp, guard=None)
    return record, view


def _link_figure(out: Path, view, status_log, figures) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from telesmooth.scripts.figures import FigureWriter
    from telesmooth.systems.link_guard import GUARD_MODES
    from telesmooth.systems.link_monitor import LINK_STATUSES

    writer = FigureWriter(out)
    fig, axes = plt.subplots(3, 1, figsize=(9, 5.6), sharex=True)
    axes[0].step(status_log[0], status_log[1], where="post", color="C0", lw=1.2)
    axes[0].set_yticks(range(len(LINK_STATUSES)), LINK_STATUSES)
    axes[0].set_ylim(-0.5, len(LINK_STATUSES) - 0.5)
    axes[0].set_ylabel("link (ground)")
    if view is not None:
        axes[1].step(view["t_s"], view["guard_mode"], where="post", color="C2", lw=1.2)
        axes[2].plot(view["t_s"], 1000 * view["stream_distance_rad"], color="C2", lw=1)
    axes[1].set_yticks(range(len(GUARD_MODES)), GUARD_MODES)
    axes[1].set_ylim(-0.5, len(GUARD_MODES) - 0.5)
    axes[1].set_ylabel("robot's guard\n(telemetry)")
    axes[2].set_ylabel("command − accepted\npacket [mrad]")
    axes[2].set_xlabel("time on the ground clock [s]")
    writer.save(fig, "link.png", "The link as the ground saw it, and the robot's link guard as "
                "its telemetry reported it")
    figures.extend(writer.figures)


def _ground_text(metrics: dict, view, extra: dict, figures) -> str:
    scenario = metrics["scenario"]
    tracking = metrics["tracking"]
    commands = metrics["commands"]
    lines = [
        "# telesmooth ground",
        "",
        "Chain: the ground side of the two processes: the packets went to the robot over "
        f"LCM ({extra['lcm_url']}, {extra['signing']}); the robot's side (what its receiver "
        "and link guard did) is in the onboard process's report. The robot's track here is "
        "what its telemetry reported"
        + ("" if view is None else
           f", mapped onto the ground clock (the robot's clock "
           f"{'+' if view['clock_offset_s'] >= 0 else '−'} {abs(view['clock_offset_s']):.3f} s, "
           "the smallest arrival − onboard-time difference over the run)") + ".",
        "",
        f"Scenario: arm `{scenario['arm']}`, operator: {scenario['operator']}, smoother "
        f"`{scenario['method']}`, on collision `{scenario['on_collision']}`. "
        f"{metrics['duration_s']:.2f} s run in {metrics['wall_time_s']:.1f} s wall time, "
        f"{metrics['num_packets']} packets.",
        "",
        "## Limits",
        "",
    ]
    names = commands.get("joint_names") or []
    over = (_over_limits(commands["fd_acceleration"], names, "acceleration")
            + _over_limits(commands["fd_jerk"], names, "jerk"))
    lines.append("The commands this ground sent "
                 + (f"break {_and(over)}." if over else
                    "stay within the FD acceleration and jerk limits on every joint."))
    if view is not None:
        from telesmooth.systems.link_guard import GUARD_MODES

        period = np.median(np.diff(view["t_s"])) if view["t_s"].size > 1 else 0.0
        modes = {name: float(np.count_nonzero(view["guard_mode"] == k) * period)
                 for k, name in enumerate(GUARD_MODES)}
        lines.append(
            "The robot's link guard, as its telemetry reported it: "
            + ", ".join(f"{k} {v:.2f} s" for k, v in modes.items() if v)
            + f"; its command at most {1000 * np.max(view['stream_distance_rad']):.1f} mrad "
            "(max over joints) from the newest packet it accepted.")
    else:
        lines.append("No telemetry arrived from the robot.")
    lines += ["", "## Accuracy", ""]
    if view is not None and tracking["response_error_m"] is not None:
        lines.append(
            f"Robot response error against the sent commands (mean / max): "
            f"{1000 * tracking['response_error_m']['mean']:.2f} / "
            f"{1000 * tracking['response_error_m']['max']:.2f} mm; whole-chain error against "
            f"the operator: {1000 * tracking['chain_error_m']['mean']:.2f} / "
            f"{1000 * tracking['chain_error_m']['max']:.2f} mm (read from the telemetry a ramp "
            "after the first message that names each packet accepted: within a telemetry "
            "period of the instant the robot's own report reads).")
    lines.append("")
    for title, name in figures:
        lines += [f"## {title}", "", f"![{title}]({name})", ""]
    return "\n".join(lines)


def _ground_metrics(record: SimulationRecord) -> dict:
    if record.tracker_t_s.size == 0:
        # run_metrics needs the robot's track; without telemetry only the commands count.
        return None
    metrics = run_metrics(record)
    return metrics


def write_ground_report(out: Path, handles, context, *, wall_time_s: float,
                        extra: dict) -> Path:
    """Writes the ground process's ``report.md`` (its figures, ``metrics.json``, the CSVs)
    into ``out``; ``extra``: ``lcm_url`` and ``signing`` for the text."""
    record, view = ground_record(handles, context, wall_time_s=wall_time_s)
    metrics = _ground_metrics(record)
    status = handles.logs["link_status"].FindLog(context)
    status_log = (status.sample_times(), status.data()[0])
    if metrics is None:
        text = ("# telesmooth ground\n\nNo telemetry arrived from the robot: nothing to "
                "report about it. The packets sent are in commands.csv.\n")
        from telesmooth.scripts.simulate_report import _write_tables

        if record.packet_seq is not None:
            _write_tables(out, record)
        write_text(out / "report.md", text)
        return out / "report.md"
    metrics["side"] = "ground"
    if view is not None:
        metrics["telemetry_clock_offset_s"] = view["clock_offset_s"]
    write_text(out / "metrics.json", json.dumps(metrics, indent=2) + "\n")

    def text_of(figures):
        figures = list(figures)
        _link_figure(out, view, status_log, figures)
        return _ground_text(metrics, view, extra, figures)

    return write_record_report(out, record, text_of)
