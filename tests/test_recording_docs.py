"""The examples of docs/commands.md, "Your own recordings", work as written.

Each example file (the fenced block after ``<!-- recording example: NAME -->``) is written to
a folder, read with the package's reader, and every command of the ``<!-- recording commands
-->`` blocks is run there as the docs give it (``simulate`` with a short ``--duration``,
``compare`` on one method). The joint targets the chain's inverse kinematics logged
(``targets.csv``) are then checked against the poses the docs say the tool is commanded to:
every sample of each example is reached (so each is within reach and the joint limits, and no
joint step is refused), the clutch example holds while released and ends where the docs say.
"""

import math
import re
import runpy
import shlex
from pathlib import Path

import numpy as np
import pytest

from telesmooth.arms.description import SPACE_ARM_6DOF
from telesmooth.arms.planar import (
    AIR_BEARING_ARM,
    planar_3r_inverse_kinematics,
    planar_end_effector_angle,
    planar_forward_kinematics,
)
from telesmooth.datasets.haptic_recording import (
    PLANAR_POSE_NAMES,
    SPATIAL_POSE_NAMES,
    read_haptic_csv,
    read_haptic_npz,
)
from telesmooth.scripts.cli import main

DOCS = Path(__file__).resolve().parent.parent / "docs" / "commands.md"
HEADING = "## Your own recordings"
FENCE = re.compile(r"```(\w*)\n(.*?)```", re.DOTALL)


def _section() -> str:
    text = DOCS.read_text()
    start = text.index("\n" + HEADING + "\n")
    return text[start:text.index("\n## ", start + 1)]


def _blocks(marker: str):
    """(name after the marker, language, content) of each fenced block right under
    ``<!-- marker[: name] -->``."""
    section = _section()
    found = []
    for match in re.finditer(rf"<!-- {re.escape(marker)}(?:: (\S+))? -->\n", section):
        fence = FENCE.match(section, match.end())
        assert fence is not None, f"no fenced block right under {match.group(0)!r}"
        found.append((match.group(1), fence.group(1), fence.group(2)))
    return found


EXAMPLES = {name: text for name, _, text in _blocks("recording example")}
COMMAND_BLOCKS = _blocks("recording commands")
COMMANDS = [line for _, _, text in COMMAND_BLOCKS for line in text.splitlines() if line.strip()]


def test_the_section_has_an_example_per_arm_a_python_one_and_their_commands():
    assert set(EXAMPLES) == {"planar.csv", "space_arm.csv", "write_npz.py"}
    assert {language for _, language, _ in COMMAND_BLOCKS} == {"sh"}
    for name in ("planar.csv", "space_arm.csv", "my.npz"):
        assert any(f"file: {name}" in line for line in COMMANDS), name
    assert any(line.startswith(".venv/bin/telesmooth compare ") for line in COMMANDS)
    assert "{arm: space_arm, haptic: {source: file, file: space_arm.csv" in "".join(COMMANDS)


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    """The examples written out, the Python one run, and every documented command run."""
    folder = tmp_path_factory.mktemp("recordings")
    for name, text in EXAMPLES.items():
        (folder / name).write_text(text)
    with pytest.MonkeyPatch.context() as patch:
        patch.chdir(folder)
        runpy.run_path(str(folder / "write_npz.py"), run_name="__main__")
        for line in COMMANDS:
            argv = shlex.split(line)
            assert argv[0] == ".venv/bin/telesmooth", line
            argv = argv[1:]
            if argv[0] == "simulate":
                argv += ["--duration", str(_duration(folder, argv))]
            elif argv[0] == "compare":
                argv += ["--methods", "online-cks"]
            assert main(argv) == 0, line
    return folder


def _recording_name(argv) -> str:
    return re.search(r"file: ([^,}]+)", argv[argv.index("--scenario-text") + 1]).group(1)


def _duration(folder, argv) -> float:
    """The recording's length and one second: every target is logged, no settle time."""
    path = folder / _recording_name(argv)
    recording = read_haptic_npz(path) if path.suffix == ".npz" else read_haptic_csv(path)
    return float(recording.t_s[-1] - recording.t_s[0]) + 1.0


def _out(file: str) -> Path:
    line = next(line for line in COMMANDS if f"file: {file}" in line
                and " simulate " in f" {line} ")
    argv = shlex.split(line)
    return Path(argv[argv.index("--out") + 1])


