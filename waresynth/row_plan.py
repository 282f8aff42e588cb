"""A planned rack row: what `waresynth.scene_builder` builds a row's racks, boards and boxes from.

The random sampler draws a `RowPlan` for each sequence; `waresynth.building` plans one per rack face, so every
pass along a face builds the same racks and boxes. Row frame: X along the row, Y down, the front at Z = 0.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from waresynth.scene import Material


@dataclass
class StackPlan:
    """One stack on a board as planned: its footprint's centre (x, z), one box's size (width, height,
    depth), yaw, how many boxes high and the stack's material."""

    x: float
    z: float
    size: tuple[float, float, float]
    yaw: float
    count: int
    material: Material


@dataclass
class RackPlan:
    """One rack of a row as planned: its id, X range and the stacks of each board (lowest first)."""

    id: str
    x_min: float
    x_max: float
    stacks: list[list[StackPlan]]


@dataclass
class RowPlan:
    """A rack row as planned (row frame: X along it, front at Z = 0): shared shelf heights, depth and
    uprights, the box-density preset, the materials of racks and boards, and the racks in X order. The
    random sampler (`build_scene`) draws one per sequence; `waresynth.building` plans one per rack face, so
    every pass along a face builds the same racks and boxes from it."""

    levels: list[float]
    thickness: float
    top: float
    depth: float
    upright_width: float
    density: str
    preset: dict[str, Any]
    rack_material: Material
    board_material: Material
    racks: list[RackPlan] = field(default_factory=list)
    gaps: list[tuple[float, float]] = field(default_factory=list)  #: X ranges between neighbouring racks


@dataclass
class CameraPlan:
    """A pass's camera as planned: distance to the rack front, height, signed step and the first frame's X."""

    distance: float
    height: float
    step: float
    x0: float
