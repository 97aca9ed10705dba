"""Looking at a run: the robot in Meshcat (live or as one offline HTML file) and the diagram.

* :func:`AddRobotVisualizer` connects Meshcat visualizers to the onboard robot's SceneGraph
  (:class:`~telesmooth.systems.flexible_arm.FlexibleJointArm`'s ``query_object`` port).
* :func:`draw_workspace` and :func:`draw_tool_path` draw what is *not* in that SceneGraph: the
  scenario's obstacles and bounding walls (they live only in the collision checker's rigid
  model) and the operator's commanded tool path. They are static Meshcat objects.
* :func:`start_meshcat_recording` and :func:`save_meshcat_recording` record a run and write
  Meshcat's self-contained ``StaticHtml()``: three.js, the scene and the animation are inline,
  so the file opens offline from ``file://``
  (:func:`~telesmooth.diagrams.simulation.record_meshcat_html` runs the whole chain so).
* :func:`diagram_svg` renders a built diagram with Graphviz (the ``dot`` program).

Meshcat here always binds ``localhost`` (``MeshcatParams().host`` defaults to ``"*"``, all
interfaces): see :func:`local_meshcat`.
"""

from __future__ import annotations

import dataclasses
import shutil
import warnings
from pathlib import Path

import numpy as np
from pydrake.geometry import (
    Box,
    Meshcat,
    MeshcatParams,
    MeshcatVisualizer,
    MeshcatVisualizerParams,
    Rgba,
    Role,
)
from pydrake.math import RigidTransform

from telesmooth.arms.workspace import Workspace

__all__ = [
    "AddRobotVisualizer",
    "COLLISION_PREFIX",
    "FRAMES_PER_SECOND",
    "ILLUSTRATION_PREFIX",
    "OBSTACLE_RGBA",
    "RobotVisualizers",
    "TOOL_PATH_PATH",
    "TOOL_PATH_RGBA",
    "WALL_RGBA",
    "WORKSPACE_PATH",
    "commanded_tool_points",
    "diagram_svg",
    "draw_tool_path",
    "draw_workspace",
    "local_meshcat",
]

ILLUSTRATION_PREFIX = "robot"
"""Meshcat path (under ``/drake``) of the robot's illustration geometry."""
COLLISION_PREFIX = "collision"
"""Meshcat path of the robot's proximity (collision) geometry, hidden by default."""
WORKSPACE_PATH = "workspace"
"""Meshcat path of the workspace boxes; one child per :class:`BoxObstacle` name."""
TOOL_PATH_PATH = "commanded_tool_path"
"""Meshcat path of the operator's commanded tool path drawn by :func:`start_meshcat_recording`."""

# The collision checker's SDF uses the same red (alpha 0.6 obstacles, 0.15 walls).
OBSTACLE_RGBA = Rgba(0.8, 0.2, 0.2, 0.6)
WALL_RGBA = Rgba(0.8, 0.2, 0.2, 0.15)
TOOL_PATH_RGBA = Rgba(0.1, 0.4, 0.9, 1.0)

FRAMES_PER_SECOND = 30.0
"""Recording rate of :func:`start_meshcat_recording`, frames per simulated second."""


@dataclasses.dataclass(frozen=True)
class RobotVisualizers:
    """The visualizers added by :func:`AddRobotVisualizer`.

    Attributes:
        illustration: Draws the illustration geometry under ``/drake/robot``.
        collision: Draws the proximity geometry under ``/drake/collision`` (hidden by
            default; toggle it in the Meshcat controls), or None.
    """

    illustration: MeshcatVisualizer
    collision: MeshcatVisualizer | None


def local_meshcat(port: int | None = None) -> Meshcat:
    """A Meshcat server listening on localhost only (``port`` None = the first free 7000+)."""
    return Meshcat(MeshcatParams(host="localhost", port=port))


