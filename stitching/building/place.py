"""Place each pass's row map on its rack face: by its route pose, then refined where passes overlap.

A pass's row map (`WarehouseMap`: X from its first camera along the camera's right, Z about the rack's mid-depth,
Y from its lowest slot's board) goes into its face's frame (`stitching.building.map`) as follows:

* **Z**: the racks' front (the median of its shelves' front edges) on the face's front line from the floor
  plan; rack rows are straight, so a pass's heading only has to pick the face (within `PlaceConfig.max_heading_off`).
* **X**: the route's first-camera X, plus a correction per pass solved once per face by weighted least squares
  over: the route (each correction near 0, within ``route_sigma``), every overlap between two passes of the
  face (the shift that best lays one pass's boxes and rack ends on the other's, `overlap_shift`), and the face's
  ends in the floor plan (a pass that saw past a face's end puts that rack end on it). An overlap whose shift
  the solution contradicts by more than `PlaceConfig.outlier` is dropped and the rest solved again.
* **Y**: each slot's level (from the route) and that level's board height in the floor plan (else the board
  heights the pass measured, its lowest slot at the floor).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from layouts.errors import InputError
from stitching.building.config import PlaceConfig
from stitching.building.route import FacePlan, PassPose, Route
from stitching.uprights import Upright
from stitching.warehouse_map import WarehouseMap, cut_sides


@dataclass
class PlacedBox:
    level: int
    x: float  #: face-frame centre X
    z: float  #: face-frame centre Z (from the front line)
    rel: float  #: centre height above its board
    size: tuple[float, float, float]
    yaw: float
    confidence: float
    observations: int
    colour: tuple[int, int, int] | None


@dataclass
class PlacedShelf:
    level: int
    board: float  #: board height above the pass's lowest slot's board (metres)
    clear: float
    z_range: tuple[float, float]  #: face frame
    confidence: float


@dataclass
class PlacedRack:
    lo: float
    hi: float
    cut_lo: bool
    cut_hi: bool
    shelves: list[PlacedShelf]
    boxes: list[PlacedBox]


@dataclass
class PlacedPass:
    """A pass's row map in its face's frame, before (``x0``) and after (``x0 + shift``) registration."""

    pose: PassPose
    x0: float
    racks: list[PlacedRack]
    seen: list[tuple[float, float]]  #: X intervals its view held (map-relative: add `offset`)
    board_thickness: float
    trusted: float  #: share of its frames placed on a confirmed path
    shift: float = 0.0
    edges: list[dict] = field(default_factory=list)
    uprights: list[Upright] = field(default_factory=list)  #: upright frames its row map found (add `offset`)

    @property
    def offset(self) -> float:
        return self.x0 + self.shift

    @property
    def levels(self) -> list[int]:
        return sorted({s.level for r in self.racks for s in r.shelves})

    def seen_range(self) -> tuple[float, float]:
        if not self.seen:
            xs = [v for r in self.racks for v in (r.lo, r.hi)] or [0.0]
            return self.offset + min(xs), self.offset + max(xs)
        return self.offset + min(a for a, _ in self.seen), self.offset + max(b for _, b in self.seen)


def place_pass(pose: PassPose, face: FacePlan, wmap: WarehouseMap, cfg: PlaceConfig | None = None) -> PlacedPass:
    """A pass's row map in its face frame at its route pose (`shift` 0)."""
    cfg = cfg or PlaceConfig()
    nominal = 90.0 if face.side == "R" else -90.0
    off = (pose.heading_deg - nominal + 180.0) % 360.0 - 180.0
    if abs(off) > cfg.max_heading_off:
        raise InputError(
            f"route: pass {pose.sequence!r} heads {pose.heading_deg:.0f} degrees, not toward face "
            f"{face.aisle:02d}-{face.side} ({nominal:.0f})"
        )
    shelves = wmap.shelves()
    front = float(np.median([s.z_range[0] for s in shelves])) if shelves else 0.0
    racks = []
    for r in wmap.racks:
        cut_lo, cut_hi = cut_sides(r.partial)
        placed_shelves, boxes = [], []
        for s in r.shelves:
            level = pose.slot_level(s.slot)
            placed_shelves.append(
                PlacedShelf(
                    level, s.board_height, s.clear_height, (s.z_range[0] - front, s.z_range[1] - front), s.confidence
                )
            )
            for b in s.boxes:
                boxes.append(
                    PlacedBox(
                        level,
                        b.center[0],
                        b.center[2] - front,
                        -b.center[1] - s.board_height,
                        tuple(b.size),
                        b.yaw,
                        b.confidence,
                        b.observations,
                        b.colour,
                    )  # fmt: skip
                )
        racks.append(PlacedRack(r.x_range[0], r.x_range[1], cut_lo, cut_hi, placed_shelves, boxes))
    steps = wmap.steps
    trusted = sum(s.trusted for s in steps) / len(steps) if steps else 1.0
    ups = [Upright(x, sup) for x, sup in wmap.uprights]
    return PlacedPass(pose, face.sign * pose.x, racks, list(wmap.seen_x), wmap.board_thickness, trusted, uprights=ups)


