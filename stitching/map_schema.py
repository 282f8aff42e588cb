"""The declared schema of a warehouse map file (``warehouse.json``), checked before a map is believed.

`check_map` validates the parsed JSON with pydantic and refuses, in one line naming the file and the
field (``racks[0].shelves[1].boxes[2].yaw``), any map whose figures would be printed as answers but
cannot be true:

* every number finite, every length and coordinate within `MAX_METRES` of the map's origin;
* box sizes > 0, clear heights and board thickness >= 0 (a clear height 0: no front view saw it);
* confidences in [0, 1], observations and slots >= 0, yaw in radians within [-2 pi, 2 pi];
* ``x_range`` / ``z_range`` / ``seen_x`` intervals ordered (low <= high);
* rack, shelf and box ids unique in the map;
* each box's footprint on its shelf: overlapping the shelf's X and Z range (`INSIDE_TOLERANCE` either side;
  a box seen at a rack's end may overhang it, one wholly beside it belongs to no shelf).

Fields not named here are left as they are (a map's ``meta`` is free-form).
"""

from __future__ import annotations

import math
from typing import Annotated, Any

from pydantic import BaseModel, ConfigDict, Field, StrictBool, StrictInt, StrictStr, ValidationError, model_validator

from layouts.errors import InputError, first_problem

#: the largest coordinate or length a map may hold, metres (a warehouse row is far shorter)
MAX_METRES = 1.0e4
#: how far beside its shelf's X / Z range a box's footprint may lie, metres (rounding in the file)
INSIDE_TOLERANCE = 0.05

Coord = Annotated[float, Field(allow_inf_nan=False, ge=-MAX_METRES, le=MAX_METRES)]
Size = Annotated[float, Field(allow_inf_nan=False, gt=0, le=MAX_METRES)]
NonNeg = Annotated[float, Field(allow_inf_nan=False, ge=0, le=MAX_METRES)]
Unit = Annotated[float, Field(allow_inf_nan=False, ge=0, le=1)]
Yaw = Annotated[float, Field(allow_inf_nan=False, ge=-2 * math.pi, le=2 * math.pi)]
Count = Annotated[StrictInt, Field(ge=0)]
Ident = StrictStr | StrictInt
Partial = Any  #: None, "start", "end" or "both": checked where the map is built (`warehouse_map._partial`)


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
    def _inside(self) -> ShelfDoc:
        _ordered(self.x_range, "x_range")
        _ordered(self.z_range, "z_range")
        (x0, x1), (z0, z1), tol = self.x_range, self.z_range, INSIDE_TOLERANCE
        for b in self.boxes:
            x, _, z = b.center
            c, s = abs(math.cos(b.yaw)), abs(math.sin(b.yaw))
            hx = (b.size[0] * c + b.size[2] * s) / 2  # half the footprint's extent along X and Z
            hz = (b.size[0] * s + b.size[2] * c) / 2
            if not (x - hx < x1 + tol and x + hx > x0 - tol and z - hz < z1 + tol and z + hz > z0 - tol):
                raise ValueError(
                    f"box {b.id} (centre x {x}, z {z}) lies wholly outside its shelf (x {list(self.x_range)}, "
                    f"z {list(self.z_range)})"
                )
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


def check_map(doc: Any, source: str) -> None:
    """Refuse (one `InputError` line naming ``source``) a parsed warehouse map that breaks the schema."""
    try:
        MapDoc.model_validate(doc)
    except ValidationError as e:
        raise InputError(f"{source}: malformed warehouse map: {first_problem(e.errors())}") from None
