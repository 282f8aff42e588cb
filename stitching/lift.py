"""Lift: one frame's 2D detections -> 3D cuboids in that frame's shelf-centric coordinates.

Coordinates: X about the camera, Z about the rack mid-depth, Y down with ``Y = 0`` at the top of
slot 0's board. Slot ``r``'s board sits at height ``H_r`` above slot 0's:
``H_0 = 0`` and ``H_{r+1} = H_r + clear_height_r + board_thickness``, the clear heights coming from
the front views (``board_thickness`` is a parameter, default 0.06 m, the middle of the
generator's 0.04-0.08 m range).

Per slot, top-view boxes and front-view runs are matched one-to-one by the IoU of their X
extents (Hungarian assignment, ``scipy.optimize.linear_sum_assignment``). Rules:

=========================  ============================================================  ==========
detection                   missing extent                                                confidence
=========================  ============================================================  ==========
top + front matched         height = median front height over the shared columns          1.0
top, front columns below    height = median front height over its own box columns         0.8
top only                    height = median height of this slot's matched boxes, else     0.4
                            half the clear height
front only (not covered     Z = middle of the shelf depth, depth = median depth of this   0.3
by any top box)             slot's boxes, else half the shelf depth
=========================  ============================================================  ==========

A box cut by the visible range keeps its flags; its confidence is multiplied by 0.8.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment

from layouts.errors import LayoutError
from stitching.detect import FrameDetections
from stitching.geometry import Cuboid

CONF_MATCHED = 1.0
CONF_PROFILE = 0.8
CONF_TOP_ONLY = 0.4
CONF_FRONT_ONLY = 0.3
CUT_FACTOR = 0.8


@dataclass(frozen=True)
class LiftConfig:
    board_thickness: float = 0.06  #: metres between one slot's clear height and the next board top
    match_iou: float = 0.3  #: minimum X-extent IoU for a top/front match
    min_profile_fraction: float = 0.3  #: share of a top box's columns with front box pixels to use them

    def __post_init__(self) -> None:
        for name in ("board_thickness", "match_iou", "min_profile_fraction"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v):
                raise LayoutError(f"LiftConfig.{name} must be a finite number, got {v!r}")
        if self.board_thickness < 0:
            raise LayoutError(f"LiftConfig.board_thickness must be >= 0 metres, got {self.board_thickness!r}")
        if not 0 <= self.match_iou <= 1:
            raise LayoutError(f"LiftConfig.match_iou must be in [0, 1], got {self.match_iou!r}")
        if not 0 <= self.min_profile_fraction <= 1:
            raise LayoutError(f"LiftConfig.min_profile_fraction must be in [0, 1], got {self.min_profile_fraction!r}")


@dataclass
class FrameBox:
    """One lifted box of one frame (frame shelf-centric coordinates)."""

    slot: int
    cx: float
    cz: float
    w: float
    d: float
    yaw: float
    height: float  #: metres above its own board
    x0: float  #: axis-aligned X range of the footprint
    x1: float
    z0: float
    z1: float
    cut_left: bool
    cut_right: bool
    confidence: float
    source: str

    def cuboid(self, board_height: float) -> Cuboid:
        return Cuboid((self.cx, -(board_height + self.height / 2), self.cz), (self.w, self.height, self.d), self.yaw)


@dataclass
class FrameShelf:
    slot: int
    present: bool
    board_height: float  #: metres above slot 0's board
    clear_height: float
    z_range: tuple[float, float]
    segments: list[tuple[float, float, bool, bool]]
    shelf_cols: np.ndarray


@dataclass
class FrameReconstruction:
    """A frame's shelves and boxes in its own shelf-centric coordinates."""

    shelves: list[FrameShelf]
    boxes: list[FrameBox]
    vis_lo: int
    vis_hi: int

    def cuboids(self) -> list[Cuboid]:
        return [b.cuboid(self.shelves[b.slot].board_height) for b in self.boxes]