def _targets(folder, file):
    data = np.loadtxt(folder / _out(file) / "targets.csv", delimiter=",",
                      skiprows=1)
    return data[:, 0], data[:, 1:]


def _planar_poses(q) -> np.ndarray:
    xy = planar_forward_kinematics(q, AIR_BEARING_ARM.link_lengths_m)
    return np.column_stack([xy, planar_end_effector_angle(q)])


def _commanded_planar(recording) -> np.ndarray:
    """The tool poses the docs describe for a planar recording with a clutch: absolute while
    engaged from the start; held while released; after re-engaging, the hand's motion added
    to the held pose (an offset in x, y, phi). NaN rows: held (no new command)."""
    commands = np.full(recording.pose.shape, np.nan)
    offset = np.zeros(3)
    held = recording.pose[0]
    engaged = True
    for k, (pose, enable) in enumerate(zip(recording.pose, recording.enable)):
        if not enable:
            engaged = False
            continue
        if not engaged:
            offset = held - pose
            engaged = True
        held = commands[k] = pose + offset
    return commands


def test_the_planar_example_reads_and_every_pose_is_within_reach(folder):
    recording = read_haptic_csv(folder / "planar.csv", expected_pose_names=PLANAR_POSE_NAMES)
    assert recording.period_s == pytest.approx(0.25, rel=1e-12)
    commands = _commanded_planar(recording)
    commanded = commands[~np.isnan(commands[:, 0])]
    _, reachable = planar_3r_inverse_kinematics(commanded[:, :2], commanded[:, 2],
                                                AIR_BEARING_ARM)
    assert reachable.all()
    # The docs' words: released at 1.25 s, re-engaged at 1.75 s, held at (0.73, 0.03)
    # meanwhile, ends at (0.75, 0.03) rather than the hand's (0.72, 0).
    released = recording.t_s[~recording.enable]
    assert released.tolist() == [1.25, 1.5]
    assert np.allclose(commands[4], [0.73, 0.03, 0.0], atol=1e-12)
    assert np.allclose(commands[-1], [0.75, 0.03, 0.0], atol=1e-12)
    assert np.allclose(recording.pose[-1], [0.72, 0.0, 0.0], atol=1e-12)


def test_the_chain_reaches_every_planar_command_and_holds_while_released(folder):
    recording = read_haptic_csv(folder / "planar.csv")
    commands = _commanded_planar(recording)
    t, q = _targets(folder, "planar.csv")
    reached = _planar_poses(q)
    for k in np.flatnonzero(~np.isnan(commands[:, 0])):
        distance = np.abs(reached - commands[k]).max(axis=1)
        assert (distance < 1e-9).any(), (k, commands[k])
    # While released (targets logged from 1.25 s up to the re-engaged command) the target
    # is the held pose; the last is the re-indexed end.
    hold = (t > 1.25) & (t <= 1.75)
    assert hold.any() and np.abs(reached[hold] - [0.73, 0.03, 0.0]).max() < 1e-9
    assert np.abs(reached[-1] - [0.75, 0.03, 0.0]).max() < 1e-9


def test_the_chain_reaches_every_pose_of_the_six_dof_example(folder):
    from telesmooth.arms.space_arm_ik import SpaceArmKinematics

    recording = read_haptic_csv(folder / "space_arm.csv",
                                expected_pose_names=SPATIAL_POSE_NAMES)
    # It starts in the arm's x-z plane through the shoulder (y = roll = yaw = 0), as the docs
    # require for the start pose.
    assert recording.pose[0, 1] == 0.0 and recording.pose[0, 3] == recording.pose[0, 5] == 0.0
    # The docs' words: 4 cm sideways (+y), 4 cm up, 0.08 rad about the vertical (yaw).
    assert np.allclose(recording.pose[-1] - recording.pose[0],
                       [0.0, 0.04, 0.04, 0.0, 0.0, 0.08], atol=1e-12)
    kinematics = SpaceArmKinematics(SPACE_ARM_6DOF)
    _, q = _targets(folder, "space_arm.csv")
    reached = np.array([kinematics.tool_pose(row) for row in q])
    lower, upper = np.asarray(SPACE_ARM_6DOF.joint_lower_rad), SPACE_ARM_6DOF.joint_upper_rad
    assert ((q >= lower) & (q <= np.asarray(upper))).all()
    for pose in recording.pose:
        position = np.linalg.norm(reached[:, :3] - pose[:3], axis=1)
        angle = np.abs(reached[:, 3:] - pose[3:]).max(axis=1)   # small angles: no wrap
        assert ((position < 1e-4) & (angle < 1e-3)).any(), pose
    assert np.linalg.norm(reached[-1, :3] - recording.pose[-1, :3]) < 1e-4


