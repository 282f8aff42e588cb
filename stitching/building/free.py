"""Where a box fits across a building: every scanned location with a gap for it, nearest first.

A location fits a ``w x d x h`` box as a row map's shelf does (`stitching.free_space.fits`: clear height, depth,
a gap along X inside the uprights and clear of every box, the neighbouring positions' included, wide enough for
the box and its margin, never in unknown length; on a network-made map (``meta`` ``layouts: net``) also
`stitching.free_space.NETWORK_EDGE_SLACK` clear of each box); only the map's own locations are offered (a fit on a shelf
without a location record is none), and never one no pass saw, nor by default one whose inventory row is
flagged ``recount`` (its boxes are uncertain, so is the gap: ``with_recount`` lists those too, marked, after the
others). Ranked by the
walk from ``near`` (a location code), else in building order: along the aisle within one aisle, else out to
the nearer end of the racks (where the cross aisles are), across, and back in. The box centre's ranges are given
in building X.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

from layouts.errors import InputError
from layouts.locations import NOT_SCANNED
from stitching.building.map import BuildingMap
from stitching.free_space import edge_slack, fits, rack_of, shelf_free_space


@dataclass
class LocationFit:
    location: str
    rotated: bool  #: the box turned 90 degrees (its depth along the aisle)
    along_x: float  #: the box's extent along the aisle in this placement
    centres: list[tuple[float, float]]  #: building X ranges for the box's centre
    free_length: float
    distance: float | None  #: metres walked from ``near`` (`walk`); None without ``near``
    confidence: float
    recount: bool = False  #: its inventory row is flagged ``recount``: count it before putting a box there

    def to_dict(self) -> dict:
        return asdict(self)


def _centre(bmap: BuildingMap, code: str) -> tuple[float, float, int]:
    """Building X of a location's centre, the Z of its aisle's middle, its aisle."""
    face, shelf, loc = bmap.location(code)
    x = face.to_building(shelf.cuboid).center[0]
    fronts = [f.front_z for f in bmap.faces if f.aisle == face.aisle]
    z = sum(fronts) / len(fronts) if len(fronts) == 2 else face.front_z - face.sign * 1.5
    return x, z, loc.aisle


def _ends(bmap: BuildingMap) -> tuple[float, float]:
    """Building X just past the racks' ends, where a walk turns into the next aisle."""
    xs = [v * f.sign for f in bmap.faces for r in f.map.racks for v in r.x_range] or [0.0]
    return min(xs) - 1.0, max(xs) + 1.0


def walk(a: tuple[float, float, int], b: tuple[float, float, int], ends: tuple[float, float]) -> float:
    """Metres walked between two locations' aisle positions (see the module docstring)."""
    if a[2] == b[2]:
        return abs(a[0] - b[0])
    return min(abs(a[0] - e) + abs(b[0] - e) for e in ends) + abs(a[1] - b[1])


def building_fits(
    bmap: BuildingMap,
    w: float,
    d: float,
    h: float,
    margin: float = 0.0,
    near: str | None = None,
    with_recount: bool = False,
    inventory: list[dict] | None = None,
) -> list[LocationFit]:
    """Scanned locations where the box fits, nearest to ``near`` first, those flagged ``recount`` left out or, with
    ``with_recount``, listed after the others (see the module docstring)."""
    rows = bmap.inventory() if inventory is None else inventory  # the caller's rows, when it made them already
    flagged = {r["location"] for r in rows if r.get("recount") == "true"}
    origin = _centre(bmap, near) if near is not None else None
    slack = edge_slack(bmap.meta)
    ends = _ends(bmap)
    found = []
    for face in bmap.faces:
        shelves = {s.id: s for s in face.map.shelves()}
        for f in fits(face.map, w, d, h, margin, slack):
            loc = face.locations.get(f.shelf)
            if loc is None or loc.code != f.shelf or not loc.scanned or (f.shelf in flagged and not with_recount):
                continue
            shelf = shelves[f.shelf]
            fs = shelf_free_space(shelf, rack_of(face.map, shelf))
            centres = [tuple(sorted((face.sign * a + 0.0, face.sign * b + 0.0))) for a, b in f.centres]
            dist = None
            if origin is not None:
                dist = walk(origin, _centre(bmap, f.shelf), ends)
            found.append(
                LocationFit(
                    f.shelf,
                    f.rotated,
                    f.along_x,
                    sorted(centres),
                    fs.free_length,
                    dist,
                    fs.confidence,
                    f.shelf in flagged,
                )
            )
    order = {loc.code: k for k, (_, _, loc) in enumerate(bmap.locations())}
    if origin is not None:
        return sorted(found, key=lambda r: (r.recount, r.distance, order[r.location], r.rotated))
    return sorted(found, key=lambda r: (r.recount, order[r.location], r.rotated))


def format_fits(rows: list[LocationFit], box: str, limit: int = 20) -> str:
    """A plain-text table of the first ``limit`` locations a box fits."""
    if not rows:
        return f"a {box} box fits in no scanned location"
    head = f"{'location':<16} {'turned':>6} {'free_len':>8} {'dist_m':>7} {'conf':>5} {'recount':>7}  centre X (building, m)"
    lines = [head, "-" * len(head)]
    for r in rows[:limit]:
        dist = "-" if r.distance is None else f"{r.distance:.1f}"
        ranges = ", ".join(f"[{a:.2f}, {b:.2f}]" for a, b in r.centres)
        lines.append(
            f"{r.location:<16} {'yes' if r.rotated else 'no':>6} {r.free_length:>8.2f} {dist:>7} {r.confidence:>5.2f} "
            f"{'yes' if r.recount else '-':>7}  {ranges}"
        )
    if len(rows) > limit:
        lines.append(f"... and {len(rows) - limit} more (--json lists all)")
    return "\n".join(lines)


def check_near(bmap: BuildingMap, code: str | None) -> str | None:
    """``code`` if the building has that location (one line naming --near otherwise)."""
    if code is None:
        return None
    try:
        bmap.location(code)
    except InputError:
        raise InputError(
            f"--near {code!r}: no such location in the building map (e.g. {bmap.locations()[0][2].code})"
        ) from None
    return code


def format_inventory(rows: list[dict]) -> str:
    """A plain-text table of inventory rows: per location its boxes (or ``not scanned``), free length,
    occupancy, confidence and whether it was seen only in part."""
    head = f"{'location':<16} {'boxes':>11} {'free_len':>8} {'occup':>6} {'conf':>5} {'partial':>7}"
    lines = [head, "-" * len(head)]
    for r in rows:
        if r["boxes"] == NOT_SCANNED:
            lines.append(f"{r['location']:<16} {NOT_SCANNED:>11}")
            continue
        lines.append(
            f"{r['location']:<16} {r['boxes']:>11} {r['free_length_m']:>8.2f} {r['occupancy']:>6.0%} "
            f"{r['confidence']:>5.2f} {r['partial']:>7}"
        )
    return "\n".join(lines)
