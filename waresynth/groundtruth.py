"""Ground-truth layouts per frame, rasterised from the scene model with `layouts.raster.fill_rect`.

Slot r is the r-th visible shelf level counted from the lowest (visibility rule in
docs/conventions.md, see `waresynth.scene_builder.level_visible`) that also lies inside the canonical
view (`slot_levels`): a board the camera sees but the network's canonical window does not hold is no slot,
so the slots the network counts from its row head are the ones the ground truth counts. Top view: each rack's board footprint
(x range x depth) is shelf, each stack's yawed footprint is box. Front view: board x range x
clear height (the window clips it at ``h_extent``) is shelf; each stack's x extent (of its yawed
footprint) x its stack height is box.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from layouts.classes import BOX, SHELF
from layouts.codecs import FrameLayouts
from layouts.raster import fill_rect
from layouts.spec import LayoutSpec
from waresynth.row_plan import level_in_window, slot_half_height
from waresynth.scene import Scene


def stacks(shelf) -> list[dict[str, Any]]:
    """Group a shelf's boxes into stacks: footprint (centre x/z, w, d, yaw) and total height."""
    out: dict[str, dict[str, Any]] = {}
    for b in shelf.boxes:
        s = out.setdefault(
            b.stack_id,
            {"x": b.center[0], "z": b.center[2], "w": b.size[0], "d": b.size[2], "yaw": b.yaw, "height": 0.0},
        )
        s["height"] += b.size[1]
    return list(out.values())


def in_canonical_view(scene: Scene, spec: LayoutSpec, level: int) -> bool:
    """Whether a level's board edge and the point at half its clear height (the two points of the visibility
    rule) lie within the canonical view of the scene's images (`layouts.canonical`: on the level camera's
    front plane, ``spec.x_extent`` wide and ``x_extent * H / W`` tall about the optical axis) or at most
    `waresynth.row_plan.SLOT_MARGIN` past its edges."""
    shelf = scene.racks[0].shelves[level]
    half = slot_half_height(scene.camera.intrinsics, spec.x_extent)
    return level_in_window(scene.camera.height, -float(shelf.board_top_y), float(shelf.clear_height), half)


def slot_levels(scene: Scene, spec: LayoutSpec, canonical: bool = True) -> list[int]:
    """The levels the shelf slots show, lowest first (at most R): the visible ones inside the canonical view
    (``canonical=False``: every visible one, the rule a building's planned passes keep with their routes).

    A wider lens or a camera further back than the default's (60 degrees, at most 2.9 m) sees boards above
    and below the rows the network reads; counted as slots, slot 0 would be a board its row head cannot find
    and every slot it finds would name the level below its own."""
    inside = [k for k in scene.visible_levels if not canonical or in_canonical_view(scene, spec, k)]
    return inside[: spec.num_slots]


def frame_slots(scene: Scene, spec: LayoutSpec, canonical: bool = True) -> list[dict[str, Any]]:
    """Per-slot records (lowest slot level first, at most R; `slot_levels`): level, board top Y, clear height."""
    shelves = scene.racks[0].shelves
    return [
        {"level": k, "board_top_y": float(shelves[k].board_top_y), "clear_height": float(shelves[k].clear_height)}
        for k in slot_levels(scene, spec, canonical)
    ]


def frame_layouts(scene: Scene, spec: LayoutSpec, cam_x: float, canonical: bool = True) -> FrameLayouts:
    """Top and front layouts ``(R, D, D)`` and visible columns for a camera at X = ``cam_x`` (slots: `slot_levels`)."""
    top = np.zeros(spec.shape, np.uint8)
    front = np.zeros(spec.shape, np.uint8)
    mid_z = scene.rack_mid_z
    half = spec.x_extent / 2 + 0.5
    levels = slot_levels(scene, spec, canonical)
    for rack in scene.racks:
        if rack.x_max < cam_x - half - 2.0 or rack.x_min > cam_x + half + 2.0:
            continue
        xc, width = (rack.x_min + rack.x_max) / 2 - cam_x, rack.x_max - rack.x_min
        for r, k in enumerate(levels):
            shelf = rack.shelves[k]
            fill_rect(top[r], spec, "top", (xc, rack.z_front + rack.depth / 2 - mid_z), (width, rack.depth), SHELF)
            fill_rect(front[r], spec, "front", (xc, shelf.clear_height / 2), (width, shelf.clear_height), SHELF)
            for st in stacks(shelf):
                bx = st["x"] - cam_x
                fill_rect(top[r], spec, "top", (bx, st["z"] - mid_z), (st["w"], st["d"]), BOX, yaw=st["yaw"])
                c, s = abs(math.cos(st["yaw"])), abs(math.sin(st["yaw"]))
                ext = c * st["w"] + s * st["d"]
                fill_rect(front[r], spec, "front", (bx, st["height"] / 2), (ext, st["height"]), BOX)
    visible = scene.camera.intrinsics.visible_columns(spec, scene.camera.distance)
    return FrameLayouts(top, front, visible)