def AddRobotVisualizer(builder, robot, meshcat: Meshcat, *, publish_period_s: float = 1 / 30,
                       collision_layer: bool = True) -> RobotVisualizers:
    """Adds Meshcat visualizers for the geometry of ``robot`` to ``builder``.

    Args:
        builder: The DiagramBuilder that already holds ``robot``.
        robot: A system in ``builder`` with a ``query_object`` output port (SceneGraph's
            QueryObject), e.g. :class:`~telesmooth.systems.flexible_arm.FlexibleJointArm`.
        meshcat: The Meshcat instance to draw into.
        publish_period_s: Period of the visualizers' periodic publish, s (positive). Recorded
            frames are taken at the recording's own rate, not at this one.
        collision_layer: Also add a proximity-role layer under ``/drake/collision``, hidden
            by default.

    Returns:
        The added visualizers (named ``robot_visualizer`` and
        ``robot_collision_visualizer`` in the diagram).

    Raises:
        ValueError: if ``publish_period_s`` is not positive and finite.
    """
    if not (np.isfinite(publish_period_s) and publish_period_s > 0.0):
        raise ValueError(f"publish_period_s = {publish_period_s!r} must be positive and finite")
    query_object = robot.GetOutputPort("query_object")
    illustration = MeshcatVisualizer.AddToBuilder(
        builder, query_object, meshcat,
        MeshcatVisualizerParams(publish_period=publish_period_s, role=Role.kIllustration,
                                prefix=ILLUSTRATION_PREFIX))
    illustration.set_name("robot_visualizer")
    collision = None
    if collision_layer:
        collision = MeshcatVisualizer.AddToBuilder(
            builder, query_object, meshcat,
            MeshcatVisualizerParams(publish_period=publish_period_s, role=Role.kProximity,
                                    prefix=COLLISION_PREFIX, visible_by_default=False))
        collision.set_name("robot_collision_visualizer")
    return RobotVisualizers(illustration=illustration, collision=collision)


def draw_workspace(meshcat: Meshcat, workspace: Workspace, *,
                   path: str = WORKSPACE_PATH) -> list[str]:
    """Draws the workspace's obstacles and bounding walls as static boxes.

    They are not in the robot's SceneGraph (only the collision checker's rigid model has
    them), so they are drawn directly. Obstacles are drawn in :data:`OBSTACLE_RGBA`, walls
    (names ``wall_*``) in the fainter :data:`WALL_RGBA`, both in the world frame.

    Args:
        meshcat: The Meshcat instance.
        workspace: The scenario's workspace (``scenario.workspace_or_default``).
        path: Parent Meshcat path; each box is ``f"{path}/{box.name}"``.

    Returns:
        The Meshcat paths created, one per box, in ``workspace.boxes()`` order.
    """
    meshcat.Delete(path)
    paths = []
    for box in workspace.boxes():
        box_path = f"{path}/{box.name}"
        rgba = WALL_RGBA if box.name.startswith("wall_") else OBSTACLE_RGBA
        meshcat.SetObject(box_path, Box(*box.size_m), rgba)
        meshcat.SetTransform(box_path, RigidTransform(np.array(box.center_m)))
        paths.append(box_path)
    return paths


def draw_tool_path(meshcat: Meshcat, path_name: str, points_3xN, rgba: Rgba = TOOL_PATH_RGBA,
                   *, line_width: float = 2.0) -> str:
    """Draws a polyline through ``points_3xN`` (world frame, m) at ``path_name``.

    Args:
        meshcat: The Meshcat instance.
        path_name: Meshcat path of the line.
        points_3xN: Vertices, m; shape (3, N) with N ≥ 2, finite.
        rgba: Line colour.
        line_width: Line width in pixels (browsers may draw 1 px regardless).

    Returns:
        ``path_name``.

    Raises:
        ValueError: if ``points_3xN`` is not a finite (3, N ≥ 2) array.
    """
    points = np.asarray(points_3xN, dtype=float)
    if points.ndim != 2 or points.shape[0] != 3 or points.shape[1] < 2:
        raise ValueError(f"points_3xN has shape {points.shape}; expected (3, N) with N >= 2")
    if not np.all(np.isfinite(points)):
        raise ValueError("points_3xN must be finite")
    meshcat.SetLine(path_name, points, line_width, rgba)
    return path_name


