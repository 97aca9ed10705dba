"""The operator's seat without a browser: the predicted robot, measured, and a session's round
trip.

The teleop diagram (MakeTeleopDiagram) runs headless at full speed, driven by the scenario's
recording or by the console system fed from a scripted stand-in for the page's controls.

* The predicted robot against the robot's telemetry of the same instant (Defaults, the
  telemetry 0.5 s late on the downlink): with the robot's own model the residual is the
  integrators' difference, micrometres (under 1 mm is the claim); with the onboard stiffness
  20 % off the model it grows by more than ten times and the display's residual passes the
  warning; through an outage of the downlink the display says how long no telemetry came,
  the prediction keeps running on the commands sent, and afterwards is as good as before.
* Each residual is recomputed here from predicted.csv against the tracker's own record of the
  instant (not the telemetry the predictor read), so an instant off by one sample shows.
* A session (the console driven by a script) writes the operator's hand as a recording;
  `simulate` replaying it sends the same commands, and `compare` runs on it.
"""

import csv

import numpy as np
import pytest

from telesmooth.console.input import ConsoleInputs, console_params, reach_saturation
from telesmooth.console.status import StatusInputs, status_lines
from telesmooth.diagrams.scenario import LoadScenario
from telesmooth.diagrams.simulation import simulate
from telesmooth.diagrams.teleop import MakeTeleopDiagram, console_pose_names
from telesmooth.scripts.cli import main
from telesmooth.scripts.teleop import console_scenario
from telesmooth.scripts.teleop_report import write_teleop_report
from telesmooth.systems.flexible_arm import MakeSimulator
from telesmooth.systems.operator_console import OperatorConsole

DOWNLINK = "{delay_s: 0.5}"
LAB_STIFFNESS = (500.0, 300.0, 100.0)   # the lab preset of the air-bearing arm, N·m/rad
DURATION_S = 33.5                        # Defaults: the recording + 3 s settle


def _run(text, duration_s=DURATION_S):
    scenario = LoadScenario(scenario_text=text)
    handles = MakeTeleopDiagram(scenario)
    simulator = MakeSimulator(handles.diagram, scenario.onboard)
    simulator.Initialize()
    simulator.AdvanceTo(duration_s)
    return handles, simulator.get_context()


@pytest.fixture(scope="module")
def nominal():
    return _run("{link: {downlink: " + DOWNLINK + "}}")


@pytest.fixture(scope="module")
def stiffer():
    stiffness = [1.2 * k for k in LAB_STIFFNESS]
    return _run(f"{{link: {{downlink: {DOWNLINK}}}, onboard: {{drive: "
                f"{{stiffness_n_m_per_rad: {stiffness}}}}}, predictor: {{drive: "
                "{preset: lab}}}")


@pytest.fixture(scope="module")
def outage():
    return _run("{link: {downlink: {delay_s: 0.5, outages: [[10.0, 14.0]]}}}")


def _residuals(handles):
    r = handles.predictor.residuals
    return (np.array([x.t_s for x in r]), np.array([x.residual_m for x in r]),
            np.array([x.horizon_s for x in r]))


def test_with_the_robots_own_model_the_prediction_is_within_a_millimetre(nominal):
    handles, _ = nominal
    t, residual, horizon = _residuals(handles)
    # One measured prediction per display period from the first telemetry to the last.
    assert t.size >= int((DURATION_S - 0.6) / 0.04) - 2
    assert np.all(np.diff(t) > 0)
    assert residual.max() < 1e-3
    assert residual.max() < 2e-5            # the integrators' difference, measured ~3 µm
    # Before the first telemetry arrived (0.5 s) each prediction ran from the start; after,
    # ahead of its telemetry by the downlink's delay and the sample's age, plus up to a
    # re-synchronisation period and the catch-up of a new look-ahead (the horizon at three
    # display periods of copy-time per update: ceil(0.71 / 0.08) = 9 updates, 0.36 s).
    early = t < 0.5
    np.testing.assert_allclose(horizon[early], t[early], atol=1e-9)
    late = horizon[~early]
    assert np.all(late >= 0.5 - 1e-9) and np.all(late <= 0.5 + 0.01 + 0.2 + 0.36 + 1e-9)
    assert np.median(late) > 0.55


def test_each_residual_is_the_distance_to_the_robot_at_that_instant(nominal, tmp_path):
    handles, context = nominal
    write_teleop_report(tmp_path, handles, context)
    with open(tmp_path / "predicted.csv", newline="") as f:
        rows = list(csv.reader(f))
    assert rows[0][:2] == ["t", "horizon_s"] and rows[0][-1] == "residual_m"
    data = np.array(rows[1:], dtype=float)
    telemetry = np.loadtxt(tmp_path / "telemetry.csv", delimiter=",", skiprows=1)
    index = {round(t * 100): i for i, t in enumerate(telemetry[:, 0])}
    measured = telemetry[[index[round(t * 100)] for t in data[:, 0]], -3:]
    np.testing.assert_allclose(data[:, 5:8], measured, rtol=0, atol=1e-15)
    np.testing.assert_allclose(np.linalg.norm(data[:, 2:5] - measured, axis=1), data[:, 8],
                               rtol=1e-12, atol=1e-15)
    # One sample off (10 ms): the robot moves, so the distances are not these.
    shifted = telemetry[[index[round(t * 100) + 1] for t in data[:, 0]], -3:]
    assert np.max(np.linalg.norm(data[:, 2:5] - shifted, axis=1)) > 20 * data[:, 8].max()


