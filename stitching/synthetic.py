"""Small synthetic rack rows and their ground-truth layouts, for tests, demos and benchmarks.

This is a light stand-in for the WareSynth generator that needs no rendering: random racks and
box stacks in the generator's ``scene.json`` format (world frame, Y down, floor Y = 0), a camera
translating along the row, and per-frame top/front layouts rasterised with
`layouts.raster.fill_rect` following docs/conventions.md. The per-frame records mimic
``meta.json["frames"]`` so the same evaluation code runs on both.
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Iterable, Iterator
from dataclasses import dataclass

import numpy as np

from layouts.camera import Intrinsics
from layouts.classes import BOX, SHELF
from layouts.codecs import FrameLayouts
from layouts.raster import fill_rect
from layouts.spec import LayoutSpec
from stitching.geometry import stacks_of


@dataclass
class SyntheticSequence:
    spec: LayoutSpec
    scene: dict
    frames: list[dict]  #: per-frame records like meta.json["frames"]
    layouts: list[FrameLayouts]


def random_scene(rng: np.random.Generator, length: float = 12.0, levels: int = 3, density: str | None = None) -> dict:
    """A row of racks filling ``length`` metres of X starting at X = 0 (scene.json layout)."""
    first, spacing, thick = rng.uniform(0.1, 0.4), rng.uniform(0.8, 1.2), rng.uniform(0.04, 0.08)
    depth, z_front = rng.uniform(0.8, 1.2), 0.0
    board_tops = [first + k * spacing for k in range(levels)]  # heights of board tops above the floor
    top_height = board_tops[-1] + rng.uniform(0.7, 1.0)
    density = density or str(rng.choice(["dense", "moderate", "sparse"]))
    gap_rng = {"dense": (0.03, 0.1), "moderate": (0.08, 0.35), "sparse": (0.25, 0.9)}[density]
    racks, x = [], 0.0
    while x < length:
        width = rng.uniform(1.6, 3.0)
        rid = f"rack_{len(racks):02d}"
        shelves = []
        for lv, bt in enumerate(board_tops):
            clear = (board_tops[lv + 1] - thick if lv + 1 < levels else top_height) - bt
            sid = f"{rid}/shelf_{lv:02d}"
            boxes, bx = [], x + rng.uniform(0.03, 0.15)
            while True:
                w, d = rng.uniform(0.25, 0.7), rng.uniform(0.25, min(0.7, depth))
                yaw = math.radians(rng.uniform(-12, 12)) if rng.random() < 0.4 else 0.0
                ext = abs(math.cos(yaw)) * w + abs(math.sin(yaw)) * d
                if bx + ext > x + width - 0.03:
                    break
                n_stack = 1 + int(rng.random() < 0.4) + int(rng.random() < 0.2)
                hmax = clear - 0.08
                hs = [rng.uniform(0.15, 0.5) for _ in range(n_stack)]
                while sum(hs) > hmax and hs:
                    hs.pop()
                ez = abs(math.sin(yaw)) * w + abs(math.cos(yaw)) * d
                cz = z_front + rng.uniform(0.0, 0.08) + ez / 2
                stack_id = f"{sid}/stack_{len({b['stack_id'] for b in boxes}):03d}"
                y = -bt
                for k, h in enumerate(hs):
                    boxes.append(
                        {
                            "id": f"{sid}/box_{len(boxes):03d}",
                            "center": [bx + ext / 2, y - h / 2, cz],
                            "size": [w, h, d],
                            "yaw": yaw,
                            "stack_id": stack_id,
                            "stack_level": k,
                        }
                    )
                    y -= h
                bx += ext + rng.uniform(*gap_rng)
            shelves.append(
                {"id": sid, "level": lv, "board_top_y": -bt, "thickness": thick, "clear_height": clear, "boxes": boxes}
            )
        racks.append(
            {"id": rid, "x_min": x, "x_max": x + width, "z_front": z_front, "depth": depth, "shelves": shelves}
        )
        x += width + rng.uniform(0.2, 0.5)
    return {
        "row": {"z_front": z_front, "depth": depth, "levels": board_tops, "top_height": top_height},
        "racks": racks,
    }


def render_frame(scene: dict, spec: LayoutSpec, cam_x: float, levels: list[int]) -> FrameLayouts:
    """Ground-truth layouts of one frame for the given shelf levels (slot r = levels[r])."""
    top = np.zeros(spec.shape, np.uint8)
    front = np.zeros(spec.shape, np.uint8)
    mid_z = scene["row"]["z_front"] + scene["row"]["depth"] / 2
    half = spec.x_extent / 2 + 1.0
    for rack in scene["racks"]:
        if rack["x_max"] < cam_x - half or rack["x_min"] > cam_x + half:
            continue
        cx, w = (rack["x_min"] + rack["x_max"]) / 2 - cam_x, rack["x_max"] - rack["x_min"]
        for r, lv in enumerate(levels):
            shelf = rack["shelves"][lv]
            clear = min(shelf["clear_height"], spec.h_extent)
            fill_rect(top[r], spec, "top", (cx, rack["z_front"] + rack["depth"] / 2 - mid_z), (w, rack["depth"]), SHELF)
            fill_rect(front[r], spec, "front", (cx, clear / 2), (w, clear), SHELF)
            for st in stacks_of(shelf):
                c, s = math.cos(st.yaw), math.sin(st.yaw)
                bw, bh, bd = st.size
                fill_rect(top[r], spec, "top", (st.center[0] - cam_x, st.center[2] - mid_z), (bw, bd), BOX, st.yaw)
                ext = abs(c) * bw + abs(s) * bd
                hh = min(bh, clear)
                fill_rect(front[r], spec, "front", (st.center[0] - cam_x, hh / 2), (ext, hh), BOX)
    return FrameLayouts(top, front)


def make_sequence(
    seed: int = 0,
    frames: int = 50,
    spec: LayoutSpec | None = None,
    step: float = 0.1,
    reverse_at: int | None = None,
    distance: float = 2.6,
    levels: int = 3,
    density: str | None = None,
) -> SyntheticSequence:
    """A camera sweeping a random row by ``step`` metres per frame (turning back at ``reverse_at``)."""
    spec = spec or LayoutSpec()
    rng = np.random.default_rng(seed)
    length = abs(step) * frames + spec.x_extent + 4.0
    scene = random_scene(rng, length=length, levels=levels, density=density)
    intr = Intrinsics.from_fov(256, 256, 60.0)
    visible = intr.visible_columns(spec, distance)
    slot_levels = list(range(min(levels, spec.num_slots)))
    x = spec.x_extent / 2 + 1.0 if step >= 0 else length - spec.x_extent / 2 - 1.0
    mid_z = scene["row"]["z_front"] + scene["row"]["depth"] / 2
    recs, lays = [], []
    for i in range(frames):
        if i and reverse_at is not None and i == reverse_at:
            step = -step
        if i:
            x += step
        fl = render_frame(scene, spec, x, slot_levels)
        fl.visible = visible.copy()
        lays.append(fl)
        slots = [
            {
                "level": lv,
                "board_top_y": scene["racks"][0]["shelves"][lv]["board_top_y"],
                "clear_height": scene["racks"][0]["shelves"][lv]["clear_height"],
            }
            for lv in slot_levels
        ]
        recs.append(
            {
                "index": i,
                "camera_position": [x, -1.2, scene["row"]["z_front"] - distance],
                "distance": distance,
                "rack_mid_z": mid_z,
                "slots": slots,
                "visible_fraction": float(visible.mean()),
            }
        )
    return SyntheticSequence(spec, scene, recs, lays)


def stream_frames(
    scene: dict, spec: LayoutSpec, xs: Iterable[float], distance: float = 2.6, levels: int | None = None
) -> Iterator[FrameLayouts]:
    """Ground-truth layouts for camera X positions ``xs``, one frame at a time (nothing is kept).

    For long aisles: each frame rasterises only the racks near the camera (racks are looked up by
    X), so the cost per frame does not grow with the row length, and memory holds one frame.
    """
    racks = sorted(scene["racks"], key=lambda r: r["x_min"])
    starts = [r["x_min"] for r in racks]
    widest = max((r["x_max"] - r["x_min"] for r in racks), default=0.0)
    n_levels = len(scene["row"]["levels"]) if levels is None else levels
    slot_levels = list(range(min(n_levels, spec.num_slots)))
    visible = Intrinsics.from_fov(256, 256, 60.0).visible_columns(spec, distance)
    half = spec.x_extent / 2 + 1.0
    for x in xs:
        x = float(x)
        a = bisect.bisect_left(starts, x - half - widest)
        b = bisect.bisect_right(starts, x + half)
        fl = render_frame({"row": scene["row"], "racks": racks[a:b]}, spec, x, slot_levels)
        fl.visible = visible.copy()
        yield fl


def long_aisle(
    seed: int, frames: int, spec: LayoutSpec | None = None, step: float = 0.1, levels: int = 3
) -> tuple[dict, np.ndarray]:
    """A row long enough for ``frames`` camera steps of ``step`` metres, and the camera X per frame."""
    spec = spec or LayoutSpec()
    rng = np.random.default_rng(seed)
    length = abs(step) * frames + spec.x_extent + 4.0
    scene = random_scene(rng, length=length, levels=levels)
    xs = spec.x_extent / 2 + 1.0 + step * np.arange(frames)
    return scene, xs


def degrade(fl: FrameLayouts, rng: np.random.Generator, morph_px: int = 1, flip_fraction: float = 0.03) -> FrameLayouts:
    """Degrade layouts the way a network does: grow (``morph_px`` > 0) or shrink (< 0) the box
    regions by ``|morph_px|`` pixels, then flip ``flip_fraction`` of all pixels to a random class."""
    from scipy import ndimage

    out = []
    for arr in (fl.top, fl.front):
        a = arr.copy()
        if morph_px:
            st = np.zeros((3, 3, 3), bool)
            st[1] = ndimage.generate_binary_structure(2, 1)
            box = a == BOX
            if morph_px > 0:
                grown = ndimage.binary_dilation(box, st, iterations=morph_px)
                a[grown & (a != 0)] = BOX
            else:
                shrunk = ndimage.binary_erosion(box, st, iterations=-morph_px)
                a[box & ~shrunk] = SHELF
        flip = rng.random(a.shape) < flip_fraction
        a[flip] = rng.integers(0, 3, int(flip.sum()), dtype=np.uint8)
        out.append(a)
    return FrameLayouts(out[0], out[1], fl.visible)
