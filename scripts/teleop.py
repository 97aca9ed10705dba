"""`telesmooth teleop`: drive the robot live from a browser, the whole chain in one process.

The operator's console is a Meshcat page (localhost only unless ``--host`` says otherwise):
sliders and keys, Enable (Space) and Stop (Esc), a gamepad. The chain runs against the wall
clock: console → ground station → uplink (``link.faults``) → onboard receiver and link
guard → flexible plant → telemetry (``link.downlink``) → the predicted robot → the display
(:func:`~telesmooth.diagrams.teleop.MakeTeleopDiagram`). It prints one line with the page's
address, then a progress line every second (real-time rate, late ticks, the link and the
robot's guard, the clutch), and with ``--out`` writes the session: the operator's hand as
a haptic recording (``operator.npz`` and ``operator.csv``, the format ``simulate``'s
``file`` source reads), the uplink and telemetry logs, ``predicted.csv`` and ``report.md``.
"""

from __future__ import annotations

import dataclasses
import math
import signal
import time
from pathlib import Path

import numpy as np

from telesmooth.scripts.formatting import log as _log

__all__ = ["console_scenario", "run_teleop", "write_session"]

PROGRESS_PERIOD_S = 1.0
SLICE_S = 0.1


def console_scenario(scenario):
    """The scenario as the live console drives it: the operator at the browser console
    (``haptic.source = "console"``: the hand starts at ``haptic.live_initial_pose``) and the
    deployed chain."""
    haptic = dataclasses.replace(scenario.haptic, source="console")
    return dataclasses.replace(scenario, haptic=haptic, chain="deployed")


def _initial_pose(scenario) -> np.ndarray:
    pose = np.asarray(scenario.haptic.live_initial_pose, dtype=float)
    if scenario.arm == "space_arm":
        from telesmooth.arms.air_bearing import planar_pose_to_space_arm

        pose = planar_pose_to_space_arm(pose)
    return pose


def _slider_ranges(scenario) -> dict:
    from telesmooth.arms.air_bearing import SHOULDER_IN_BASE_M

    if scenario.arm == "air_bearing_arm":
        return {"x_m": (-1.1, 1.1), "y_m": (-1.1, 1.1)}
    centre = np.asarray(SHOULDER_IN_BASE_M, dtype=float)
    return {name: (float(c - 1.2), float(c + 1.2))
            for name, c in zip(("x_m", "y_m", "z_m"), centre)}


def exposure_warning(host: str) -> str | None:
    """What to tell the operator when the page listens on ``host``: None for this machine's
    loopback (``localhost``, 127.0.0.0/8, ::1), a warning for anything else (another
    interface, every interface)."""
    import ipaddress

    if host == "localhost":
        return None
    try:
        if ipaddress.ip_address(host).is_loopback:
            return None
    except ValueError:
        pass                                    # a host name: it may resolve anywhere
    return (f"--host {host}: the operator console is reachable from other machines on that "
            "interface; anyone who reaches it can drive the robot")


def open_meshcat(host: str, port: int | None, command: str = "teleop"):
    """A Meshcat server on ``host`` (``127.0.0.1`` by default: this machine only); a port in
    use is one clear error."""
    from pydrake.geometry import Meshcat, MeshcatParams

    warning = exposure_warning(host)
    if warning is not None:
        _log(f"{command}: warning: {warning}")
    try:
        return Meshcat(MeshcatParams(host=host, port=port))
    except RuntimeError as error:
        where = f"--port = {port}" if port is not None else "a free port from 7000"
        raise RuntimeError(f"{where}: Meshcat could not listen on {host} (the port is in use "
                           f"or not allowed: {error}); give another --port") from None


def _console_and_display(scenario, meshcat):
    """The browser console (its controls on the page) and the display; the console's
    forward kinematics is bound later to the diagram's inverse kinematics (``bind``)."""
    from telesmooth.arms.joint_vectors import as_per_joint
    from telesmooth.console.input import console_params, reach_saturation
    from telesmooth.diagrams.teleop import console_pose_names
    from telesmooth.systems.inverse_kinematics import IkStatus
    from telesmooth.systems.operator_console import MeshcatControls, OperatorConsole
    from telesmooth.systems.operator_display import OperatorDisplay

    arm = scenario.arm_description
    names = console_pose_names(scenario)
    pose0 = _initial_pose(scenario)
    controls = MeshcatControls(meshcat, names, initial_pose=pose0,
                               position_range_m=_slider_ranges(scenario))
    params = console_params(names, period_s=scenario.haptic.period_s,
                            saturate=reach_saturation(scenario.arm),
                            slider_steps=controls.slider_steps)
    bound = {}
    console = OperatorConsole(params, controls, initial_pose=pose0,
                              forward_kinematics=lambda q: bound["ik"]
                              .forward_kinematics_pose(q), num_joints=arm.num_joints)
    smoother = scenario.smoother
    display = OperatorDisplay(
        meshcat, arm, pose_names=names, period_s=scenario.predictor.period_s,
        uplink_period_s=scenario.uplink.period_s,
        max_acceleration=as_per_joint("max_acceleration_rad_per_s2",
                                      smoother.max_acceleration_rad_per_s2, arm.num_joints,
                                      arm.joint_names, allow_inf=True),
        max_jerk=as_per_joint("max_jerk_rad_per_s3", smoother.max_jerk_rad_per_s3,
                              arm.num_joints, arm.joint_names, allow_inf=True),
        residual_warning_m=max(scenario.predictor.residual_warning_m,
                               5.0 * scenario.onboard.tracker.noise_m),
        distance_horizon_m=scenario.collision_checker.distance_horizon_m,
        ik_names={status.value: status.name.lower().replace("_", " ")
                  for status in IkStatus})

    def bind(ik):
        bound["ik"] = ik

    return console, display, bind