def test_a_model_twenty_percent_stiff_shows_in_the_residual_and_the_display(nominal,
                                                                             stiffer):
    _, nominal_residual, _ = _residuals(nominal[0])
    handles, context = stiffer
    _, residual, _ = _residuals(handles)
    assert residual.max() > 10 * nominal_residual.max()
    # What the display shows: the largest residual of the last 2 s, against its warning.
    shown = handles.logs["predictor_residual"].FindLog(context).data()[0]
    warning = handles.scenario.predictor.residual_warning_m
    assert np.nanmax(shown) > warning
    nominal_shown = nominal[0].logs["predictor_residual"].FindLog(nominal[1]).data()[0]
    assert np.nanmax(nominal_shown) < warning
    lines = status_lines(_status(residual_m=float(np.nanmax(shown)), warning=warning))
    assert any(line.startswith("PREDICTION OFF") for line in lines)


def _status(*, residual_m=float("nan"), warning=1e-4, silence_s=0.02):
    return StatusInputs(
        enabled=True, stop=False, notice=0, saturated=False, telemetry_age_s=0.51,
        telemetry_silence_s=silence_s, robot_guard_mode=0, stream_distance_rad=0.0,
        holding=False, collision=False, min_distance_m=0.17, ik_failure="",
        sigma=np.full(3, 4e-4), acceleration_ratio=np.zeros(3), jerk_ratio=np.zeros(3),
        residual_m=residual_m, residual_warning_m=warning)


def test_through_a_downlink_outage_the_prediction_runs_on_the_commands_sent(outage):
    handles, context = outage
    logs = handles.logs
    silence_log = logs["predictor_telemetry_silence"].FindLog(context)
    t, silence = silence_log.sample_times(), silence_log.data()[0]
    # The last telemetry sent before the outage (t < 10 s) arrives 0.5 s later; then none
    # until the first after it (14 s) arrives at 14.5 s.
    during = (t > 11.6) & (t < 14.4)
    assert np.all(silence[during] > 1.0)
    assert silence[during].max() > 3.5
    longest = float(silence[during].max())
    lines = status_lines(_status(silence_s=longest))
    assert f"link: NO TELEMETRY FOR {longest:.1f} s" in " ".join(lines)
    # The predicted robot moves through the outage (the operator's motion goes on).
    q_log = logs["predictor_q_predicted"].FindLog(context)
    q = q_log.data().T
    inside = (q_log.sample_times() > 11.0) & (q_log.sample_times() < 14.0)
    assert np.ptp(q[inside], axis=0).max() > 0.05
    # No prediction could be measured inside it; after it, as good as ever.
    r_t, residual, _ = _residuals(handles)
    assert not np.any((r_t >= 10.0 + 1e-9) & (r_t < 14.0 - 1e-9))
    assert residual[r_t >= 14.0].max() < 1e-3


class _ScriptedControls:
    """A stand-in for the page: Enable at 0.5 s, then the x slider moved 5 mm per key press
    at 20 Hz for 2 s, the y slider back later, and nothing else."""

    def __init__(self, pose0):
        self.pose0 = np.asarray(pose0, dtype=float)
        self.time = 0.0
        self.sliders = self.pose0.copy()

    def read(self, anchor_pose=None):
        t = self.time
        self.time += 0.01
        sliders = self.sliders.copy()
        if 1.0 <= t < 3.0:
            sliders[0] = self.pose0[0] + 0.005 * int((t - 1.0) * 20 + 1)
        elif t >= 3.0:
            sliders[0] = self.pose0[0] + 0.2
        if t >= 4.0:
            sliders[1] = self.pose0[1] - 0.05
        self.sliders = sliders
        return ConsoleInputs(sliders=sliders, enable_clicks=1 if t >= 0.5 else 0)

    def set_sliders(self, pose):
        self.sliders = np.asarray(pose, dtype=float)


def test_a_session_replays_as_a_recording(tmp_path):
    scenario = console_scenario(LoadScenario())
    names = console_pose_names(scenario)
    pose0 = np.array(scenario.haptic.live_initial_pose)
    console = OperatorConsole(
        console_params(names, saturate=reach_saturation(scenario.arm)),
        _ScriptedControls(pose0), initial_pose=pose0)
    handles = MakeTeleopDiagram(scenario, console=console)
    simulator = MakeSimulator(handles.diagram, scenario.onboard)
    simulator.Initialize()
    simulator.AdvanceTo(12.0)
    out = tmp_path / "session"
    write_teleop_report(out, handles, simulator.get_context())
    assert (out / "report.md").read_text().startswith("# telesmooth teleop")
    session = np.loadtxt(out / "commands.csv", delimiter=",", skiprows=1)
    # The hand moved +x by 0.2 m and the robot was sent there.
    assert session[-1, 3] != session[0, 3]
    replay = simulate(LoadScenario(scenario_text="{haptic: {source: file, file: '%s'}}"
                                    % (out / "operator.npz")), duration_s=12.0)
    count = min(len(replay.packet_seq), session.shape[0])
    assert count >= 47
    np.testing.assert_array_equal(replay.packet_state[:count, :3], session[:count, 3:6])
    # compare runs every method on the operator's own hand.
    assert main(["compare", "--scenario-text",
                 "{haptic: {source: file, file: '%s'}}" % (out / "operator.npz"),
                 "--methods", "original,online-cks", "--out", str(tmp_path / "cmp")]) == 0
    assert (tmp_path / "cmp" / "report.md").exists()