def _features(p: PlacedPass, lo: float, hi: float) -> dict[tuple, list[tuple[float, float]]]:
    """Face-frame features of ``p`` inside [lo, hi]: per (kind, level) a list of (x, width)."""
    out: dict[tuple, list[tuple[float, float]]] = {}
    for r in p.racks:
        for x, cut, kind in ((r.lo, r.cut_lo, "lo"), (r.hi, r.cut_hi, "hi")):
            x += p.offset
            if not cut and lo <= x <= hi:
                out.setdefault(("rack", kind), []).append((x, 0.0))
        for b in r.boxes:
            x = b.x + p.offset
            half = 0.5 * b.size[0]
            if lo <= x - half and x + half <= hi:
                out.setdefault(("box", b.level), []).append((x, b.size[0]))
    return out


def overlap_shift(p: PlacedPass, q: PlacedPass, cfg: PlaceConfig | None = None) -> tuple[float, int] | None:
    """The shift ``t`` to add to ``q``'s X that lays its boxes and rack ends in the overlap on ``p``'s, and how
    many features agree; None where they share too little."""
    cfg = cfg or PlaceConfig()
    (a0, a1), (b0, b1) = p.seen_range(), q.seen_range()
    lo, hi = max(a0, b0) + cfg.margin, min(a1, b1) - cfg.margin
    if hi - lo < 0.5:
        return None
    fp, fq = _features(p, lo - cfg.max_shift, hi + cfg.max_shift), _features(q, lo, hi)
    pairs = []  # (difference, key, index in q)
    for key, qs in fq.items():
        ps = fp.get(key, [])
        for j, (xq, wq) in enumerate(qs):
            for xp, wp in ps:
                d = xp - xq
                if abs(d) <= cfg.max_shift and abs(wp - wq) <= 0.15:
                    pairs.append((d, key, j))
    if not pairs:
        return None
    diffs = np.array([d for d, _, _ in pairs])
    best, best_t = 0, 0.0
    for t in diffs:
        near = np.abs(diffs - t) <= cfg.match_tol
        n = len({(pairs[i][1], pairs[i][2]) for i in np.flatnonzero(near)})
        if n > best or (n == best and abs(t) < abs(best_t)):
            best, best_t = n, float(t)
    if best < cfg.min_matches:
        return None
    near = np.abs(diffs - best_t) <= cfg.match_tol
    return float(np.median(diffs[near])), best


