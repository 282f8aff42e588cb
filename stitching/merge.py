"""Merge: F_{t+1} = merge(F_t, f_{t+1}), streaming, in one global frame.

`MapBuilder` keeps only the map itself (fused boxes, a per-slot shelf-evidence strip along X at
layout resolution, running means of shelf heights) plus the previous frame's top layout for the
correlation fallback: memory does not grow with the frames already merged. The one exception is
the camera path, one `StepRecord` per frame (``MergeConfig.keep_steps = None``, the default, which
``warehouse.json`` stores); ``keep_steps = N`` keeps only the last N beside running totals
(`stitching.path_record.StepStats`), so memory is bounded by the map alone. Map boxes and rack ends are indexed by X
(`stitching.xindex.XIndex`), so a frame's cost depends on what is near it, not on how much of the
row is already mapped (time grows linearly with the frame count on a long aisle).

Each map box is a `stitching.fused_box.FusedBox` (its fusion rules are described there). `build` stands each
on its shelf (`_on_shelf`: the footprint's centre over the shelf's fused depth, the part beyond it cut off, no box
longer than its rack or taller than the clear height) and keeps one of any two covering half of each other, by
the definitions the map's schema checks (`stitching.map_schema`), so every map it builds is one its readers take.
"""

from __future__ import annotations

import bisect
import math
from collections import deque
from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment

from layouts.errors import LayoutError
from layouts.spec import LayoutSpec
from stitching.fused_box import FusedBox, dedup_boxes
from stitching.lift import FrameBox, FrameReconstruction
from stitching.map_schema import DUPLICATE_SHARE, Footprint, footprint_extent, overlap_share
from stitching.path_record import StepStats, UntrustedFrames
from stitching.registration import Registration
from stitching.shift import MotionPrior, ShiftConfig
from stitching.uprights import UprightStrip
from stitching.warehouse_map import MapBox, MapRack, MapShelf, StepRecord, WarehouseMap, partial_side
from stitching.xindex import XIndex

MAX_HELD = 64  #: untrusted frames held back at most; older ones of a longer stretch are left out of the map
MIN_SIZE = 1e-3  #: metres; a box cut to its shelf thinner than this stands on no shelf


