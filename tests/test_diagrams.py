"""Diagrams and scenarios: built-in scenarios run; latency end to end; LCM split == in-process."""

import numpy as np
import pytest
from pydrake.lcm import DrakeLcm
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder

from telesmooth.datasets.haptic_recording import HapticRecording, write_haptic_csv
from telesmooth.diagrams.scenario import LoadScenario, Scenario
from telesmooth.diagrams.teleoperation import (
    MakeGroundDiagram,
    MakeOnboardDiagram,
    MakeTeleoperationDiagram,
    uplink_packets,
)
from telesmooth.systems.laser_tracker import tracker_record

TICK = 0.25
LAG = 3


packets = uplink_packets   # per packet: (seq, send_time, state_sent), deduplicated


@pytest.mark.parametrize("name,duration", [("Defaults", 4.0), ("OneOfEverything", None)])
def test_builtin_scenarios_run(name, duration):
    scenario = LoadScenario(scenario_name=name)
    handles = MakeTeleoperationDiagram(scenario)
    end = duration or handles.ground.recording.t_s[-1] + scenario.settle_s
    simulator = Simulator(handles.diagram)
    simulator.AdvanceTo(end)
    context = simulator.get_context()
    assert context.get_time() == pytest.approx(end)
    seq, times, states = packets(handles, context)
    assert list(seq) == list(range(len(seq))) and len(seq) >= int(end / TICK) - 1
    np.testing.assert_allclose(times, TICK * seq, atol=1e-12)
    for log in handles.logs.values():
        assert np.all(np.isfinite(log.FindLog(context).data()))
    q_link = tracker_record(handles.logs["tracker"].FindLog(context).data().T).q_link
    n = handles.ground.initial_position_rad.size
    # The robot follows the commands: link angles end near the last sent positions.
    assert np.abs(q_link[-1] - states[-1, :n]).max() < 0.05


def _step_recording(tmp_path):
    t = np.arange(0, 6.0, 0.01)
    pose = np.tile([0.7, 0.0, 0.0], (t.size, 1))
    pose[t >= 2.0, 0] = 0.72          # a 2 cm step of the hand at t = 2 s
    path = tmp_path / "step.csv"
    write_haptic_csv(path, HapticRecording(t_s=t, pose=pose, enable=np.ones(t.size, bool),
                                           pose_names=("x_m", "y_m", "phi_rad")))
    return path


def test_pass_through_command_leaves_exactly_three_ticks_after_the_ik_target(tmp_path):
    path = _step_recording(tmp_path)
    scenario = LoadScenario(scenario_text=(
        f"{{haptic: {{source: file, file: '{path}'}}, smoother: {{method: pass-through}}, "
        "settle_s: 0.5}"))
    handles = MakeTeleoperationDiagram(scenario)
    simulator = Simulator(handles.diagram)
    simulator.AdvanceTo(6.0)
    context = simulator.get_context()
    seq, _, states = packets(handles, context)
    q_target = handles.logs["q_target"].FindLog(context)
    target_times, targets = q_target.sample_times(), q_target.data().T
    for k, state in zip(seq, states):
        if k < LAG:
            continue
        # The FIFO took the IK target as seen at t_{k−3} (the 100 Hz logger sees the same
        # pre-update value at that instant).
        row = int(np.argmin(np.abs(target_times - (k - LAG) * TICK)))
        np.testing.assert_array_equal(state[:3], targets[row], err_msg=f"packet {k}")
    moved = seq[np.argmax(np.abs(states[:, 0] - states[0, 0]) > 1e-6)]
    first_target_move = np.argmax(np.abs(targets[:, 0] - targets[0, 0]) > 1e-6)
    # The hand moved at 2.00 s; the IK target changes 1 sample later (2.01 s); the first
    # 4 Hz tick that samples it is 2.25 s (k = 9) and the robot gets it at k = 12 (3.00 s).
    assert target_times[first_target_move] == pytest.approx(2.01)
    assert moved == 12


def test_lcm_split_sends_the_same_commands_as_the_single_process(tmp_path):
    scenario = LoadScenario(scenario_text="{settle_s: 0.0}")
    duration = 6.0
    single = MakeTeleoperationDiagram(scenario)
    simulator = Simulator(single.diagram)
    simulator.AdvanceTo(duration)
    seq, _, states = packets(single, simulator.get_context())

    lcm = DrakeLcm("memq://")
    ground = MakeGroundDiagram(scenario, lcm=lcm)
    onboard = MakeOnboardDiagram(scenario, lcm=lcm)
    builder = DiagramBuilder()
    builder.AddSystem(ground.diagram)
    builder.AddSystem(onboard.diagram)
    split = Simulator(builder.Build())
    split.AdvanceTo(duration)
    context = split.get_context()
    received_seq = onboard.logs["last_command_seq"].FindLog(context).data()[0]
    commanded = onboard.logs["q_accepted"].FindLog(context).data().T
    n = 3
    checked = 0
    for k, state in zip(seq, states):
        rows = np.flatnonzero(received_seq == k)
        if rows.size == 0:
            continue
        np.testing.assert_array_equal(commanded[rows[0]], state[:n], err_msg=f"packet {k}")
        checked += 1
    assert checked >= len(seq) - 2
    # The onboard side got packet k a few ms after t_k: never before, at most one poll late.
    times = onboard.logs["last_command_seq"].FindLog(context).sample_times()
    for k in (4, 10, 20):
        first = times[np.argmax(received_seq >= k)]
        assert k * TICK < first <= k * TICK + 0.02 + 1e-9