def _anchors(p: PlacedPass, face: FacePlan, cfg: PlaceConfig) -> list[tuple[float, str]]:
    """(target correction, which end) for each end of the face this pass saw past: its end rack's end on it."""
    if face.x_min is None or face.x_max is None or not p.racks:
        return []
    lo_f, hi_f = sorted((face.sign * face.x_min, face.sign * face.x_max))
    s0, s1 = p.seen_range()
    out = []
    first, last = min(p.racks, key=lambda r: r.lo), max(p.racks, key=lambda r: r.hi)
    if not first.cut_lo and s0 < first.lo + p.offset - cfg.margin and abs(first.lo + p.offset - lo_f) < cfg.max_shift:
        out.append((lo_f - (first.lo + p.x0), "start"))
    if not last.cut_hi and s1 > last.hi + p.offset + cfg.margin and abs(last.hi + p.offset - hi_f) < cfg.max_shift:
        out.append((hi_f - (last.hi + p.x0), "end"))
    return out


def register_face(passes: list[PlacedPass], face: FacePlan, cfg: PlaceConfig | None = None) -> None:
    """Solve every pass's X correction on one face (in place: ``shift`` and ``edges``)."""
    cfg = cfg or PlaceConfig()
    n = len(passes)
    if n == 0:
        return
    for p in passes:
        p.shift = 0.0
    edges = []
    for i in range(n):
        for j in range(i + 1, n):
            got = overlap_shift(passes[i], passes[j], cfg)
            if got is not None:
                edges.append((i, j, got[0], got[1]))
    anchors = [(i, t, end) for i, p in enumerate(passes) for t, end in _anchors(p, face, cfg)]
    sigma = max(cfg.route_sigma, 0.05)
    for _ in range(3):
        rows, rhs, w = [], [], []
        for i in range(n):
            rows.append(np.eye(n)[i])
            rhs.append(0.0)
            w.append(1.0 / sigma)
        for i, j, t, m in edges:  # (x0_j + d_j) - (x0_i + d_i) moved by t: d_j - d_i = t
            row = np.zeros(n)
            row[j], row[i] = 1.0, -1.0
            rows.append(row)
            rhs.append(t)
            w.append(math.sqrt(m) / cfg.edge_sigma)
        for i, t, _ in anchors:
            rows.append(np.eye(n)[i])
            rhs.append(t)
            w.append(1.0 / cfg.anchor_sigma)
        a = np.array(rows) * np.array(w)[:, None]
        sol = np.linalg.lstsq(a, np.array(rhs) * np.array(w), rcond=None)[0]
        bad = [e for e in edges if abs(sol[e[1]] - sol[e[0]] - e[2]) > cfg.outlier]
        if not bad:
            break
        worst = max(bad, key=lambda e: abs(sol[e[1]] - sol[e[0]] - e[2]))
        edges.remove(worst)
    for i, p in enumerate(passes):
        p.shift = float(sol[i])
        p.edges = [
            {"with": passes[j if k == i else k].pose.sequence, "shift": round(t if k == i else -t, 4), "matches": m}
            for k, j, t, m in edges
            if i in (k, j)
        ] + [{"with": f"face {end}", "shift": round(t, 4), "matches": 1} for k, t, end in anchors if k == i]


def place_passes(route: Route, maps: Mapping[str, WarehouseMap], cfg: PlaceConfig | None = None) -> list[PlacedPass]:
    """Every pass of ``route`` placed by its pose (``maps``: its row map by sequence) and registered (`register`):
    in route order."""
    cfg = cfg or PlaceConfig()
    placed = [place_pass(pose, route.faces[pose.key], maps[pose.sequence], cfg) for pose in route.passes]
    register(route, placed, cfg)
    return placed


def register(route: Route, placed: list[PlacedPass], cfg: PlaceConfig | None = None) -> None:
    """Register the placed passes face by face where they overlap (`register_face`, in place)."""
    for key, plan in sorted(route.faces.items()):
        mine = [p for p in placed if p.pose.key == key]
        if mine:
            register_face(mine, plan, cfg)
