"""Free space per shelf, and where a box of a given size fits.

Per shelf (its X range x depth range x clear height in the map):

* ``gaps``: the X intervals not covered by any box's footprint extent along X (a box anywhere
  in the depth blocks that X), ``free_length`` their total;
* ``free_area``: shelf area minus the boxes' footprint areas (clipped to the shelf);
* ``free_volume``: shelf volume (area x clear height) minus the boxes' volumes (clipped);
* ``occupancy``: occupied footprint area / shelf area;
* ``confidence``: the shelf's confidence times the mean confidence of its boxes (1 if none).

`fits(w, d, h)` lists, per shelf, the gaps where a ``w x d x h`` box stands: ``h`` must be at most
the clear height minus ``margin``, the box may turn 90 degrees (``w`` along X or ``d`` along X),
its depth must fit the shelf depth, and the gap must be at least its X size plus ``2 * margin``.
Each returned interval is the range of X positions for the box's *centre*.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

from layouts.errors import InputError
from stitching.geometry import clip_convex, polygon_area
from stitching.warehouse_map import MapShelf, WarehouseMap


@dataclass
class ShelfFreeSpace:
    shelf: str
    length: float
    depth: float
    clear_height: float
    free_length: float
    free_area: float
    free_volume: float
    occupancy: float
    boxes: int
    confidence: float
    gaps: list[tuple[float, float]]

    def to_dict(self) -> dict:
        d = asdict(self)
        for k, v in d.items():
            if isinstance(v, float):
                d[k] = round(v, 4)
        d["gaps"] = [[round(a, 4), round(b, 4)] for a, b in self.gaps]
        return d


@dataclass
class Fit:
    shelf: str
    along_x: float  #: the box's extent along X in this placement
    rotated: bool  #: True when the box's depth runs along X
    centres: list[tuple[float, float]]  #: X ranges for the box centre

    def to_dict(self) -> dict:
        return {
            "shelf": self.shelf,
            "along_x": round(self.along_x, 4),
            "rotated": self.rotated,
            "centres": [[round(a, 4), round(b, 4)] for a, b in self.centres],
        }


def _gaps(shelf: MapShelf) -> list[tuple[float, float]]:
    lo, hi = shelf.x_range
    spans = sorted(b.cuboid.x_range() for b in shelf.boxes)
    gaps, cur = [], lo
    for a, b in spans:
        if a > cur:
            gaps.append((cur, min(a, hi)))
        cur = max(cur, b)
        if cur >= hi:
            break
    if cur < hi:
        gaps.append((cur, hi))
    return [(a, b) for a, b in gaps if b - a > 1e-9]


def shelf_free_space(shelf: MapShelf) -> ShelfFreeSpace:
    """Free length, area, volume and occupancy of one shelf."""
    x0, x1 = shelf.x_range
    z0, z1 = shelf.z_range
    length, depth = max(x1 - x0, 0.0), max(z1 - z0, 0.0)
    area = length * depth
    rect = [(x0, z0), (x1, z0), (x1, z1), (x0, z1)]
    occ_area = occ_vol = 0.0
    for b in shelf.boxes:
        a = polygon_area(clip_convex(b.cuboid.footprint(), rect)) if area > 0 else 0.0
        occ_area += a
        occ_vol += a * min(b.size[1], shelf.clear_height)
    gaps = _gaps(shelf)
    confs = [b.confidence for b in shelf.boxes]
    conf = shelf.confidence * (sum(confs) / len(confs) if confs else 1.0)
    return ShelfFreeSpace(
        shelf=shelf.id,
        length=length,
        depth=depth,
        clear_height=shelf.clear_height,
        free_length=sum(b - a for a, b in gaps),
        free_area=max(area - occ_area, 0.0),
        free_volume=max(area * shelf.clear_height - occ_vol, 0.0),
        occupancy=min(occ_area / area, 1.0) if area > 0 else 0.0,
        boxes=len(shelf.boxes),
        confidence=conf,
        gaps=gaps,
    )


def free_space(wmap: WarehouseMap) -> list[ShelfFreeSpace]:
    """Free space of every shelf of the map, in rack/shelf order."""
    return [shelf_free_space(s) for s in wmap.shelves()]


def parse_box(text: str) -> tuple[float, float, float]:
    """``'0.4x0.3x0.3'`` (width x depth x height, metres) -> floats, or a one-line error."""
    parts = str(text).lower().replace("*", "x").split("x")
    try:
        vals = tuple(float(p) for p in parts)
    except ValueError:
        vals = ()
    if len(vals) != 3 or not all(math.isfinite(v) and v > 0 for v in vals):
        raise InputError(f"--box must be WxDxH in metres with positive numbers, e.g. 0.4x0.3x0.3; got {text!r}")
    return vals  # type: ignore[return-value]


def fits(wmap: WarehouseMap, w: float, d: float, h: float, margin: float = 0.0) -> list[Fit]:
    """Shelves and box-centre X ranges where a ``w x d x h`` box fits (see the module docstring)."""
    for name, v in (("w", w), ("d", d), ("h", h), ("margin", margin)):
        if not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0:
            raise InputError(f"fits: {name} must be a finite number >= 0, got {v!r}")
    out: list[Fit] = []
    for shelf in wmap.shelves():
        if h > shelf.clear_height - margin:
            continue
        depth = shelf.z_range[1] - shelf.z_range[0]
        gaps = _gaps(shelf)
        for along, across, rotated in ((w, d, False), (d, w, True)):
            if rotated and w == d:
                continue
            if across > depth:
                continue
            need = along + 2 * margin
            centres = [(a + need / 2, b - need / 2) for a, b in gaps if b - a >= need]
            if centres:
                out.append(Fit(shelf.id, along, rotated, centres))
    return out


def format_table(rows: list[ShelfFreeSpace], racks: int = 0) -> str:
    """A plain-text table of free space per shelf; without rows, a line saying so (``racks``: the map's rack
    count, which tells "no racks found" from racks without shelves)."""
    head = f"{'shelf':<22} {'boxes':>5} {'length':>7} {'free_len':>8} {'free_m2':>8} {'free_m3':>8} {'occup':>6} {'clear_h':>7} {'conf':>5}"
    lines = [head, "-" * len(head)]
    for r in rows:
        lines.append(
            f"{r.shelf:<22} {r.boxes:>5d} {r.length:>7.2f} {r.free_length:>8.2f} {r.free_area:>8.2f} "
            f"{r.free_volume:>8.2f} {r.occupancy:>6.0%} {r.clear_height:>7.2f} {r.confidence:>5.2f}"
        )
    if not rows:
        lines.append(
            "no racks found: no shelf to measure" if not racks else f"{racks} racks found, but no shelves on them"
        )
    return "\n".join(lines)
