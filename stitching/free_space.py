"""Free space per shelf, and where a box of a given size fits.

A shelf's *clear span* is the part of its X range a box can stand on: a rack's ``x_range`` runs from the
outer face of its first upright to that of its last, so each end of the shelf that is an end of its rack
moves in by `UPRIGHT_INSET` (the upright's width, `UPRIGHT_WIDTH`, and the clearance a box keeps from it,
`UPRIGHT_CLEARANCE`, as the ground truth's usable board does); an end where a partial rack is cut stays where
the view ended, and a position's end inside a level (a building's locations) is no upright. Per shelf:

* ``length``: the clear span's length; ``gaps``: the X intervals of it under no box (a box anywhere in the
  depth blocks that X; boxes of the neighbouring positions of the same level, standing over the boundary,
  count too), ``free_length`` their total;
* ``occupancy``: the share of the (known) clear length under a box, a length share as in the ground truth;
* ``free_area`` / ``free_volume``: the clear span's area (x clear height) minus the boxes' footprints
  (volumes), clipped to it;
* ``confidence``: the shelf's confidence times the mean confidence of its boxes (1 if none).

A partial shelf (``MapShelf.partial``: its rack runs on past the X range the camera saw) has the gap running
to each cut end ``unknown``, not free: a box there may have been seen only in part, and what lies past the cut
was never seen. ``free_length``, ``free_area``, ``free_volume`` and ``occupancy`` cover the rest (``unknown_length``
is left out), the confidence is scaled by `PARTIAL_CONFIDENCE` per cut end, and `fits` never places a box in
unknown length.

`fits(w, d, h)` lists, per shelf, the gaps where a ``w x d x h`` box stands: ``h`` must be at most the clear
height minus ``margin``, the box may turn 90 degrees (``w`` along X or ``d`` along X), its depth must fit the
shelf depth, and the gap must be at least its X size plus ``2 * margin``, so the box and its margin stand clear
of the uprights and of every box. Each returned interval is the range of X positions for the box's *centre*.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field

from layouts.errors import InputError
from stitching.geometry import clip_convex, polygon_area
from stitching.warehouse_map import MapBox, MapRack, MapShelf, WarehouseMap, cut_sides

UPRIGHT_WIDTH = (
    0.08  #: metres along X of an upright's section (a typical pallet-rack upright; the map does not measure it)
)
UPRIGHT_CLEARANCE = 0.03  #: metres a box keeps from an upright (the beams' connectors), as the ground truth's board
UPRIGHT_INSET = UPRIGHT_WIDTH + UPRIGHT_CLEARANCE  #: metres from a rack's end to where a box can stand
#: metres a box edge the network read may lie from the map's (its boxes' edges move by a median 3.5 cm between
#: two scans): `fits` keeps this much more clear of each box of a network-made map
NETWORK_EDGE_SLACK = 0.05
PARTIAL_CONFIDENCE = 0.7  #: free-space confidence factor per cut end of a partial shelf
#: the legend line `format_table` prints under a table with partial shelves
PARTIAL_LEGEND = (
    "partial: rack cut at its start (low X) / end (high X) by the first or last view; length is the seen part "
    "and the gap running to a cut end is unknown, not free"
)


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
    gaps: list[tuple[float, float]]  #: free X intervals (never the unknown ones)
    partial: str | None = None  #: the shelf's `MapShelf.partial`: None (seen whole), "start", "end", "both"
    unknown_length: float = 0.0  #: seen length whose free space is unknown (the gaps running to cut ends)
    unknown: list[tuple[float, float]] = field(default_factory=list)  #: those X intervals

    def to_dict(self) -> dict:
        d = asdict(self)
        for k, v in d.items():
            if isinstance(v, float):
                d[k] = round(v, 4)
        d["gaps"] = [[round(a, 4), round(b, 4)] for a, b in self.gaps]
        d["unknown"] = [[round(a, 4), round(b, 4)] for a, b in self.unknown]
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


def clear_span(shelf: MapShelf, rack: MapRack | None = None) -> tuple[float, float]:
    """The X range of ``shelf`` a box can stand on (see the module docstring); ``rack``: the shelf's rack (default:
    the shelf spans its rack, as in a row map)."""
    lo, hi = shelf.x_range
    r0, r1 = rack.x_range if rack is not None else shelf.x_range
    cut_lo, cut_hi = cut_sides(shelf.partial)
    if abs(lo - r0) < 1e-6 and not cut_lo:
        lo += UPRIGHT_INSET
    if abs(hi - r1) < 1e-6 and not cut_hi:
        hi -= UPRIGHT_INSET
    return (lo, hi) if hi > lo else ((lo + hi) / 2, (lo + hi) / 2)


def _level_boxes(shelf: MapShelf, rack: MapRack | None) -> list[MapBox]:
    """The boxes standing on ``shelf``'s level: its own, and its rack's other shelves' on the same slot."""
    others = [b for s in (rack.shelves if rack is not None else []) if s is not shelf and s.slot == shelf.slot
              for b in s.boxes]  # fmt: skip
    return list(shelf.boxes) + others