def test_the_python_example_writes_a_100_hz_recording_the_chain_follows(folder):
    recording = read_haptic_npz(folder / "my.npz", expected_pose_names=PLANAR_POSE_NAMES)
    assert recording.num_samples == 601 and recording.enable.all()
    assert recording.period_s == pytest.approx(0.01, rel=1e-9)
    # The docs' words: rest 1 s, 10 cm along +x and 5 cm along +y in 4 s, rest 1 s.
    t, pose = recording.t_s, recording.pose
    assert np.allclose(pose[t <= 1.0], [0.70, 0.0, 0.0], atol=1e-12)
    assert np.allclose(pose[t >= 5.0], [0.80, 0.05, 0.0], atol=1e-12)
    assert np.all(np.diff(pose[:, 0]) >= 0.0) and np.all(np.diff(pose[:, 1]) >= 0.0)
    # write_haptic_csv writes the same recording as CSV.
    from telesmooth.datasets.haptic_recording import write_haptic_csv

    write_haptic_csv(folder / "my_copy.csv", recording)
    copy = read_haptic_csv(folder / "my_copy.csv", expected_pose_names=PLANAR_POSE_NAMES)
    assert np.array_equal(copy.t_s, recording.t_s) and np.array_equal(copy.pose, pose)
    _, q = _targets(folder, "my.npz")
    assert np.abs(_planar_poses(q)[-1] - [0.80, 0.05, 0.0]).max() < 1e-9


@pytest.mark.parametrize("file", ["planar.csv", "space_arm.csv", "my.npz"])
def test_each_report_names_its_recording(folder, file):
    report = (folder / _out(file) / "report.md").read_text()
    assert f"operator: the recording `{file}`" in report


def test_compare_ran_on_the_planar_example(folder):
    line = next(line for line in COMMANDS if line.startswith(".venv/bin/telesmooth compare "))
    argv = shlex.split(line)
    table = (folder / argv[argv.index("--out") + 1] / "table.md").read_text()
    assert "| online-cks |" in table and "| original |" in table


def test_the_example_poses_are_where_the_docs_say_the_frames_put_them():
    # The 6-DOF example starts at the pose the planar examples start at, lifted into the x-z
    # plane through the shoulder: (x, y, phi) -> (x, 0, 0.45 + y, 0, -phi, 0).
    from telesmooth.arms.air_bearing import SHOULDER_IN_BASE_M, planar_pose_to_space_arm

    assert tuple(SHOULDER_IN_BASE_M) == (0.0, 0.0, 0.45)
    lifted = planar_pose_to_space_arm([0.70, 0.0, 0.0])
    first = np.array(EXAMPLES["space_arm.csv"].splitlines()[1].split(","), dtype=float)[1:]
    assert np.allclose(lifted, first, atol=1e-12)
    # Raising the arm (positive shoulder pitch) is a negative pitch, as the docs say.
    from telesmooth.arms.space_arm_ik import SpaceArmKinematics

    raised = SpaceArmKinematics(SPACE_ARM_6DOF).tool_pose([0.0, 0.3, 0.0, 0.0, 0.0, 0.0])
    assert raised[2] > 0.45 and math.isclose(raised[4], -0.3, abs_tol=1e-9)


def test_the_limits_the_docs_give_are_the_scenarios():
    """docs/commands.md's smooth section states the chain's own limits: they are those of
    Defaults (every joint) and OneOfEverything (per joint)."""
    from telesmooth.diagrams.scenario import LoadScenario

    text = (Path(__file__).resolve().parents[1] / "docs" / "commands.md").read_text()
    text = " ".join(text.split())
    assert ("0.05 rad/s² and 0.1 rad/s³ on every joint by default (`OneOfEverything`: "
            "acceleration 0.05 on the 6-DOF arm's first three joints, 0.2 on the wrist's)"
            ) in text
    defaults = LoadScenario().smoother
    assert (defaults.max_acceleration_rad_per_s2, defaults.max_jerk_rad_per_s3) == (0.05, 0.1)
    every = LoadScenario(scenario_name="OneOfEverything").smoother
    assert tuple(every.max_acceleration_rad_per_s2) == (0.05,) * 3 + (0.2,) * 3
    assert every.max_jerk_rad_per_s3 == 0.1