def build_teleop(scenario, meshcat, *, monitor=None):
    """The teleop diagram with the browser console and the display in ``meshcat`` (and the
    wall-clock ``monitor``); returns (handles, console, display)."""
    from telesmooth.diagrams.teleop import MakeTeleopDiagram
    from telesmooth.diagrams.visualization import draw_workspace

    console, display, bind = _console_and_display(scenario, meshcat)
    handles = MakeTeleopDiagram(scenario, console=console, display=display, monitor=monitor)
    bind(handles.ground.inverse_kinematics)
    draw_workspace(meshcat, scenario.workspace_or_default)
    return handles, console, display


def build_operator(scenario, meshcat, lcm, *, monitor=None):
    """The operator's own process on ``lcm``: the console, its display and the predicted
    robot; returns (handles, console, display)."""
    from telesmooth.diagrams.teleop import MakeOperatorDiagram
    from telesmooth.diagrams.visualization import draw_workspace

    console, display, bind = _console_and_display(scenario, meshcat)
    # A live process: the predictor reads the robot's clock against the wall clock, not
    # against this process's simulated time (which lags by however late it runs).
    handles = MakeOperatorDiagram(scenario, lcm=lcm, console=console, display=display,
                                  monitor=monitor, wall_clock=time.perf_counter)
    bind(handles.inverse_kinematics)
    draw_workspace(meshcat, scenario.workspace_or_default)
    return handles, console, display


def _run_live(name: str, simulator, monitor, display, duration_s, progress) -> None:
    """Advances ``simulator`` against the wall clock in slices until ``duration_s`` (None:
    until SIGINT/SIGTERM), feeding the display the timing and printing ``progress()``
    every second."""
    stopped = []

    def on_signal(signum, _frame):
        if stopped:
            raise KeyboardInterrupt
        stopped.append(signal.Signals(signum).name)

    previous = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    simulator.Initialize()
    end = math.inf if duration_s is None else float(duration_s)
    next_progress = PROGRESS_PERIOD_S
    try:
        while not stopped and simulator.get_context().get_time() < end - 1e-9:
            target = min(end, simulator.get_context().get_time() + SLICE_S)
            simulator.AdvanceTo(target)
            display.clock.realtime_rate = monitor.statistics(last_s=1.0).realtime_rate
            display.clock.late_ticks = monitor.late_ticks
            if target >= next_progress - 1e-9:
                _log(progress())
                next_progress += PROGRESS_PERIOD_S
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)
    if stopped:
        _log(f"{name}: {stopped[0]} at t = {simulator.get_context().get_time():.2f} s; "
             "ending the session")
    stats = monitor.statistics()
    _log(f"{name}: {simulator.get_context().get_time():.2f} s at {stats.realtime_rate:.3f}× "
         f"real time; late ticks {stats.late_ticks} of {stats.ticks} (worst "
         f"{1000 * stats.worst_s:.1f} ms)")


def _announce(name: str, scenario, url: str) -> None:
    print(f"operator console: {url}", flush=True)
    _log(f"{name}: open {url} in a browser; Space engages the clutch, A/D S/W move the hand"
         + (", K/I up/down" if scenario.arm == "space_arm" else "")
         + "; Esc stops. Ctrl-C ends the session.")


