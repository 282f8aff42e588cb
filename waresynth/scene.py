"""Scene model: a rack row with shelves and boxes, background, lighting and a camera path.

World frame (docs/conventions.md): X along the row, Y down (floor at Y = 0), Z into the racks; the
row's front plane is ``Z = 0``. Every renderable thing is a cuboid `Part` (12 triangles); the
racks/shelves/boxes hierarchy is kept beside the parts for ground truth and ``scene.json``.
`waresynth.scene_builder.build_scene` samples a `Scene` from a seed and the config.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from layouts.camera import Intrinsics
from layouts.canonical import camera_rotation

#: Renderer texture patterns by name.
PATTERNS: dict[str, int] = {
    "plain": 0,
    "noise": 1,
    "tape": 2,
    "label": 3,
    "perforated": 4,
    "tiles": 5,
    "bricks": 6,
    "panels": 7,
    "wood": 8,
    "wrap": 9,
    "printed": 10,
    "stained": 11,
    "lines": 12,
}

Z_FRONT = 0.0


@dataclass
class Material:
    colour: tuple[float, float, float]  #: linear-ish RGB in [0, 1]
    pattern: int
    reflectance: float = 0.05
    scale: float = 1.0  #: pattern scale in metres (tile size, brick length ...)


@dataclass
class Part:
    """One rendered cuboid: centre, size (width along its own axis, height, depth) and yaw about Y."""

    center: tuple[float, float, float]
    size: tuple[float, float, float]
    yaw: float
    semantic: int
    instance: int
    material: int


@dataclass
class Box:
    id: str
    center: tuple[float, float, float]
    size: tuple[float, float, float]
    yaw: float
    stack_id: str
    stack_level: int
    instance_id: int

    def to_dict(self) -> dict[str, Any]:
        return {
            "id": self.id,
            "center": [float(v) for v in self.center],
            "size": [float(v) for v in self.size],
            "yaw": float(self.yaw),
            "stack_id": self.stack_id,
            "stack_level": self.stack_level,
            "instance_id": self.instance_id,
        }


@dataclass
class Shelf:
    id: str
    level: int
    board_top_y: float
    thickness: float
    clear_height: float
    instance_id: int
    boxes: list[Box] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        return {
            "id": self.id,
            "level": self.level,
            "board_top_y": float(self.board_top_y),
            "thickness": float(self.thickness),
            "clear_height": float(self.clear_height),
            "instance_id": self.instance_id,
            "boxes": [b.to_dict() for b in self.boxes],
        }


@dataclass
class Rack:
    id: str
    x_min: float
    x_max: float
    z_front: float
    depth: float
    instance_id: int
    shelves: list[Shelf] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        return {
            "id": self.id,
            "x_min": float(self.x_min),
            "x_max": float(self.x_max),
            "z_front": float(self.z_front),
            "depth": float(self.depth),
            "instance_id": self.instance_id,
            "shelves": [s.to_dict() for s in self.shelves],
        }


@dataclass
class Camera:
    """A translation along X at fixed height and distance; positions are world (x, y, z).

    The camera keeps one rotation for the whole sequence: ``roll_deg`` about its optical axis,
    ``pitch_deg`` (optical axis up > 0) and ``yaw_deg`` (turned right > 0), the convention of
    `layouts.canonical.camera_rotation`; all 0 (the default) faces the racks square (+Z).
    """

    intrinsics: Intrinsics
    height: float
    distance: float
    step: float
    positions: np.ndarray  #: (N, 3) float64
    roll_deg: float = 0.0
    pitch_deg: float = 0.0
    yaw_deg: float = 0.0

    @property
    def angles(self) -> tuple[float, float, float]:
        """(roll, pitch, yaw) in degrees."""
        return (self.roll_deg, self.pitch_deg, self.yaw_deg)

    @property
    def rotation(self) -> np.ndarray:
        """3x3: the camera's frame in the world's (a camera ray ``d`` is the world ray ``R d``)."""
        return camera_rotation(*self.angles)


@dataclass
class Scene:
    row: dict[str, Any]
    racks: list[Rack]
    camera: Camera
    visible_levels: list[int]
    light: dict[str, float]
    sensor: dict[str, float]
    background: str
    density: str
    parts: list[Part] = field(default_factory=list)
    materials: list[Material] = field(default_factory=list)
    clutter: list[dict[str, Any]] = field(default_factory=list)
    walls: list[dict[str, Any]] = field(default_factory=list)
    instances: list[dict[str, Any]] = field(default_factory=list)
    #: what the sequence's look changes from the neutral one (`waresynth.look.draw_look`; {}: none)
    look: dict[str, Any] = field(default_factory=dict)

    @property
    def rack_mid_z(self) -> float:
        return self.row["z_front"] + self.row["depth"] / 2

    def to_dict(self) -> dict[str, Any]:
        """The ``scene.json`` content (world frame, Y down, floor Y = 0)."""
        return {
            "row": self.row,
            "racks": [r.to_dict() for r in self.racks],
            "clutter": self.clutter,
            "walls": self.walls,
            "instances": self.instances,
            "light": self.light,
            "background": self.background,
            "density": self.density,
            **({"look": self.look} if self.look else {}),
        }
