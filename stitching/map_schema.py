"""The declared schema of a warehouse map file (``warehouse.json``), checked before a map is believed.

`check_map` validates the parsed JSON with pydantic and refuses, in one line naming the file and the
field (``racks[0].shelves[1].boxes[2].yaw``), any map whose figures would be printed as answers but
cannot be true:

* every number finite, every length and coordinate within `MAX_METRES` of the map's origin;
* box sizes > 0, clear heights and board thickness >= 0 (a clear height 0: no front view saw it);
* confidences in [0, 1], observations and slots >= 0, yaw in radians within [-2 pi, 2 pi];
* ``x_range`` / ``z_range`` / ``seen_x`` intervals ordered (low <= high);
* rack, shelf and box ids unique in the map;
* each shelf's ``x_range`` within its rack's;
* each box on its shelf: its footprint (`footprint_extent`) overlapping the shelf's X and Z range (a box
  seen at a rack's end may overhang it, one wholly beside it belongs to no shelf), no longer along X than
  the shelf, no deeper along Z than the shelf's depth, no taller than its clear height (where known);
* no box of a shelf covering more than `DUPLICATE_SHARE` of another's footprint (`overlap_share`): the
  same box twice.

Every comparison allows `INSIDE_TOLERANCE` (rounding in the file, a hand edit by a centimetre).
`check_built` holds the maps we write to the same schema: a map that breaks it is a defect
(`layouts.errors.ContractError`), never a file a later command refuses.

Fields not named here are left as they are (a map's ``meta`` is free-form).
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from typing import Annotated, Any

from pydantic import BaseModel, ConfigDict, Field, StrictBool, StrictInt, StrictStr, ValidationError, model_validator

from layouts.errors import ContractError, InputError, first_problem
from stitching.geometry import clip_convex, footprint_corners, polygon_area

#: the largest coordinate or length a map may hold, metres (a warehouse row is far shorter)
MAX_METRES = 1.0e4
#: how far a box may reach past its shelf, or a shelf past its rack, metres (rounding in the file, a hand edit)
INSIDE_TOLERANCE = 0.05
#: two boxes of one shelf overlapping by more than this share of the smaller footprint are the same box twice
DUPLICATE_SHARE = 0.5

Coord = Annotated[float, Field(allow_inf_nan=False, ge=-MAX_METRES, le=MAX_METRES)]
Size = Annotated[float, Field(allow_inf_nan=False, gt=0, le=MAX_METRES)]
NonNeg = Annotated[float, Field(allow_inf_nan=False, ge=0, le=MAX_METRES)]
Unit = Annotated[float, Field(allow_inf_nan=False, ge=0, le=1)]
Yaw = Annotated[float, Field(allow_inf_nan=False, ge=-2 * math.pi, le=2 * math.pi)]
Count = Annotated[StrictInt, Field(ge=0)]
Ident = StrictStr | StrictInt
Partial = Any  #: None, "start", "end" or "both": checked where the map is built (`warehouse_map._partial`)
Footprint = tuple[float, float, float, float, float]  #: ``(cx, cz, w, d, yaw)`` of a box on its shelf


def footprint_extent(cx: float, cz: float, w: float, d: float, yaw: float) -> tuple[float, float, float, float]:
    """``(x0, x1, z0, z1)``: the X and Z extent of a ``w x d`` footprint centred at ``(cx, cz)`` whose width axis
    is turned by ``yaw`` (the cuboid convention of `stitching.geometry`): where a box stands on its shelf, for
    this schema and for the stitcher that builds maps to it (`stitching.merge`)."""
    c, s = abs(math.cos(yaw)), abs(math.sin(yaw))
    hx, hz = (w * c + d * s) / 2, (w * s + d * c) / 2
    return cx - hx, cx + hx, cz - hz, cz + hz


def overlap_share(a: Footprint, b: Footprint) -> float:
    """Area where two footprints ``(cx, cz, w, d, yaw)`` overlap, as a share of the smaller one's (1: one holds
    the other); exact for any yaw (the extents first, the turned rectangles clipped only where needed)."""
    ax0, ax1, az0, az1 = footprint_extent(*a)
    bx0, bx1, bz0, bz1 = footprint_extent(*b)
    ix, iz = min(ax1, bx1) - max(ax0, bx0), min(az1, bz1) - max(az0, bz0)
    small = min(a[2] * a[3], b[2] * b[3])
    if ix <= 0 or iz <= 0 or small <= 0:
        return 0.0
    if a[4] == 0 and b[4] == 0:
        return ix * iz / small
    return polygon_area(clip_convex(footprint_corners(*a), footprint_corners(*b))) / small


def _ordered(v: tuple[float, float], name: str) -> tuple[float, float]:
    if v[0] > v[1]:
        raise ValueError(f"{name} [{v[0]}, {v[1]}] is reversed (low must come first)")
    return v


class _Doc(BaseModel):
    model_config = ConfigDict(extra="allow", allow_inf_nan=False)


class BoxDoc(_Doc):
    id: Ident
    center: tuple[Coord, Coord, Coord]
    size: tuple[Size, Size, Size]
    yaw: Yaw
    confidence: Unit
    observations: Count
    colour: Any = None  #: three integers 0-255, checked where the map is built (`warehouse_map._colour`)

    @property
    def footprint(self) -> Footprint:
        return self.center[0], self.center[2], self.size[0], self.size[2], self.yaw


class ShelfDoc(_Doc):
    id: Ident
    slot: Count
    board_height: Coord
    clear_height: NonNeg
    x_range: tuple[Coord, Coord]
    z_range: tuple[Coord, Coord]
    confidence: Unit
    boxes: list[BoxDoc]
    partial: Partial = None

    @model_validator(mode="after")
    def _order(self) -> ShelfDoc:
        _ordered(self.x_range, "x_range")
        _ordered(self.z_range, "z_range")
        return self


class RackDoc(_Doc):
    id: Ident
    x_range: tuple[Coord, Coord]
    shelves: list[ShelfDoc]
    partial: Partial = None

    @model_validator(mode="after")
    def _order(self) -> RackDoc:
        _ordered(self.x_range, "x_range")
        return self


class StepDoc(_Doc):
    frame: Count
    offset: Coord
    shift: Coord
    direction: Annotated[StrictInt, Field(ge=-1, le=1)]
    confidence: Unit
    method: StrictStr
    matches: Count
    trusted: StrictBool = True


class MapDoc(_Doc):
    board_thickness: NonNeg
    origin_world: tuple[Coord, Coord, Coord] | None = None
    meta: dict[str, Any] | None = None
    seen_x: list[tuple[Coord, Coord]] | None = None
    uprights: list[tuple[Coord, Unit]] | None = None  #: upright frames along the row: (centre X, support)
    steps: list[StepDoc]
    racks: list[RackDoc]

    @model_validator(mode="after")
    def _unique(self) -> MapDoc:
        for iv in self.seen_x or []:
            _ordered(iv, "seen_x interval")
        for kind, ids in (
            ("rack", [r.id for r in self.racks]),
            ("shelf", [s.id for r in self.racks for s in r.shelves]),
            ("box", [b.id for r in self.racks for s in r.shelves for b in s.boxes]),
        ):
            seen: set[str] = set()
            for i in ids:
                if str(i) in seen:
                    raise ValueError(f"{kind} id {i!r} appears more than once")
                seen.add(str(i))
        return self

    @model_validator(mode="after")
    def _standing(self) -> MapDoc:
        said = next(_geometry(self), None)
        if said:
            raise ValueError(said)  # says where: racks[i].shelves[j](.boxes[k])
        return self


def _box_problem(b: BoxDoc, s: ShelfDoc) -> str | None:
    """What keeps box ``b`` from standing on shelf ``s``, or None."""
    tol = INSIDE_TOLERANCE
    (x0, x1), (z0, z1) = s.x_range, s.z_range
    bx0, bx1, bz0, bz1 = footprint_extent(*b.footprint)
    if not (bx0 < x1 + tol and bx1 > x0 - tol and bz0 < z1 + tol and bz1 > z0 - tol):
        return (
            f"box {b.id} (centre x {b.center[0]}, z {b.center[2]}) lies wholly outside its shelf "
            f"(x {list(s.x_range)}, z {list(s.z_range)})"
        )
    for axis, reach, room in (("X", bx1 - bx0, x1 - x0), ("Z", bz1 - bz0, z1 - z0)):
        if reach > room + 2 * tol:
            what = "longer than its shelf" if axis == "X" else "deeper than its shelf"
            return f"box {b.id} reaches {reach:.6g} m along {axis}: {what} ({room:.6g} m)"
    if s.clear_height > 0 and b.size[1] > s.clear_height + tol:
        return f"box {b.id} is {b.size[1]:.6g} m tall: taller than its shelf's clear height ({s.clear_height:.6g} m)"
    return None


def _duplicate(s: ShelfDoc) -> tuple[int, int, float] | None:
    """``(k, j, share)``: the first box ``k`` covering more than `DUPLICATE_SHARE` of an earlier box ``j``."""
    feet = [b.footprint for b in s.boxes]
    spans = [footprint_extent(*f)[:2] for f in feet]
    active: list[int] = []  # boxes whose X extent may still reach the next one's
    for k in sorted(range(len(feet)), key=lambda k: spans[k][0]):
        active = [j for j in active if spans[j][1] > spans[k][0]]
        for j in active:
            share = overlap_share(feet[j], feet[k])
            if share > DUPLICATE_SHARE:
                return max(j, k), min(j, k), share
        active.append(k)
    return None


def _geometry(doc: MapDoc) -> Iterator[str]:
    """Each shelf outside its rack and each box off its shelf or twice on it, as ``where: what``."""
    tol = INSIDE_TOLERANCE
    for i, r in enumerate(doc.racks):
        for j, s in enumerate(r.shelves):
            where = f"racks[{i}].shelves[{j}]"
            if s.x_range[0] < r.x_range[0] - tol or s.x_range[1] > r.x_range[1] + tol:
                yield f"{where}.x_range: shelf {s.id} {list(s.x_range)} lies outside its rack {list(r.x_range)}"
            for k, b in enumerate(s.boxes):
                said = _box_problem(b, s)
                if said:
                    yield f"{where}.boxes[{k}]: {said}"
            dup = _duplicate(s)
            if dup:
                k, m, share = dup
                yield (
                    f"{where}.boxes[{k}]: box {s.boxes[k].id} covers {share:.0%} of box {s.boxes[m].id} "
                    f"(boxes[{m}]): the same box twice"
                )


def _problem(doc: Any) -> str | None:
    """The first way a parsed map breaks the schema, as ``where: what``, or None."""
    try:
        MapDoc.model_validate(doc)
    except ValidationError as e:
        return first_problem(e.errors())
    return None


def check_map(doc: Any, source: str) -> None:
    """Refuse (one `InputError` line naming ``source``) a parsed warehouse map that breaks the schema."""
    said = _problem(doc)
    if said:
        raise InputError(f"{source}: malformed warehouse map: {said}")


def check_built(doc: dict) -> None:
    """Hold a map about to be published (``WarehouseMap.to_dict``) to the schema its readers check: one that breaks
    it is a defect of the code that built it (`ContractError`), raised before anything is written."""
    said = _problem(doc)
    if said:
        raise ContractError(f"warehouse map built here breaks its schema (a defect, nothing written): {said}")