def _gaps(span: tuple[float, float], boxes: list[MapBox], slack: float = 0.0) -> list[tuple[float, float]]:
    lo, hi = span
    spans = sorted((a - slack, b + slack) for a, b in (b.cuboid.x_range() for b in boxes))
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


def _split_gaps(
    shelf: MapShelf, rack: MapRack | None = None, slack: float = 0.0
) -> tuple[list[tuple[float, float]], list[tuple[float, float]]]:
    """``(free gaps, unknown gaps)`` of the clear span: a partial shelf's gaps running to a cut end are unknown."""
    lo, hi = span = clear_span(shelf, rack)
    cut_lo, cut_hi = cut_sides(shelf.partial)
    free, unknown = [], []
    for a, b in _gaps(span, _level_boxes(shelf, rack), slack):
        (unknown if (cut_lo and a <= lo + 1e-9) or (cut_hi and b >= hi - 1e-9) else free).append((a, b))
    return free, unknown


def rack_of(wmap: WarehouseMap, shelf: MapShelf) -> MapRack | None:
    """The rack holding ``shelf`` (None when no rack of ``wmap`` does)."""
    return next((r for r in wmap.racks if any(s is shelf for s in r.shelves)), None)


def shelf_free_space(shelf: MapShelf, rack: MapRack | None = None) -> ShelfFreeSpace:
    """Free length, area, volume and occupancy of one shelf's clear span (of its known part when partial);
    ``rack``: the shelf's rack (default: the shelf spans its rack, as in a row map)."""
    x0, x1 = clear_span(shelf, rack)
    z0, z1 = shelf.z_range
    length, depth = max(x1 - x0, 0.0), max(z1 - z0, 0.0)
    gaps, unknown = _split_gaps(shelf, rack)
    unknown_length = sum((b - a for a, b in unknown), 0.0)
    free_length = sum((b - a for a, b in gaps), 0.0)
    known = length - unknown_length
    area = known * depth  # the known part: boxes never reach into unknown gaps
    rect = [(x0, z0), (x1, z0), (x1, z1), (x0, z1)]
    occ_area = occ_vol = 0.0
    for b in _level_boxes(shelf, rack):
        a = polygon_area(clip_convex(b.cuboid.footprint(), rect)) if area > 0 else 0.0
        occ_area += a
        occ_vol += a * min(b.size[1], shelf.clear_height)
    confs = [b.confidence for b in shelf.boxes]
    conf = shelf.confidence * (sum(confs) / len(confs) if confs else 1.0)
    conf *= PARTIAL_CONFIDENCE ** sum(cut_sides(shelf.partial))
    return ShelfFreeSpace(
        shelf=shelf.id,
        length=length,
        depth=depth,
        clear_height=shelf.clear_height,
        free_length=free_length,
        free_area=max(area - occ_area, 0.0),
        free_volume=max(area * shelf.clear_height - occ_vol, 0.0),
        occupancy=min(max(known - free_length, 0.0) / known, 1.0) if known > 1e-9 else 0.0,
        boxes=len(shelf.boxes),
        confidence=conf,
        gaps=gaps,
        partial=shelf.partial,
        unknown_length=unknown_length,
        unknown=unknown,
    )


def free_space(wmap: WarehouseMap) -> list[ShelfFreeSpace]:
    """Free space of every shelf of the map, in rack/shelf order."""
    return [shelf_free_space(s, r) for r in wmap.racks for s in r.shelves]


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


