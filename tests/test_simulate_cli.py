"""`telesmooth simulate`: files, figures recomputed from the written tables, clear errors."""

import csv
import json

import numpy as np
import pytest

from telesmooth.scripts.cli import main


def _read(path):
    with open(path, newline="") as handle:
        rows = list(csv.reader(handle))
    return rows[0], np.array(rows[1:], dtype=float)


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    out = tmp_path_factory.mktemp("simulate")
    assert main(["simulate", "--duration", "6", "--out", str(out)]) == 0
    return out


def test_writes_every_file(run):
    for name in ("report.md", "metrics.json", "commands.csv", "telemetry.csv", "targets.csv",
                 "joints.png", "acceleration_jerk.png", "end_effector.png",
                 "tracking_error.png", "error_along_path.png", "sigma_collision.png"):
        assert (run / name).is_file(), name
    assert (run / "joints.png").stat().st_size > 10_000
    text = (run / "report.md").read_text()
    # The report names the demonstration, states the plant's modes, and links no replay
    # that was not made.
    assert "the LASA demonstration `Angle` #0 at 1× the demonstrator's hand speed" in text
    assert "Plant: `air_bearing_arm`, drive preset `lab` (continuous)" in text
    assert "2.66 Hz (ζ 0.072)" in text and "run.html" not in text


def test_packets_are_4hz_and_metrics_match_the_written_commands(run):
    header, commands = _read(run / "commands.csv")
    assert header[:3] == ["seq", "send_t", "sample_t"]
    np.testing.assert_array_equal(commands[:, 0], np.arange(len(commands)))
    np.testing.assert_allclose(commands[:, 1], 0.25 * commands[:, 0], atol=1e-9)
    assert len(commands) == 25                      # ticks 0, 0.25, …, 6.0
    metrics = json.loads((run / "metrics.json").read_text())
    assert metrics["num_packets"] == 25
    q = commands[commands[:, 2] >= 0.0][:, 3:6]     # packets that estimate t >= 0
    acc = np.abs(np.diff(q, n=2, axis=0)) / 0.25**2
    np.testing.assert_allclose(metrics["commands"]["fd_acceleration"]["max_abs"],
                               acc.max(axis=0), rtol=1e-9, atol=1e-12)


def test_telemetry_is_100hz_and_tool_position_is_planar_fk(run):
    from telesmooth.arms.planar import AIR_BEARING_ARM, planar_forward_kinematics

    header, telemetry = _read(run / "telemetry.csv")
    np.testing.assert_allclose(np.diff(telemetry[:, 0]), 0.01, atol=1e-9)
    xy = planar_forward_kinematics(telemetry[:, 1:4], AIR_BEARING_ARM.link_lengths_m)
    np.testing.assert_allclose(telemetry[:, 7:9], xy, atol=1e-9)


def test_bad_scenario_text_exits_2_naming_the_key(tmp_path, capsys):
    code = main(["simulate", "--scenario-text", "{fifo: {delay_s: 0.3}}", "--out",
                 str(tmp_path / "x")])
    assert code == 2
    assert "delay_s = 0.3" in capsys.readouterr().err
    assert not (tmp_path / "x").exists()


def test_on_collision_flag_overrides_the_scenario(tmp_path):
    from telesmooth.scripts.cli import _load_scenario, build_parser

    parser = build_parser()
    for command in ("simulate", "ground", "onboard", "compare", "experiment"):
        args = parser.parse_args([command, "--on-collision", "stop"])
        assert _load_scenario(args).fifo.on_collision == "stop", command
        args = parser.parse_args([command])
        assert _load_scenario(args).fifo.on_collision == "hold", command
    with pytest.raises(SystemExit):
        parser.parse_args(["simulate", "--on-collision", "brake"])
    out = tmp_path / "stop"
    assert main(["simulate", "--duration", "2", "--on-collision", "stop", "--out",
                 str(out)]) == 0
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["scenario"]["on_collision"] == "stop"
    assert "on collision `stop`" in (out / "report.md").read_text()
