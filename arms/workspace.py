"""Workspace obstacles as scenario data: boxes and a bounding box, and their SDFormat.

A :class:`Workspace` is plain data (it can live in a scenario file): a tuple of box obstacles
and an optional axis-aligned bounding box that the arm must stay inside. The bounding box is
modelled as six walls (or four, when ``bounds_z`` is None, for the planar air-bearing table)
of thickness ``wall_thickness_m`` placed just outside the bounds, so "the arm touches the
bounding box" is an ordinary collision between an arm link and a wall.

:func:`workspace_sdf` writes the static SDFormat model the collision checker (the
pre-simulator) loads next to the rigid arm. All coordinates are in the arm's base (world)
frame, metres. The default workspaces are OUR scenarios, not the paper's.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence

__all__ = [
    "AIR_BEARING_WORKSPACE",
    "BoxObstacle",
    "SPACE_ARM_WORKSPACE",
    "Workspace",
    "workspace_sdf",
]


def _vector3(field: str, value: Sequence[float], *, positive: bool = False) -> tuple:
    try:
        vector = tuple(float(v) for v in value)
    except (TypeError, ValueError):
        raise ValueError(f"{field} = {value!r} must be three numbers (x, y, z) in m") from None
    if len(vector) != 3:
        raise ValueError(f"{field} = {value!r} must be three numbers (x, y, z) in m")
    for axis, v in zip("xyz", vector):
        if not math.isfinite(v) or (positive and v <= 0.0):
            kind = "positive and finite" if positive else "finite"
            raise ValueError(f"{field}.{axis} = {v!r} must be {kind}")
    return vector


@dataclasses.dataclass(frozen=True)
class BoxObstacle:
    """An axis-aligned box.

    Attributes:
        name: Unique name (used in the SDFormat model and in reports).
        center_m: Centre, m; (x, y, z).
        size_m: Edge lengths, m; (x, y, z), each positive.
    """

    name: str
    center_m: tuple[float, float, float]
    size_m: tuple[float, float, float]

    def __post_init__(self) -> None:
        if not self.name or not str(self.name).replace("_", "").isalnum():
            raise ValueError(f"BoxObstacle.name = {self.name!r} must be a non-empty identifier")
        object.__setattr__(self, "center_m", _vector3(f"{self.name}.center_m", self.center_m))
        object.__setattr__(
            self, "size_m", _vector3(f"{self.name}.size_m", self.size_m, positive=True)
        )


@dataclasses.dataclass(frozen=True)
class Workspace:
    """Obstacles and a bounding box around the arm.

    Attributes:
        obstacles: Box obstacles.
        bounds_lower_m: Lower corner of the bounding box, m (x, y, z), or None for no box.
        bounds_upper_m: Upper corner, m; each coordinate above the lower one.
        planar: If True (air-bearing table) only the four side walls are built; their height
            spans ``bounds_lower_m[2]`` to ``bounds_upper_m[2]``.
        wall_thickness_m: Thickness of each wall, m.
    """

    obstacles: tuple[BoxObstacle, ...] = ()
    bounds_lower_m: tuple[float, float, float] | None = None
    bounds_upper_m: tuple[float, float, float] | None = None
    planar: bool = False
    wall_thickness_m: float = 0.05

    def __post_init__(self) -> None:
        object.__setattr__(self, "obstacles", tuple(self.obstacles))
        names = [o.name for o in self.obstacles]
        if len(set(names)) != len(names):
            raise ValueError(f"Workspace.obstacles names {names!r} must be unique")
        if (self.bounds_lower_m is None) != (self.bounds_upper_m is None):
            raise ValueError(
                "Workspace.bounds_lower_m and bounds_upper_m must be given together; got "
                f"{self.bounds_lower_m!r} and {self.bounds_upper_m!r}"
            )
        if self.bounds_lower_m is not None:
            lower = _vector3("Workspace.bounds_lower_m", self.bounds_lower_m)
            upper = _vector3("Workspace.bounds_upper_m", self.bounds_upper_m)
            for axis, lo, hi in zip("xyz", lower, upper):
                if not lo < hi:
                    raise ValueError(
                        f"Workspace.bounds_lower_m.{axis} = {lo!r} must be below "
                        f"bounds_upper_m.{axis} = {hi!r}"
                    )
            object.__setattr__(self, "bounds_lower_m", lower)
            object.__setattr__(self, "bounds_upper_m", upper)
        if not (math.isfinite(self.wall_thickness_m) and self.wall_thickness_m > 0.0):
            raise ValueError(
                f"Workspace.wall_thickness_m = {self.wall_thickness_m!r} must be positive"
            )

    def walls(self) -> tuple[BoxObstacle, ...]:
        """The bounding box as wall boxes just outside the bounds (empty without bounds)."""
        if self.bounds_lower_m is None:
            return ()
        lower, upper, t = self.bounds_lower_m, self.bounds_upper_m, self.wall_thickness_m
        center = [0.5 * (lo + hi) for lo, hi in zip(lower, upper)]
        span = [hi - lo + 2.0 * t for lo, hi in zip(lower, upper)]
        walls = []
        axes = (0, 1) if self.planar else (0, 1, 2)
        for axis in axes:
            for side, name in ((-1, "lower"), (1, "upper")):
                c = list(center)
                c[axis] = (lower[axis] - 0.5 * t) if side < 0 else (upper[axis] + 0.5 * t)
                size = list(span)
                size[axis] = t
                if self.planar:
                    size[2] = upper[2] - lower[2]
                walls.append(BoxObstacle(f"wall_{'xyz'[axis]}_{name}", tuple(c), tuple(size)))
        return tuple(walls)

    def boxes(self) -> tuple[BoxObstacle, ...]:
        """Obstacles followed by the walls."""
        return self.obstacles + self.walls()


def workspace_sdf(workspace: Workspace, *, model_name: str = "workspace") -> str:
    """Static SDFormat model with one collision/visual box per obstacle and wall."""
    text = (
        '<?xml version="1.0"?>\n<sdf version="1.9">\n'
        f'  <model name="{model_name}">\n    <static>true</static>\n'
    )
    for box in workspace.boxes():
        center = " ".join(f"{v:.12g}" for v in box.center_m)
        size = " ".join(f"{v:.12g}" for v in box.size_m)
        alpha = 0.15 if box.name.startswith("wall_") else 0.6
        text += (
            f'    <link name="{box.name}">\n      <pose>{center} 0 0 0</pose>\n'
            f'      <collision name="{box.name}_collision"><geometry><box><size>{size}</size>'
            "</box></geometry></collision>\n"
            f'      <visual name="{box.name}_visual"><geometry><box><size>{size}</size>'
            f"</box></geometry><material><diffuse>0.8 0.2 0.2 {alpha}</diffuse></material>"
            "</visual>\n    </link>\n"
        )
    return text + "  </model>\n</sdf>\n"


SPACE_ARM_WORKSPACE = Workspace(
    obstacles=(BoxObstacle("payload", (0.6, 0.55, 0.35), (0.3, 0.3, 0.7)),),
    bounds_lower_m=(-1.25, -1.25, -0.05),
    bounds_upper_m=(1.25, 1.25, 1.5),
)
"""Our 6-DOF scenario: a payload box beside the arm inside a 2.5 x 2.5 x 1.55 m bay."""

AIR_BEARING_WORKSPACE = Workspace(
    obstacles=(BoxObstacle("fixture", (0.75, 0.55, 0.0), (0.3, 0.1, 0.2)),),
    bounds_lower_m=(-0.4, -0.8, -0.1),
    bounds_upper_m=(1.2, 0.8, 0.1),
    planar=True,
)
"""Our air-bearing table: 1.6 x 1.6 m walls and a fixture beyond the LASA drawing area."""