def edge_slack(meta: dict) -> float:
    """`NETWORK_EDGE_SLACK` for a map whose boxes the network read (a row map's ``meta`` names its checkpoint, a
    building map's says ``layouts: net``), else 0 (boxes from ground-truth layouts)."""
    return NETWORK_EDGE_SLACK if meta.get("checkpoint") or meta.get("layouts") == "net" else 0.0


def fits(
    wmap: WarehouseMap, w: float, d: float, h: float, margin: float = 0.0, slack: float | None = None
) -> list[Fit]:
    """Shelves and box-centre X ranges where a ``w x d x h`` box fits (see the module docstring); ``slack``: metres
    kept clear of each box beyond ``margin`` (default `edge_slack` of the map's meta)."""
    slack = edge_slack(wmap.meta) if slack is None else slack
    for name, v in (("w", w), ("d", d), ("h", h), ("margin", margin), ("slack", slack)):
        if not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0:
            raise InputError(f"fits: {name} must be a finite number >= 0, got {v!r}")
    out: list[Fit] = []
    for rack, shelf in ((r, s) for r in wmap.racks for s in r.shelves):
        if h > shelf.clear_height - margin:
            continue
        depth = shelf.z_range[1] - shelf.z_range[0]
        gaps = _split_gaps(shelf, rack, slack)[0]  # inside the uprights, clear of boxes, never in unknown length
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
    count, which tells "no racks found" from racks without shelves). Partial shelves show their cut end(s) in
    the ``partial`` column and their unknown length in ``unknown``, and a legend line follows the table."""
    head = (
        f"{'shelf':<22} {'boxes':>5} {'length':>7} {'free_len':>8} {'unknown':>7} {'free_m2':>8} {'free_m3':>8} "
        f"{'occup':>6} {'clear_h':>7} {'conf':>5} {'partial':<7}"
    )
    lines = [head, "-" * len(head)]
    for r in rows:
        lines.append(
            f"{r.shelf:<22} {r.boxes:>5d} {r.length:>7.2f} {r.free_length:>8.2f} {r.unknown_length:>7.2f} "
            f"{r.free_area:>8.2f} {r.free_volume:>8.2f} {r.occupancy:>6.0%} {r.clear_height:>7.2f} "
            f"{r.confidence:>5.2f} {r.partial or '-':<7}".rstrip()
        )
    if not rows:
        lines.append(
            "no racks found: no shelf to measure" if not racks else f"{racks} racks found, but no shelves on them"
        )
    if any(r.partial for r in rows):
        lines.append(PARTIAL_LEGEND)
    return "\n".join(lines)


#: the CSV columns of a shelf's free space (`ShelfFreeSpace.to_dict`)
CSV_COLUMNS = ("shelf", "boxes", "length", "depth", "clear_height", "free_length", "free_area", "free_volume")
CSV_COLUMNS += ("occupancy", "confidence", "partial", "unknown_length")
#: the CSV columns a box query adds: fits (yes/no), the box centre's X ranges (A..B, space-separated) as given and
#: turned
CSV_FIT_COLUMNS = ("fits", "fit_centre_x", "fit_centre_x_turned")


def _ranges(found: list[Fit]) -> str:
    return " ".join(f"{a:.4f}..{b:.4f}" for f in found for a, b in f.centres)


def free_space_csv(rows: list[ShelfFreeSpace], placements: list[Fit] | None = None) -> str:
    """One CSV line per shelf (`CSV_COLUMNS`); with ``placements`` (a box query's `fits`) the `CSV_FIT_COLUMNS`."""
    import csv
    import io

    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(CSV_COLUMNS + (CSV_FIT_COLUMNS if placements is not None else ()))
    for r in rows:
        d = r.to_dict()
        row = ["" if d[c] is None else d[c] for c in CSV_COLUMNS]
        if placements is not None:
            mine = [f for f in placements if f.shelf == r.shelf]
            row += ["yes" if mine else "no"]
            row += [_ranges([f for f in mine if not f.rotated]), _ranges([f for f in mine if f.rotated])]
        writer.writerow(row)
    return out.getvalue()