def run_teleop(scenario, *, host: str = "127.0.0.1", port: int | None = None,
               duration_s: float | None = None, realtime: float = 1.0,
               out: Path | None = None) -> int:
    """Runs the live chain until ``duration_s`` (None: until SIGINT/SIGTERM) and writes the
    session into ``out``."""
    from telesmooth.systems.flexible_arm import MakeSimulator
    from telesmooth.systems.wall_clock_monitor import WallClockMonitor

    scenario = console_scenario(scenario)
    meshcat = open_meshcat(host, port)
    url = meshcat.web_url().rstrip("/") + "/"
    # A publish per haptic tick records when the tick really ran.
    monitor = WallClockMonitor(scenario.haptic.period_s, rate=max(realtime, 1e-9))
    handles, _, display = build_teleop(scenario, meshcat, monitor=monitor)
    simulator = MakeSimulator(handles.diagram, scenario.onboard)
    if realtime > 0:
        simulator.set_target_realtime_rate(realtime)
    _announce("teleop", scenario, url)
    _run_live("teleop", simulator, monitor, display, duration_s,
              lambda: _progress_line(handles, simulator.get_context(), monitor))
    if out is not None:
        write_session(Path(out), handles, simulator.get_context(), monitor=monitor)
    return 0


def run_operator(scenario, *, lcm_url: str, host: str = "127.0.0.1", port: int | None = None,
                 duration_s: float | None = None, out: Path | None = None) -> int:
    """The console alone on the bus ``lcm_url`` (docs/operator.md): publishes the hand, reads
    the ground's packets and events and the robot's telemetry for its display; writes the
    session (the hand, console.csv, predicted.csv, report.md) into ``out``."""
    from pydrake.lcm import DrakeLcm
    from pydrake.systems.analysis import Simulator

    from telesmooth.scripts.teleop_report import write_operator_report
    from telesmooth.systems.wall_clock_monitor import WallClockMonitor

    scenario = console_scenario(scenario)
    meshcat = open_meshcat(host, port, "operator")
    url = meshcat.web_url().rstrip("/") + "/"
    lcm = DrakeLcm(lcm_url)
    monitor = WallClockMonitor(scenario.haptic.period_s)
    handles, _, display = build_operator(scenario, meshcat, lcm, monitor=monitor)
    simulator = Simulator(handles.diagram)
    simulator.set_target_realtime_rate(1.0)
    _announce("operator", scenario, url)
    _log(f"operator: publishing the hand on {lcm_url} (TELEOP_HAPTIC_COMMAND); run "
         "`telesmooth ground --scenario-text \"{haptic: {source: lcm}}\"` and "
         "`telesmooth onboard` on the same bus")
    _run_live("operator", simulator, monitor, display, duration_s,
              lambda: _operator_progress(handles, simulator.get_context(), monitor))
    if out is not None:
        write_operator_report(Path(out), handles, simulator.get_context(), monitor=monitor)
    return 0


def _progress_parts(handles, context, monitor):
    """What both progress lines read: the predictor's view, the last second's timing, and the
    clutch in words."""
    predictor = handles.predictor
    view = predictor.view(predictor.GetMyContextFromRoot(context))
    console = handles.console
    state = console.console_state(console.GetMyContextFromRoot(context)) if console else None
    clutch = ("stopped" if state is not None and state.stop else
              "engaged" if state is not None and state.enabled else "released")
    return view, monitor.statistics(last_s=1.0), clutch


def _link_words(view, arriving: str) -> str:
    return ("no telemetry yet" if not math.isfinite(view.telemetry_silence_s) else
            f"no telemetry for {view.telemetry_silence_s:.1f} s"
            if view.telemetry_silence_s > 1.0 else arriving)


def _residual_words(view) -> str:
    return "—" if not math.isfinite(view.residual_m) else f"{1000 * view.residual_m:.2f} mm"


def _operator_progress(handles, context, monitor) -> str:
    view, stats, clutch = _progress_parts(handles, context, monitor)
    return (f"operator: t = {context.get_time():6.1f} s, real time {stats.realtime_rate:.2f}×,"
            f" {_link_words(view, 'telemetry arriving')}, clutch {clutch}, prediction "
            f"residual {_residual_words(view)}")


def _progress_line(handles, context, monitor) -> str:
    from telesmooth.safety.guard import GuardMode

    view, stats, clutch = _progress_parts(handles, context, monitor)
    link = _link_words(view, f"telemetry {1000 * view.telemetry_age_s:.0f} ms old")
    guard = ("—" if view.guard_mode < 0 else GuardMode(int(view.guard_mode)).label)
    return (f"teleop: t = {context.get_time():6.1f} s, real time {stats.realtime_rate:.2f}×, "
            f"late ticks {monitor.late_ticks} (worst {1000 * stats.worst_s:.0f} "
            f"ms), link: {link}, robot guard {guard}, clutch {clutch}, prediction residual "
            f"{_residual_words(view)}")


def write_session(out: Path, handles, context, *, monitor=None) -> Path:
    """The session's files in ``out``: the operator's hand (``operator.npz``,
    ``operator.csv``), ``predicted.csv``, the chain's logs and ``report.md``."""
    from telesmooth.scripts.teleop_report import write_teleop_report

    return write_teleop_report(out, handles, context, monitor=monitor)