@dataclass(frozen=True)
class MergeConfig:
    match_score: float = 0.5  #: minimum overlap score for a frame box to update a map box
    min_support: float = 0.3  #: observed / seen below this drops a box at the end
    min_rack_length: float = 0.3  #: metres; shorter shelf runs are not racks
    rack_gap_fill: float = 0.08  #: metres; shelf runs closer than this are one rack
    partial_margin: float = 0.05  #: metres; a rack end this close to the seen range's end is partial there
    keep_steps: int | None = None  #: StepRecords kept: None = every frame, N = the last N (plus `StepStats`)

    def __post_init__(self) -> None:
        for name in ("match_score", "min_support", "min_rack_length", "rack_gap_fill", "partial_margin"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0:
                raise LayoutError(f"MergeConfig.{name} must be a finite number >= 0, got {v!r}")
        k = self.keep_steps
        if k is not None and (isinstance(k, bool) or not isinstance(k, int) or k < 0):
            raise LayoutError(f"MergeConfig.keep_steps must be None or an integer >= 0, got {k!r}")


class MapBuilder(Registration):
    """Streaming stitcher: call `add` once per frame in order, then `build` for the `WarehouseMap`."""

    def __init__(
        self,
        spec: LayoutSpec,
        merge: MergeConfig | None = None,
        shift: ShiftConfig | None = None,
        board_thickness: float = 0.06,
    ):
        self.spec = spec
        self.cfg = merge or MergeConfig()
        self.shift_cfg = shift or ShiftConfig()
        self.board_thickness = board_thickness
        R = spec.num_slots
        self.dx = spec.x_extent / spec.size
        self.boxes: list[list[FusedBox]] = [[] for _ in range(R)]
        # Shelf evidence strip: bins of width dx, global bin index = g0 + position.
        self.g0 = 0
        self.votes = np.zeros((R, 0), np.int32)
        self.seen = np.zeros((R, 0), np.int32)
        self.slot_present = np.zeros(R)
        self.slot_frames = 0
        self.clear = np.zeros(R)
        self.nclear = np.zeros(R)
        self.zr = np.zeros((R, 2))
        self.nshelf = np.zeros(R)
        keep = self.cfg.keep_steps
        self.steps: list[StepRecord] | deque[StepRecord] = [] if keep is None else deque(maxlen=keep)
        self.step_stats = StepStats()
        self.frames = 0  # frames added
        self.ends: list[list] = []  # fused rack ends: [slot, side (0 left, 1 right), x, count]
        # X indexes (ids = list positions): boxes per slot keyed by x0, rack ends keyed by x.
        self._box_index = [XIndex() for _ in range(R)]
        self._end_index = XIndex()
        self._max_w = 0.0  # widest map box so far: bounds how far left of a range a box may start
        self._prev_top: np.ndarray | None = None
        self._offset = 0.0
        self._velocity = 0.0
        self.prior = MotionPrior(self.shift_cfg)
        self.untrusted = UntrustedFrames(keep)  # what the frames placed by a guess saw
        self._anchor = (0, 0.0)  # (frame position, offset) of the last trusted frame
        self._held_dropped = 0  # held frames pushed out by longer stretches (left out of the map)
        self._held: deque[tuple[int, FrameReconstruction, StepRecord]] = deque(maxlen=MAX_HELD)
        self.uprights = UprightStrip(self.dx)  # upright columns of the trusted frames (`stitching.uprights`)

    def _boxes_near(self, r: int, lo: float, hi: float) -> list[FusedBox]:
        """Slot ``r``'s map boxes that may overlap ``[lo, hi]`` (a superset), in creation order."""
        boxes = self.boxes[r]
        return [boxes[i] for i in self._box_index[r].query(lo - self._max_w, hi)]

    def _add_box(self, r: int, m: FusedBox) -> None:
        m.ident = len(self.boxes[r])
        self._box_index[r].add(m.ident, m.x0)
        self.boxes[r].append(m)
        self._max_w = max(self._max_w, m.width)

    def _merge_ends(self, rec: FrameReconstruction, off: float) -> None:
        """Average whole rack ends into the map's ends (within two columns), or add new ones."""
        for sh in rec.shelves:
            for x0, x1, cut_l, cut_r in sh.segments:
                for side, x, cut in ((0, x0 + off, cut_l), (1, x1 + off, cut_r)):
                    if cut:
                        continue
                    for i in self._end_index.query(x - 2 * self.dx, x + 2 * self.dx):
                        e = self.ends[i]
                        if e[0] == sh.slot and e[1] == side and abs(e[2] - x) <= 2 * self.dx:
                            e[2] = (e[2] * e[3] + x) / (e[3] + 1)
                            e[3] += 1
                            self._end_index.move(i, e[2])
                            break
                    else:
                        self._end_index.add(len(self.ends), x)
                        self.ends.append([sh.slot, side, x, 1])

    # ------------------------------------------------------------------ merging
    def add(
        self,
        rec: FrameReconstruction,
        top: np.ndarray | None = None,
        frame: int | None = None,
        motion: float | None = None,
        motion_conf: float | None = None,
        uprights: np.ndarray | None = None,
    ) -> StepRecord:
        """Register one frame and fuse it into the map; returns its step record (``motion``, ``motion_conf``
        (default 1): see `register`; ``uprights``: the frame's upright columns, one flag per layout column)."""
        if motion is not None and (
            isinstance(motion, bool) or not isinstance(motion, (int, float)) or not math.isfinite(motion)
        ):
            raise LayoutError(f"motion must be a finite number of metres or None, got {motion!r}")
        mc = 1.0 if motion_conf is None else motion_conf
        if isinstance(mc, bool) or not isinstance(mc, (int, float)) or not 0 <= mc <= 1:
            raise LayoutError(f"motion_conf must be a number in [0, 1] or None, got {motion_conf!r}")
        step = self.register(rec, top, None if motion is None else float(motion), float(mc))
        if frame is not None:
            step.frame = frame
        off = step.offset
        self._velocity = step.shift if step.method != "prediction" else self._velocity
        self.prior.update(self.frames, off, step.trusted)
        self._offset = off
        self.steps.append(step)
        self.step_stats.add(step)
        self.frames += 1
        self._prev_top = top
        if not step.trusted:
            # placed by a guess: held back, so that a wrong guess cannot bend the map (later frames register
            # against what trusted frames placed); placed between the trusted frames on either side once the
            # path is found again (`_place_held`), left out when it is not
            lo, hi = self.spec.col_to_x(rec.vis_lo) + off, self.spec.col_to_x(rec.vis_hi) + off
            self.untrusted.add(step.frame, float(lo), float(hi))
            self._held_dropped += len(self._held) == self._held.maxlen
            self._held.append((self.frames - 1, rec, step))
            return step
        if self._held:
            self._place_held(self.frames - 1, off)
        self._anchor = (self.frames - 1, off)
        self._merge_frame(rec, off)
        if uprights is not None:
            self.uprights.add(uprights, float(self.spec.col_to_x(rec.vis_lo + 0.5)) + off, rec.vis_lo, rec.vis_hi)
        return step

    def _place_held(self, pos: int, off: float) -> None:
        """Merge the held-back frames of the stretch that ends at trusted frame ``pos`` (offset ``off``), each
        at the offset interpolated between the trusted frames on either side (their step records updated)."""
        p0, o0 = self._anchor
        prev = o0
        for p, rec, step in self._held:
            o = o0 + (off - o0) * (p - p0) / max(pos - p0, 1)
            step.offset, step.shift, prev = o, o - prev, o
            self._merge_frame(rec, o)
        self._held.clear()

    def _merge_frame(self, rec: FrameReconstruction, off: float) -> None:
        """Fuse one frame placed at camera offset ``off``: shelf evidence, rack ends, boxes."""
        self._merge_shelves(rec, off)
        self._merge_ends(rec, off)
        lo = self.spec.col_to_x(rec.vis_lo) + off
        hi = self.spec.col_to_x(rec.vis_hi) + off
        by_slot: list[list[FrameBox]] = [[] for _ in self.boxes]
        for b in rec.boxes:
            by_slot[b.slot].append(b)
        for r, fbs in enumerate(by_slot):
            if not rec.shelves[r].present:
                continue
            near = [m for m in self._boxes_near(r, lo - 0.5, hi + 0.5) if m.x1 > lo - 0.5 and m.x0 < hi + 0.5]
            for m in near:
                if m.x0 >= lo and m.x1 <= hi:
                    m.n_seen += 1
            self._merge_slot(r, fbs, near, off)

    def _merge_slot(self, r: int, fbs: list[FrameBox], near: list[FusedBox], off: float) -> None:
        if not fbs:
            return
        matched: dict[int, int] = {}
        if near:
            score = np.zeros((len(fbs), len(near)))
            for i, f in enumerate(fbs):
                fx0, fx1 = f.x0 + off, f.x1 + off
                for j, m in enumerate(near):
                    ix = min(fx1, m.x1) - max(fx0, m.x0)
                    iz = min(f.z1, m.z1) - max(f.z0, m.z0)
                    if ix <= 0 or iz <= 0:
                        continue
                    sx = ix / max(min(fx1 - fx0, m.width), 1e-6)
                    sz = iz / max(min(f.z1 - f.z0, m.depth), 1e-6)
                    score[i, j] = sx * sz
            ri, ci = linear_sum_assignment(-score)
            matched = {int(i): int(j) for i, j in zip(ri, ci) if score[i, j] >= self.cfg.match_score}
        for i, f in enumerate(fbs):
            if i in matched:
                m = near[matched[i]]
            elif near and score[i].max() >= self.cfg.match_score:
                # A second piece of an already matched box (a split detection): fuse, never duplicate.
                m = near[int(np.argmax(score[i]))]
            else:
                self._add_box(r, FusedBox(f, off))
                continue
            m.fuse(f, off)
            m.limit_width(self.spec.x_extent, self.dx)
            self._box_index[r].move(m.ident, m.x0)
            self._max_w = max(self._max_w, m.width)

    def _merge_shelves(self, rec: FrameReconstruction, off: float) -> None:
        spec = self.spec
        n = rec.vis_hi - rec.vis_lo
        self.slot_frames += 1
        if n <= 0:
            return
        x_first = float(spec.col_to_x(rec.vis_lo + 0.5)) + off
        g_first = int(math.floor(x_first / self.dx))
        self._grow(g_first, g_first + n)
        a = g_first - self.g0
        for s in rec.shelves:
            cols = s.shelf_cols[rec.vis_lo : rec.vis_hi]
            self.seen[s.slot, a : a + n] += 1
            self.votes[s.slot, a : a + n] += cols
            if s.present:
                self.slot_present[s.slot] += 1
                k = self.nshelf[s.slot]
                self.zr[s.slot] = (self.zr[s.slot] * k + np.asarray(s.z_range)) / (k + 1)
                self.nshelf[s.slot] = k + 1
                if s.clear_height > 0:  # a front view without the shelf says nothing about heights
                    k = self.nclear[s.slot]
                    self.clear[s.slot] = (self.clear[s.slot] * k + s.clear_height) / (k + 1)
                    self.nclear[s.slot] = k + 1

    def _grow(self, g_lo: int, g_hi: int) -> None:
        R = self.votes.shape[0]
        cur_lo, cur_hi = self.g0, self.g0 + self.votes.shape[1]
        if self.votes.shape[1] == 0:
            cur_lo = cur_hi = g_lo
        new_lo, new_hi = min(cur_lo, g_lo), max(cur_hi, g_hi)
        if new_lo == self.g0 and new_hi == self.g0 + self.votes.shape[1]:
            return
        # Grow geometrically so that a long aisle copies the strip O(log length) times, not O(length).
        pad = max(64, self.votes.shape[1])
        new_lo = new_lo - pad if new_lo < cur_lo else new_lo
        new_hi = new_hi + pad if new_hi > cur_hi else new_hi
        votes = np.zeros((R, new_hi - new_lo), np.int32)
        seen = np.zeros((R, new_hi - new_lo), np.int32)
        a = cur_lo - new_lo
        votes[:, a : a + self.votes.shape[1]] = self.votes
        seen[:, a : a + self.seen.shape[1]] = self.seen
        self.votes, self.seen, self.g0 = votes, seen, new_lo

    # ------------------------------------------------------------------ output
    def build(self, origin_world: tuple[float, float, float] | None = None, meta: dict | None = None) -> WarehouseMap:
        """The current map as a `WarehouseMap` (racks from the shelf strip, boxes with stable ids)."""
        cfg = self.cfg
        R = self.votes.shape[0]
        frames = max(self.slot_frames, 1)
        present = self.slot_present / frames >= 0.5
        with np.errstate(invalid="ignore", divide="ignore"):
            frac = np.where(self.seen > 0, self.votes / np.maximum(self.seen, 1), 0.0)
        shelf_bins = (frac >= 0.5) & present[:, None]
        any_bins = shelf_bins.any(axis=0)
        runs = _bin_runs(any_bins, int(round(cfg.rack_gap_fill / self.dx)))
        seen_bins = (self.seen > 0).any(axis=0)
        margin = int(round(cfg.partial_margin / self.dx))
        racks: list[MapRack] = []
        rack_ranges, rack_partial = [], []
        for a, b in runs:
            x0, x1 = (self.g0 + a) * self.dx, (self.g0 + b) * self.dx
            if x1 - x0 >= cfg.min_rack_length:
                rack_ranges.append((x0, x1))
                rack_partial.append(_partial_run(seen_bins, a, b, margin))
        # Board heights from the fused clear heights: H_0 = 0, H_{r+1} = H_r + clear_r + thickness.
        boards = np.concatenate([[0.0], np.cumsum(self.clear + self.board_thickness)])[:R]
        placed: list[list[list[_Placed]]] = [[[] for _ in range(R)] for _ in rack_ranges]
        rack_starts = [x0 for x0, _ in rack_ranges]
        for r in range(R):
            for m in dedup_boxes(self.boxes[r], cfg.match_score):
                if m.n_obs < cfg.min_support * max(m.n_seen, 1):
                    continue
                mean_conf = m.conf / m.n_obs
                if m.n_full == 0 and (m.nl == 0 or m.nr == 0) and mean_conf < 0.3:
                    continue
                if not rack_ranges:
                    continue
                k = _nearest_range(rack_ranges, rack_starts, (m.x0 + m.x1) / 2)
                p = _on_shelf(m, rack_ranges[k], (float(self.zr[r][0]), float(self.zr[r][1])), float(self.clear[r]))
                if p is not None:
                    placed[k][r].append(p)
        shares = [self.untrusted.share(x0, x1) for x0, x1 in rack_ranges]
        for k, (x0, x1) in enumerate(rack_ranges):
            rid = f"rack_{k:02d}"
            shelves = []
            for r in range(R):
                if not present[r]:
                    continue
                sid = f"{rid}/shelf_{r:02d}"
                board, clear = float(boards[r]), float(self.clear[r])
                boxes = []
                for j, p in enumerate(_without_duplicates(placed[k][r])):
                    m = p.box
                    conf = m.conf / m.n_obs * min(1.0, m.n_obs / 3)
                    if m.n_full == 0:
                        conf *= 0.7
                    boxes.append(
                        MapBox(
                            f"{sid}/box_{j:03d}",
                            (p.cx, -(board + p.h / 2), p.cz),
                            (p.w, p.h, p.d),
                            p.yaw,
                            float(conf),
                            m.n_obs,
                        )
                    )
                s_conf = float(self.slot_present[r] / frames) * (1.0 - 0.5 * shares[k])
                shelves.append(
                    MapShelf(sid, r, board, clear, (x0, x1), tuple(self.zr[r]), s_conf, boxes, rack_partial[k])
                )
            racks.append(MapRack(rid, (x0, x1), shelves, rack_partial[k]))
        meta = dict(meta or {})
        meta.setdefault("step_summary", self.step_stats.to_dict())
        meta.setdefault("registration", self.untrusted.to_dict(shares, len(self._held) + self._held_dropped))
        seen_x = [((self.g0 + a) * self.dx, (self.g0 + b) * self.dx) for a, b in _bin_runs(seen_bins, 0)]
        ups = [(u.x, u.support) for u in self.uprights.peaks()]
        return WarehouseMap(racks, list(self.steps), self.board_thickness, origin_world, meta, seen_x, ups)


@dataclass(frozen=True)
class _Placed:
    """A map box as it stands on its shelf: its footprint (centre, size, yaw) and height in the map."""

    box: FusedBox
    cx: float
    cz: float
    w: float
    d: float
    yaw: float
    h: float

    @property
    def footprint(self) -> Footprint:
        return self.cx, self.cz, self.w, self.d, self.yaw


def _on_shelf(m: FusedBox, xr: tuple[float, float], zr: tuple[float, float], clear: float) -> _Placed | None:
    """Box ``m`` stood on the shelf spanning ``xr`` x ``zr`` (clear height ``clear``, 0 = unknown), or None when it
    stands on no shelf. A box stands on its shelf: its footprint's centre lies over the shelf's depth (one beyond it
    would fall) and its footprint overlaps the rack's X range (`stitching.map_schema.footprint_extent`, the extent
    the schema checks); the part reaching past the shelf's depth is cut off, a box longer than the rack is cut to
    it (a blob over the rack's end, not one box) and none is taller than the clear height to the next board."""
    cx, cz, w, d, yaw = m.cuboid_params()
    (x0, x1), (z0, z1) = xr, zr
    if not z0 <= cz <= z1:
        return None
    _, _, bz0, bz1 = footprint_extent(cx, cz, w, d, yaw)
    lo, hi = max(bz0, z0), min(bz1, z1)
    if hi - lo < bz1 - bz0:
        (w, d), cz = _fit(w, d, yaw, hi - lo, along_z=True), (lo + hi) / 2
    bx0, bx1, _, _ = footprint_extent(cx, cz, w, d, yaw)
    if bx1 <= x0 or bx0 >= x1:
        return None
    if bx1 - bx0 > x1 - x0:
        lo, hi = max(bx0, x0), min(bx1, x1)
        (w, d), cx = _fit(w, d, yaw, hi - lo, along_z=False), (lo + hi) / 2
    if min(w, d) < MIN_SIZE:
        return None
    return _Placed(m, cx, cz, w, d, yaw, min(m.h, clear) if clear > 0 else m.h)


def _fit(w: float, d: float, yaw: float, room: float, along_z: bool) -> tuple[float, float]:
    """``(w, d)`` shrunk so that the footprint reaches at most ``room`` along Z (``along_z``) or X: the side
    lying most along that axis gives way first, both in proportion when it alone cannot."""
    c, s = abs(math.cos(yaw)), abs(math.sin(yaw))
    kw, kd = (s, c) if along_z else (c, s)  # what each side adds to the reach along the axis
    reach = w * kw + d * kd
    if reach <= room:
        return w, d
    if kd >= kw and room - w * kw > 0:
        return w, (room - w * kw) / kd
    if kw > kd and room - d * kd > 0:
        return (room - d * kd) / kw, d
    f = max(room, 0.0) / reach
    return w * f, d * f


def _without_duplicates(placed: list[_Placed]) -> list[_Placed]:
    """One shelf's boxes in X order, less those covering more than `map_schema.DUPLICATE_SHARE` (less a margin
    the file's rounding cannot cross) of a better-observed box's footprint: the same box twice."""
    kept: list[_Placed] = []
    spans: list[tuple[float, float]] = []
    index = XIndex()
    widest = 0.0
    for p in sorted(placed, key=lambda p: (-p.box.n_obs, _x_order(p))):
        x0, x1, _, _ = footprint_extent(*p.footprint)
        near = (kept[i] for i in index.query(x0 - widest, x1) if spans[i][1] > x0 and spans[i][0] < x1)
        if all(overlap_share(p.footprint, q.footprint) <= DUPLICATE_SHARE - 0.01 for q in near):
            index.add(len(kept), x0)
            kept.append(p)
            spans.append((x0, x1))
            widest = max(widest, x1 - x0)
    return sorted(kept, key=_x_order)


def _x_order(p: _Placed) -> tuple[float, float]:
    """Where a box comes in its shelf's X order (its ids): the middle of its X edges, then its near edge."""
    return (p.box.x0 + p.box.x1) / 2, p.box.z0


def _partial_run(seen: np.ndarray, a: int, b: int, margin: int) -> str | None:
    """Which ends of the shelf run ``[a, b)`` (strip bins) may go on unseen: an unseen bin (or the
    strip's end) among the ``margin + 1`` bins beyond that end means the camera's coverage stops there."""
    cut_start = a - margin - 1 < 0 or not seen[a - margin - 1 : a].all()
    cut_end = b + margin + 1 > seen.size or not seen[b : b + margin + 1].all()
    return partial_side(bool(cut_start), bool(cut_end))


def _nearest_range(ranges: list[tuple[float, float]], starts: list[float], x: float) -> int:
    """Index of the sorted, disjoint range containing ``x``, else the nearest one (the first on ties)."""
    k = bisect.bisect_right(starts, x) - 1
    best, best_d = -1, math.inf
    for j in (k, k + 1):
        if 0 <= j < len(ranges):
            x0, x1 = ranges[j]
            d = 0.0 if x0 <= x <= x1 else min(abs(x - x0), abs(x - x1))
            if d < best_d:
                best, best_d = j, d
    return best


def _bin_runs(mask: np.ndarray, fill: int) -> list[tuple[int, int]]:
    """Runs of True, joining runs separated by at most ``fill`` False bins."""
    idx = np.flatnonzero(mask)
    if idx.size == 0:
        return []
    breaks = np.flatnonzero(np.diff(idx) > fill + 1)
    starts = np.concatenate([[idx[0]], idx[breaks + 1]])
    ends = np.concatenate([idx[breaks], [idx[-1]]]) + 1
    return list(zip(starts.tolist(), ends.tolist()))