def commanded_tool_points(recording) -> np.ndarray | None:
    """The operator's commanded tool positions as a (3, K) world-frame array, or None.

    Planar recordings ``(x_m, y_m, phi_rad)`` lie in the air-bearing table's plane
    (world z = 0); 6-DOF recordings start with ``(x_m, y_m, z_m)``. Other layouts give None.
    """
    if recording is None:
        return None
    names = tuple(recording.pose_names)
    pose = np.asarray(recording.pose, dtype=float)
    if names[:3] == ("x_m", "y_m", "z_m"):
        return pose[:, :3].T.copy()
    if names[:2] == ("x_m", "y_m") and pose.shape[1] == 3:
        return np.vstack([pose[:, 0], pose[:, 1], np.zeros(pose.shape[0])])
    return None


def start_meshcat_recording(scenario, recording, *, port: int | None = None):
    """A localhost Meshcat with the workspace and the commanded tool path drawn, recording.

    Pass it to ``simulate(..., meshcat=...)`` (or ``MakeTeleoperationDiagram``), then save
    the replay with :func:`save_meshcat_recording`. Only the recording receives the
    visualizer's transforms (the live scene keeps the initial pose), which skips the large
    per-frame websocket traffic.
    """
    meshcat = local_meshcat(port)
    draw_workspace(meshcat, scenario.workspace_or_default)
    tool_points = commanded_tool_points(recording)
    if tool_points is not None:
        draw_tool_path(meshcat, TOOL_PATH_PATH, tool_points)
    meshcat.StartRecording(frames_per_second=FRAMES_PER_SECOND,
                           set_visualizations_while_recording=False)
    return meshcat


def save_meshcat_recording(meshcat, out_path, duration_s: float) -> dict:
    """Stops and publishes the recording; writes ``meshcat.StaticHtml()`` to ``out_path``.

    Returns ``html_path``, ``html_bytes`` and ``frames`` (animation frames over
    [0, duration_s]).
    """
    meshcat.StopRecording()
    meshcat.PublishRecording()
    animation = meshcat.get_mutable_recording()
    frames = animation.frame(duration_s) - animation.frame(0.0) + 1
    out = Path(out_path)
    out.parent.mkdir(parents=True, exist_ok=True)
    from telesmooth.atomic_files import write_text

    write_text(out, meshcat.StaticHtml())
    return {"html_path": str(out), "html_bytes": out.stat().st_size, "frames": int(frames)}


def diagram_svg(diagram, *, max_depth: int | None = 1) -> str:
    """The Graphviz SVG of a built ``diagram`` (subdiagrams below ``max_depth`` are boxes).

    Args:
        diagram: A built Diagram (or any System).
        max_depth: Depth of nested diagrams to expand; 1 shows the top level's systems as
            boxes; None expands everything.

    Returns:
        The SVG document as text.

    Raises:
        RuntimeError: if the Graphviz ``dot`` program is not on PATH.
    """
    if shutil.which("dot") is None:
        raise RuntimeError(
            "diagram_svg needs the Graphviz 'dot' program, which is not on PATH; install "
            "Graphviz (Debian/Ubuntu: apt-get install graphviz; macOS: brew install graphviz)")
    import pydot  # a drake dependency; imported here so the rest works without it

    dot_text = diagram.GetGraphvizString(max_depth=max_depth)
    with warnings.catch_warnings():
        # pydot 4's parser still calls pyparsing's camelCase names (deprecated in pyparsing
        # 3.3); the warnings are about pydot's code, not ours, and say nothing about the graph.
        warnings.simplefilter("ignore", DeprecationWarning)
        graphs = pydot.graph_from_dot_data(dot_text)
    if not graphs:
        raise RuntimeError("pydot could not parse the diagram's Graphviz text")
    svg = graphs[0].create_svg()
    return svg.decode("utf-8") if isinstance(svg, bytes) else str(svg)
