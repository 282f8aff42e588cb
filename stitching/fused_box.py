"""One fused map box: the running accumulator `MapBuilder` keeps per box, and the end-of-run deduplication.

Fusion rules per box (frame boxes are matched to map boxes of the same slot one-to-one by the
Hungarian assignment on footprint overlap, each extent normalised by the smaller box so a box cut
by the image border still matches its whole self):

* an edge seen whole (not cut) is averaged over its whole observations; an edge only ever seen
  cut grows outwards (min / max) as more of the box comes into view, but never makes the box
  wider than the layout's X extent (a longer "box" is a merged blob, not a box);
* the oriented footprint (centre, width, depth, yaw) averages whole observations only;
* depth range, height and confidence average all observations (cut ones weigh less);
* a map box counts how often it was inside the visible range (``seen``) and how often it was
  observed; boxes observed in fewer than ``min_support`` of those frames are dropped at the end
  (noise blobs of single frames), as are boxes never observed whole with a low confidence.
"""

from __future__ import annotations

import math

from stitching.lift import FrameBox
from stitching.xindex import XIndex

CUT_WEIGHT = 0.3  #: weight of an observation cut by the image border in the depth / height / confidence means


class FusedBox:
    """Accumulator of one map box (global X): its edges, footprint, depth, height and observation counts."""

    __slots__ = (
        "slot",
        "x0",
        "x1",
        "nl",
        "nr",
        "z0",
        "z1",
        "wz",
        "h",
        "n_full",
        "cx",
        "cz",
        "w",
        "d",
        "c4",
        "s4",
        "n_obs",
        "n_seen",
        "conf",
        "ident",
    )

    def __init__(self, fb: FrameBox, off: float):
        self.slot = fb.slot
        self.x0, self.x1 = fb.x0 + off, fb.x1 + off
        self.nl = 0 if fb.cut_left else 1
        self.nr = 0 if fb.cut_right else 1
        self.z0 = self.z1 = self.h = self.wz = 0.0
        self.n_full = 0
        self.cx = self.cz = self.w = self.d = self.c4 = self.s4 = 0.0
        self.n_obs = 0
        self.n_seen = 1
        self.conf = 0.0
        self.ident = -1  # position in its slot's box list (set by MapBuilder)
        self._fuse_common(fb, off)

    @property
    def width(self) -> float:
        return self.x1 - self.x0

    @property
    def depth(self) -> float:
        return self.z1 - self.z0

    def _fuse_common(self, fb: FrameBox, off: float) -> None:
        whole = not (fb.cut_left or fb.cut_right)
        wt = 1.0 if whole else CUT_WEIGHT
        t = self.wz + wt
        self.z0 = (self.z0 * self.wz + fb.z0 * wt) / t
        self.z1 = (self.z1 * self.wz + fb.z1 * wt) / t
        self.h = (self.h * self.wz + fb.height * wt) / t
        self.wz = t
        self.n_obs += 1
        self.conf += fb.confidence
        if whole:
            yaw, w, d = fb.yaw, fb.w, fb.d
            if self.n_full:
                # Align to the running yaw modulo 90 degrees (a rectangle's yaw is ambiguous there).
                mean = math.atan2(self.s4, self.c4) / 4
                k = round((yaw - mean) / (math.pi / 2))
                yaw -= k * math.pi / 2
                if k % 2:
                    w, d = d, w
            n = self.n_full
            self.cx = (self.cx * n + fb.cx + off) / (n + 1)
            self.cz = (self.cz * n + fb.cz) / (n + 1)
            self.w = (self.w * n + w) / (n + 1)
            self.d = (self.d * n + d) / (n + 1)
            self.c4 += math.cos(4 * yaw)
            self.s4 += math.sin(4 * yaw)
            self.n_full = n + 1

    def fuse(self, fb: FrameBox, off: float) -> None:
        x0, x1 = fb.x0 + off, fb.x1 + off
        if not fb.cut_left:
            self.x0 = x0 if self.nl == 0 else (self.x0 * self.nl + x0) / (self.nl + 1)
            self.nl += 1
        elif self.nl == 0:
            self.x0 = min(self.x0, x0)
        if not fb.cut_right:
            self.x1 = x1 if self.nr == 0 else (self.x1 * self.nr + x1) / (self.nr + 1)
            self.nr += 1
        elif self.nr == 0:
            self.x1 = max(self.x1, x1)
        self._fuse_common(fb, off)

    def limit_width(self, max_w: float, min_w: float) -> None:
        """Keep the X extent within ``[min_w, max_w]``: a cut edge stops growing at ``max_w`` (whole
        edges hold); edges averaged from different observations never cross (at least ``min_w``)."""
        if self.x1 - self.x0 < min_w:
            c = (self.x0 + self.x1) / 2
            self.x0, self.x1 = c - min_w / 2, c + min_w / 2
            return
        if self.x1 - self.x0 <= max_w:
            return
        if self.nl and not self.nr:
            self.x1 = self.x0 + max_w
        elif self.nr and not self.nl:
            self.x0 = self.x1 - max_w
        else:
            c = (self.x0 + self.x1) / 2
            self.x0, self.x1 = c - max_w / 2, c + max_w / 2

    def cuboid_params(self) -> tuple[float, float, float, float, float]:
        """(cx, cz, w, d, yaw) of the fused footprint."""
        if self.n_full:
            yaw = math.atan2(self.s4, self.c4) / 4
            if abs(yaw) > 1e-3:
                return self.cx, self.cz, self.w, self.d, yaw
        return (self.x0 + self.x1) / 2, (self.z0 + self.z1) / 2, self.width, self.depth, 0.0


def box_overlap(a: FusedBox, b: FusedBox) -> float:
    """Footprint overlap of two boxes, each extent normalised by the smaller box (1 = one holds the other)."""
    ix = min(a.x1, b.x1) - max(a.x0, b.x0)
    iz = min(a.z1, b.z1) - max(a.z0, b.z0)
    if ix <= 0 or iz <= 0:
        return 0.0
    return ix / max(min(a.width, b.width), 1e-6) * iz / max(min(a.depth, b.depth), 1e-6)


def dedup_boxes(boxes: list[FusedBox], thr: float) -> list[FusedBox]:
    """Drop boxes that overlap a better-observed box by ``thr`` or more (kept box absorbs the count).

    The host is the first kept box (in keeping order) that overlaps enough; only kept boxes whose
    X range can overlap are tested (an X index), so this is near-linear in the number of boxes.
    """
    order = sorted(boxes, key=lambda m: (-m.n_obs, m.x0))
    kept: list[FusedBox] = []
    index = XIndex()
    max_w = max((m.width for m in boxes), default=0.0)
    for m in order:
        host = next((kept[i] for i in index.query(m.x0 - max_w, m.x1) if box_overlap(kept[i], m) >= thr), None)
        if host is None:
            index.add(len(kept), m.x0)
            kept.append(m)
        else:
            host.n_seen = max(host.n_seen, m.n_seen)
    return sorted(kept, key=lambda m: m.x0)
