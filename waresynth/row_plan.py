"""A planned rack row: what `waresynth.scene_builder` builds a row's racks, boards and boxes from.

The random sampler draws a `RowPlan` for each sequence; `waresynth.building.plan` plans one per rack face, so every
pass along a face builds the same racks and boxes. Row frame: X along the row, Y down, the front at Z = 0.
Beside the plan, the geometry of its levels: clear heights, the boards' usable span, which levels a camera sees.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from layouts.camera import Intrinsics
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
    """One rack of a row as planned: its id, X range and the stacks of each board (lowest first).

    ``shared``: its (lower X, higher X) ends whose upright frame it shares with the neighbour there (bays of a
    continuous run): that frame stands centred on the end, one for both bays. An end not shared has the rack's
    own upright inside its span, flush with the end (a free-standing rack, or a shelving unit bolted to the
    next one: two uprights back to back at the joint)."""

    id: str
    x_min: float
    x_max: float
    stacks: list[list[StackPlan]]
    shared: tuple[bool, bool] = (False, False)

    def upright_centres(self, upright_width: float) -> tuple[float, float]:
        """Row-frame X of its two upright frames' centre lines (`upright_centres`)."""
        return upright_centres(self.x_min, self.x_max, upright_width, self.shared)

    def board_span(self, upright_width: float) -> tuple[float, float]:
        """The X range of its boards that boxes may stand on (`board_span`)."""
        return board_span(self.x_min, self.x_max, upright_width, self.shared)


@dataclass
class RowPlan:
    """A rack row as planned (row frame: X along it, front at Z = 0): shared shelf heights, depth and
    uprights, the box-density preset, the materials of racks and boards, and the racks in X order. The
    random sampler (`build_scene`) draws one per sequence; `waresynth.building.plan` plans one per rack face, so
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


def level_visible(intr: Intrinsics, cam_height: float, distance: float, level: float, clear: float) -> bool:
    """Generator rule: the board edge (h = 0) and half the clear height project inside the image rows."""
    for h in (0.0, clear / 2):
        v = intr.cy + intr.fy * (cam_height - level - h) / distance
        if not 0.0 <= v < intr.height:
            return False
    return True


#: how far past the canonical view's edge (a fraction of its half height) a board still counts as a slot:
#: the default camera at its farthest (60 degrees, 2.9 m) sees 11.5 % past it, and a row head trained on
#: it finds a board there at the view's edge
SLOT_MARGIN = 0.12


def slot_half_height(intr: Intrinsics, x_extent: float) -> float:
    """Half the height (metres, on the rack front plane) of the window whose boards are shelf slots: the
    canonical view of ``intr``'s images (``x_extent`` wide and ``x_extent * H / W`` tall about the optical
    axis, the network's window) and `SLOT_MARGIN` past its edges."""
    return x_extent * intr.height / intr.width / 2 * (1 + SLOT_MARGIN)


def level_in_window(cam_height: float, level: float, clear: float, half: float) -> bool:
    """Whether the two points of the visibility rule (the board edge and half the clear height above it) lie
    within ``half`` metres of the level camera's height: on the canonical view's rows (`layouts.canonical`)."""
    return all(-half <= cam_height - level - h < half for h in (0.0, clear / 2))


def clear_heights(levels: list[float], thickness: float, top: float) -> list[float]:
    out = []
    for k, lv in enumerate(levels):
        nxt = levels[k + 1] - thickness if k + 1 < len(levels) else top
        out.append(nxt - lv)
    return out


def upright_centres(x_min: float, x_max: float, upright_width: float,
                    shared: tuple[bool, bool] = (False, False)) -> tuple[float, float]:  # fmt: skip
    """The centre lines of a rack's two upright frames: on a shared end (`RackPlan.shared`) the end itself,
    else half an upright inside it."""
    half = upright_width / 2
    return (x_min if shared[0] else x_min + half), (x_max if shared[1] else x_max - half)


def board_span(x_min: float, x_max: float, upright_width: float,
               shared: tuple[bool, bool] = (False, False)) -> tuple[float, float]:  # fmt: skip
    """The X range of a rack's boards that boxes may stand on (between the uprights' inner faces, 3 cm clear);
    a shared end's upright stands half inside the rack (`upright_centres`)."""
    lo = x_min + upright_width / 2 + 0.03 if shared[0] else x_min + upright_width + 0.03
    hi = x_max - upright_width / 2 - 0.03 if shared[1] else x_max - upright_width - 0.03
    return lo, hi


def visible_levels(intr: Intrinsics, cam_height: float, distance: float, levels: list[float], thickness: float,
                   top: float) -> list[int]:  # fmt: skip
    """The levels a camera at this height and distance sees (`level_visible`), lowest first."""
    clears = clear_heights(levels, thickness, top)
    return [k for k in range(len(levels)) if level_visible(intr, cam_height, distance, levels[k], clears[k])]
