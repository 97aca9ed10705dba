"""Visualization: Meshcat on localhost only, a self-contained offline HTML, the diagram SVG."""

import base64
import re
import shutil
from pathlib import Path

import numpy as np
import pytest
from pydrake.geometry import Meshcat, Rgba
from pydrake.systems.framework import DiagramBuilder

from telesmooth.arms.workspace import AIR_BEARING_WORKSPACE, SPACE_ARM_WORKSPACE
from telesmooth.datasets.haptic_recording import SPATIAL_POSE_NAMES, HapticRecording
from telesmooth.diagrams import visualization
from telesmooth.diagrams.scenario import LoadScenario
from telesmooth.diagrams.simulation import record_meshcat_html
from telesmooth.diagrams.teleoperation import MakeTeleoperationDiagram
from telesmooth.diagrams.visualization import (
    AddRobotVisualizer,
    commanded_tool_points,
    diagram_svg,
    draw_tool_path,
    draw_workspace,
    local_meshcat,
)
from telesmooth.systems.flexible_arm import FlexibleArmConfig, FlexibleJointArm

REPO = Path(__file__).resolve().parents[1]
HAS_DOT = shutil.which("dot") is not None
needs_dot = pytest.mark.skipif(not HAS_DOT, reason="Graphviz 'dot' is not installed")

# URLs that Meshcat's inline JavaScript carries as strings but never loads: the XHTML
# namespace, the WebXR controller-profile CDN and WebXR/gamepad help links in messages.
KNOWN_INLINE_URL_PREFIXES = (
    "http://www.w3.org/",
    "https://immersiveweb.dev/",
    "https://cdn.jsdelivr.net/npm/@webxr-input-profiles/",
    "https://developer.mozilla.org/",
    "https://beej.us/",
)
STAGES = ("haptic_source", "inverse_kinematics", "collision_checker", "delay_fifo", "smoother",
          "uplink", "robot")


def listening_addresses(port: int) -> set[str] | None:
    """Local addresses with a LISTEN socket on ``port`` (from /proc/net), or None off Linux."""
    found = set()
    for table, width in (("/proc/net/tcp", 8), ("/proc/net/tcp6", 32)):
        try:
            lines = Path(table).read_text().splitlines()[1:]
        except OSError:
            return None
        for line in lines:
            fields = line.split()
            address, local_port = fields[1].split(":")
            if fields[3] != "0A" or int(local_port, 16) != port:
                continue
            # /proc/net prints each 32-bit word in host (little-endian) byte order.
            words = [bytes.fromhex(address[i:i + 8])[::-1] for i in range(0, width, 8)]
            raw = b"".join(words)
            found.add(".".join(str(b) for b in raw) if width == 8 else raw.hex())
    return found


LOOPBACK = {"127.0.0.1", "0" * 31 + "1", "0" * 20 + "ffff" + "7f000001"}


def scene_bytes(html: str) -> bytes:
    """The Meshcat commands embedded in a StaticHtml page (base64 data URLs), concatenated."""
    blobs = re.findall(r'fetch\("data:application/octet-binary;base64,([A-Za-z0-9+/=]*)"\)',
                       html)
    return b"".join(base64.b64decode(blob) for blob in blobs)


def test_local_meshcat_listens_on_loopback_only():
    dut = local_meshcat()
    assert dut.web_url().startswith("http://localhost:")
    addresses = listening_addresses(dut.port())
    if addresses is None:
        pytest.skip("no /proc/net to inspect the listening socket")
    assert addresses and addresses <= LOOPBACK, addresses


def test_record_meshcat_html_is_offline_and_shows_the_robot(tmp_path, monkeypatch):
    hosts = []

    def spy_meshcat(params):
        hosts.append(params.host)
        return Meshcat(params)

    monkeypatch.setattr(visualization, "Meshcat", spy_meshcat)
    scenario = LoadScenario(scenario_text="{settle_s: 0.0}")
    out = tmp_path / "run" / "replay.html"
    messages = []
    figures = record_meshcat_html(scenario, out, duration_s=2.0, progress=messages.append)

    assert hosts == ["localhost"]
    assert figures["meshcat_url"].startswith("http://localhost:")
    assert out.is_file() and figures["html_bytes"] == out.stat().st_size > 100_000
    assert figures["simulated_time_s"] == pytest.approx(2.0)
    assert figures["frames"] == 61            # 30 frames per simulated second, both ends
    assert figures["wall_time_s"] >= figures["simulation_wall_time_s"] > 0.0
    assert any("simulated 2.0 / 2.0 s" in message for message in messages)

    html = out.read_text(encoding="utf-8")
    assert html.count("<script src=") == 0
    assert html.count('src="http') == 0
    assert re.findall(r'fetch\("(?!data:)', html) == []
    urls = re.findall(r"https?://[^\s\"'<>)]*", html)
    assert [u for u in urls if not u.startswith(KNOWN_INLINE_URL_PREFIXES)] == []

    scene = scene_bytes(html)
    for link in ("base", "link1", "link2", "link3"):
        assert f"/drake/robot/air_bearing_arm/{link}".encode() in scene
        assert f"/drake/collision/air_bearing_arm/{link}".encode() in scene
    for box in AIR_BEARING_WORKSPACE.boxes():
        assert f"/drake/workspace/{box.name}".encode() in scene
    assert b"/drake/commanded_tool_path" in scene
    assert b"animation" in scene


