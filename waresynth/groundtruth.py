"""Ground-truth layouts per frame, rasterised from the scene model with `layouts.raster.fill_rect`.

Slot r is the r-th visible shelf level counted from the lowest (visibility rule in
docs/conventions.md, see `waresynth.scene_builder.level_visible`). Top view: each rack's board footprint
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


def frame_slots(scene: Scene, spec: LayoutSpec) -> list[dict[str, Any]]:
    """Per-slot records (lowest visible level first, at most R): level, board top Y, clear height."""
    shelves = scene.racks[0].shelves
    return [
        {"level": k, "board_top_y": float(shelves[k].board_top_y), "clear_height": float(shelves[k].clear_height)}
        for k in scene.visible_levels[: spec.num_slots]
    ]


def frame_layouts(scene: Scene, spec: LayoutSpec, cam_x: float) -> FrameLayouts:
    """Top and front layouts ``(R, D, D)`` and visible columns for a camera at X = ``cam_x``."""
    top = np.zeros(spec.shape, np.uint8)
    front = np.zeros(spec.shape, np.uint8)
    mid_z = scene.rack_mid_z
    half = spec.x_extent / 2 + 0.5
    levels = scene.visible_levels[: spec.num_slots]
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