def _x_iou(a0: float, a1: float, b0: float, b1: float) -> float:
    inter = min(a1, b1) - max(a0, b0)
    if inter <= 0:
        return 0.0
    return inter / (max(a1, b1) - min(a0, b0))


def lift_frame(det: FrameDetections, config: LiftConfig | None = None) -> FrameReconstruction:
    """Build the per-frame reconstruction (see the module docstring for the rules)."""
    cfg = config or LiftConfig()
    shelves: list[FrameShelf] = []
    boxes: list[FrameBox] = []
    h = 0.0
    for s in det.slots:
        shelves.append(FrameShelf(s.slot, s.present, h, s.clear_height, s.z_range, s.segments, s.shelf_cols))
        if s.present and s.clear_height > 0:
            h += s.clear_height + cfg.board_thickness
    for s in det.slots:
        tops, fronts = s.boxes, s.front
        match: dict[int, int] = {}
        if tops and fronts:
            cost = np.ones((len(tops), len(fronts)))
            for i, t in enumerate(tops):
                for j, f in enumerate(fronts):
                    cost[i, j] = 1.0 - _x_iou(t.x0, t.x1, f.x0, f.x1)
            ri, ci = linear_sum_assignment(cost)
            match = {int(i): int(j) for i, j in zip(ri, ci) if 1.0 - cost[i, j] >= cfg.match_iou}
        slot_boxes: list[FrameBox] = []
        heights = []
        pending = []
        for i, t in enumerate(tops):
            prof = s.box_height[t.c0 : t.c1]
            has = prof > 0
            if i in match:
                f = fronts[match[i]]
                a, b = max(t.c0, f.c0), min(t.c1, f.c1)
                seg = s.box_height[a:b]
                seg = seg[seg > 0]
                height, conf, src = float(np.median(seg)) if seg.size else f.height, CONF_MATCHED, "top+front"
                heights.append(height)
            elif has.mean() >= cfg.min_profile_fraction:
                height, conf, src = float(np.median(prof[has])), CONF_PROFILE, "top+profile"
            else:
                pending.append(i)
                continue
            slot_boxes.append(_box(s.slot, t, height, conf, src))
        for i in pending:
            t = tops[i]
            height = float(np.median(heights)) if heights else 0.5 * s.clear_height
            slot_boxes.append(_box(s.slot, t, max(height, 1e-3), CONF_TOP_ONLY, "top"))
        # Front runs that no top box explains become boxes of unknown depth.
        if fronts:
            covered = np.zeros(len(s.box_height), bool)
            for t in tops:
                covered[t.c0 : t.c1] = True
            z0, z1 = s.z_range
            depths = [t.z1 - t.z0 for t in tops]
            depth = float(np.median(depths)) if depths else 0.5 * (z1 - z0)
            for f in fronts:
                if covered[f.c0 : f.c1].mean() >= 0.5 or depth <= 0:
                    continue
                zc = (z0 + z1) / 2
                cut_l, cut_r = f.c0 <= det.vis_lo + det.cut_cols, f.c1 >= det.vis_hi - det.cut_cols
                conf = CONF_FRONT_ONLY * (CUT_FACTOR if (cut_l or cut_r) else 1.0)
                slot_boxes.append(
                    FrameBox(
                        s.slot,
                        (f.x0 + f.x1) / 2,
                        zc,
                        f.x1 - f.x0,
                        depth,
                        0.0,
                        f.height,
                        f.x0,
                        f.x1,
                        zc - depth / 2,
                        zc + depth / 2,
                        cut_l,
                        cut_r,
                        conf,
                        "front",
                    )
                )
        slot_boxes.sort(key=lambda b: b.x0)
        boxes.extend(slot_boxes)
    return FrameReconstruction(shelves, boxes, det.vis_lo, det.vis_hi)


def _box(slot: int, t, height: float, conf: float, src: str) -> FrameBox:
    if t.cut_left or t.cut_right:
        conf *= CUT_FACTOR
    return FrameBox(
        slot, t.cx, t.cz, t.w, t.d, t.yaw, height, t.x0, t.x1, t.z0, t.z1, t.cut_left, t.cut_right, conf, src
    )