def test_record_meshcat_html_rejects_bad_duration(tmp_path):
    with pytest.raises(ValueError, match="duration_s"):
        record_meshcat_html(LoadScenario(), tmp_path / "x.html", duration_s=-1.0)
    assert not (tmp_path / "x.html").exists()


@pytest.mark.parametrize("workspace,num_walls", [(SPACE_ARM_WORKSPACE, 6),
                                                 (AIR_BEARING_WORKSPACE, 4)])
def test_draw_workspace_creates_one_path_per_box(workspace, num_walls):
    meshcat = local_meshcat()
    paths = draw_workspace(meshcat, workspace)
    names = [box.name for box in workspace.obstacles]
    assert len(paths) == len(names) + num_walls
    assert paths[:len(names)] == [f"workspace/{name}" for name in names]
    assert all(meshcat.HasPath(path) for path in paths)
    # Drawing another workspace replaces this one: its boxes that the other lacks are gone.
    other = AIR_BEARING_WORKSPACE if workspace is SPACE_ARM_WORKSPACE else SPACE_ARM_WORKSPACE
    redrawn = draw_workspace(meshcat, other)
    stale = set(paths) - set(redrawn)
    assert stale and not any(meshcat.HasPath(path) for path in stale)
    assert all(meshcat.HasPath(path) for path in redrawn)


def test_draw_tool_path_checks_its_points():
    meshcat = local_meshcat()
    points = np.vstack([np.linspace(0, 1, 5), np.zeros(5), np.zeros(5)])
    assert draw_tool_path(meshcat, "path/a", points, Rgba(1, 0, 0, 1)) == "path/a"
    assert meshcat.HasPath("path/a")
    with pytest.raises(ValueError, match=r"shape \(5, 3\)"):
        draw_tool_path(meshcat, "path/b", points.T)
    points[1, 2] = np.nan
    with pytest.raises(ValueError, match="finite"):
        draw_tool_path(meshcat, "path/c", points)
    assert not meshcat.HasPath("path/b") and not meshcat.HasPath("path/c")


def test_commanded_tool_points_planar_and_spatial():
    t = np.array([0.0, 0.01])
    planar = HapticRecording(t_s=t, pose=np.array([[0.5, -0.2, 0.1], [0.6, -0.1, 0.2]]),
                             enable=np.ones(2, bool), pose_names=("x_m", "y_m", "phi_rad"))
    np.testing.assert_array_equal(commanded_tool_points(planar),
                                  [[0.5, 0.6], [-0.2, -0.1], [0.0, 0.0]])
    pose = np.arange(12.0).reshape(2, 6)
    spatial = HapticRecording(t_s=t, pose=pose, enable=np.ones(2, bool),
                              pose_names=SPATIAL_POSE_NAMES)
    np.testing.assert_array_equal(commanded_tool_points(spatial), pose[:, :3].T)
    assert commanded_tool_points(None) is None


def test_add_robot_visualizer_draws_the_arm():
    builder = DiagramBuilder()
    robot = builder.AddNamedSystem("robot", FlexibleJointArm(FlexibleArmConfig()))
    meshcat = local_meshcat()
    dut = AddRobotVisualizer(builder, robot, meshcat)
    assert dut.illustration.get_name() == "robot_visualizer"
    assert dut.collision.get_name() == "robot_collision_visualizer"
    diagram = builder.Build()
    context = diagram.CreateDefaultContext()
    robot.GetInputPort("q_commanded").FixValue(robot.GetMyMutableContextFromRoot(context),
                                                np.zeros(robot.num_joints))
    diagram.ForcedPublish(context)
    assert meshcat.HasPath("robot/air_bearing_arm/link3")
    assert meshcat.HasPath("collision/air_bearing_arm/link3")

    builder = DiagramBuilder()
    robot = builder.AddNamedSystem("robot", FlexibleJointArm(FlexibleArmConfig()))
    assert AddRobotVisualizer(builder, robot, meshcat, collision_layer=False).collision is None
    with pytest.raises(ValueError, match="publish_period_s"):
        AddRobotVisualizer(builder, robot, meshcat, publish_period_s=0.0)


@needs_dot
def test_diagram_svg_shows_the_stages_as_boxes(tmp_path):
    from telesmooth.scripts.render_diagram import main

    out = tmp_path / "diagram.svg"
    assert main(["--out", str(out)]) == 0
    svg = out.read_text(encoding="utf-8")
    assert "<svg" in svg
    for stage in STAGES:
        assert f"name={stage}" in svg
    # max_depth = 1: the robot's inside (interpolator, plant, tracker) is not drawn.
    assert "command_interpolator" not in svg and "laser_tracker" not in svg

    deeper = diagram_svg(MakeTeleoperationDiagram(LoadScenario()).diagram, max_depth=2)
    assert "<svg" in deeper and "name=command_interpolator" in deeper


def test_diagram_svg_without_dot_says_install_graphviz(monkeypatch):
    diagram = MakeTeleoperationDiagram(LoadScenario()).diagram
    monkeypatch.setattr(visualization.shutil, "which", lambda name: None)
    with pytest.raises(RuntimeError, match="install Graphviz"):
        diagram_svg(diagram)


def test_committed_diagram_svg_shows_the_stages():
    svg = (REPO / "docs" / "teleoperation_diagram.svg").read_text(encoding="utf-8")
    assert "<svg" in svg
    for stage in STAGES:
        assert f"name={stage}" in svg