@pytest.mark.parametrize("text,match", [
    ("{arm: scara}", r"arm = 'scara'"),
    ("{fifo: {delay_s: 0.8}}", r"delay_s = 0.8 is not a whole number"),
    ("{smoother: {sigma: -1.0}}", r"with scenario_text: smoother.sigma = -1.0 must be positive"),
    ("{smoother: {max_jerk_rad_per_s3: [0.1, 0.0, 0.1]}}",
     r"smoother.max_jerk_rad_per_s3\[1\] = 0.0 for joint 1 \('elbow'\)"),
    ("{smoother: {colour: red}}", r"smoother: unknown key\(s\) \['colour'\]"),
    ("{haptic: {source: file}}", r"haptic.file must name"),
    ("{uplink: {period_s: 0.5}}", r"share one period"),
    ("{initial_position_rad: [0.0, 0.0, 9.0]}",
     r"initial_position_rad\[2\] = 9.0 for joint 2 \('wrist'\) must be finite and within"),
    ("{settle_s: yes}", r"with scenario_text: settle_s = True must be a number"),
    ("{haptic: {period_s: -100}}", r"haptic.period_s = -100.0 must be positive"),
    ("{haptic: {lasa_shape: Sshap}}", r"haptic.lasa_shape = 'Sshap' is not one of the 30 "
                                      r"LASA shapes; did you mean 'Sshape'"),
    ("{haptic: {lasa_demo: 7}}", r"haptic.lasa_demo = 7 is out of range"),
    ("{fifo: {period_s: 0}, smoother: {period_s: 0}, uplink: {period_s: 0}}",
     r"fifo.period_s = 0.0 must be positive"),
    ("{smoother: {lag: 4000}, fifo: {delay_s: 1000}}", r"smoother.lag = 4000 must be an integer "
                                                       r"in 0..1000"),
    ("{1: 2}", r"scenario_text: line 1: the key '1' in the top level is an integer"),
    ("{~: 2}", r"scenario_text: line 1: the key '~' in the top level is null"),
    ("{haptic: {lasa_demo: 1, lasa_demo: 2}}", r"'haptic.lasa_demo' is given twice"),
    ("{arm: [", r"scenario_text: not valid YAML at line 1, column 8"),
    ("[1, 2]", r"scenario_text must be a mapping at the top level; got list"),
    ("{settle_s: .nan}", r"settle_s = nan"),
    ("{fifo: {delay_s: .inf}}", r"delay_s = inf"),
    ("{smoother: {max_jerk_rad_per_s3: [0.1, .nan, 0.1]}}", r"max_jerk_rad_per_s3\[1\] = nan"),
])
def test_scenario_errors_name_the_key_and_value(text, match):
    with pytest.raises(ValueError, match=match):
        LoadScenario(scenario_text=text)


def test_unknown_scenario_name_lists_the_known_ones():
    with pytest.raises(ValueError, match=r"'Nope' is not in .*\['Defaults', 'OneOfEverything'\]"):
        LoadScenario(scenario_name="Nope")


def test_scenario_file_errors_name_the_file(tmp_path):
    broken = tmp_path / "broken.yaml"
    broken.write_text("Defaults:\n  arm: [space_arm\n")
    with pytest.raises(ValueError,
                       match=r"scenario file = '.*broken.yaml': not valid YAML at line"):
        LoadScenario(filename=broken)
    with pytest.raises(ValueError, match=r"scenario file = '.*missing.yaml': cannot read"):
        LoadScenario(filename=tmp_path / "missing.yaml")


def test_yaml_syntax_error_exits_2_without_a_traceback(tmp_path, capsys):
    from telesmooth.scripts.cli import main

    assert main(["simulate", "--scenario-text", "{arm: [", "--out", str(tmp_path / "x")]) == 2
    err = capsys.readouterr().err
    assert "not valid YAML at line 1, column 8" in err and "Traceback" not in err
    assert not (tmp_path / "x").exists()


def test_defaults_scenario_is_the_dataclass_default():
    assert LoadScenario() == Scenario()


def test_a_haptic_file_in_other_units_or_for_another_arm_is_named(tmp_path):
    from telesmooth.diagrams.scenario import make_haptic_recording

    def write(name, header, row):
        path = tmp_path / name
        lines = [",".join(["t", *header])] + [",".join(str(v) for v in [0.01 * k, *row])
                                               for k in range(5)]
        path.write_text("\n".join(lines) + "\n")
        return path

    good = write("good.csv", ["x_m", "y_m", "phi_rad"], [0.8, 0.1, 0.0])
    recording = make_haptic_recording(LoadScenario(
        scenario_text=f"{{haptic: {{source: file, file: '{good}'}}}}"))
    assert recording.pose.shape == (5, 3)
    millimetres = write("mm.csv", ["x_mm", "y_mm", "phi_rad"], [800.0, 100.0, 0.0])
    with pytest.raises(ValueError, match=r"haptic.file = '.*mm.csv': the pose columns "
                                         r"\['x_mm', 'y_mm', 'phi_rad'\] are not a pose of the "
                                         r"arm 'air_bearing_arm'; expected \['x_m', 'y_m', "
                                         r"'phi_rad'\] \(metres and radians\)"):
        make_haptic_recording(LoadScenario(
            scenario_text=f"{{haptic: {{source: file, file: '{millimetres}'}}}}"))
    spatial = write("6dof.csv", ["x_m", "y_m", "z_m", "roll_rad", "pitch_rad", "yaw_rad"],
                    [0.8, 0.1, 0.0, 0.0, 0.0, 0.0])
    with pytest.raises(ValueError, match=r"6dof.csv': a 6-DOF pose .* needs arm: space_arm; "
                                         r"the arm 'air_bearing_arm' reads"):
        make_haptic_recording(LoadScenario(
            scenario_text=f"{{haptic: {{source: file, file: '{spatial}'}}}}"))
