"""`WarehouseMap`: racks -> shelves -> boxes as metric cuboids, with ids, confidences and JSON I/O.

Map frame: the shelf-centric frame of the first frame and slot 0 (DESIGN.md axes): X = metres
along the row from the first camera X, Y down with ``Y = 0`` at the top of slot 0's board (so a
height ``h`` above that board is ``Y = -h``), Z about the rack mid-depth. Boxes use the
generator's cuboid convention: ``center``, ``size = (w, h, d)``, ``yaw`` turning the width axis
to ``(cos yaw, sin yaw)`` in ``(x, z)``. ``origin_world`` (optional) places the map in a world
frame: ``world = map + origin_world``.

Partly seen racks: ``WarehouseMap.seen_x`` holds the X intervals the camera saw (the union of the
frames' visible ranges). A rack whose end lies at (or within ``MergeConfig.partial_margin`` of) an
end of that coverage may go on past it unseen: ``MapRack.partial`` (and each of its shelves'
``MapShelf.partial``) is ``"start"`` (cut at its low-X end), ``"end"`` (high-X end), ``"both"``, or
``None`` for a rack seen whole. A partial rack's ``x_range`` is the part the camera saw.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from typing import Any

from layouts.errors import InputError
from layouts.fileio import atomic_write_json, load_json
from stitching.geometry import Cuboid

MAP_FORMAT = "mvracklay-warehouse-map"
MAP_VERSION = 2  #: 2 added ``seen_x`` and the racks' and shelves' ``partial``
READ_VERSIONS = (1, 2)  #: versions `WarehouseMap.from_dict` reads (a version 1 map reads as all racks whole)
PARTIAL_SIDES = (None, "start", "end", "both")  #: values of ``MapRack.partial`` / ``MapShelf.partial``


def partial_side(cut_start: bool, cut_end: bool) -> str | None:
    """``partial`` for a rack cut at its low-X end (``cut_start``) and/or its high-X end (``cut_end``)."""
    return ("both" if cut_end else "start") if cut_start else ("end" if cut_end else None)


def cut_sides(partial: str | None) -> tuple[bool, bool]:
    """``(cut at the low-X end, cut at the high-X end)`` of a ``partial`` value (inverse of `partial_side`)."""
    return partial in ("start", "both"), partial in ("end", "both")


@dataclass
class MapBox:
    id: str
    center: tuple[float, float, float]
    size: tuple[float, float, float]
    yaw: float
    confidence: float
    observations: int
    colour: tuple[int, int, int] | None = None  #: sRGB 0-255 of its front face in the frames, None = not seen

    @property
    def cuboid(self) -> Cuboid:
        return Cuboid(tuple(self.center), tuple(self.size), self.yaw)


@dataclass
class MapShelf:
    id: str
    slot: int  #: shelf slot, counted from the lowest visible shelf
    board_height: float  #: metres above slot 0's board
    clear_height: float
    x_range: tuple[float, float]
    z_range: tuple[float, float]
    confidence: float
    boxes: list[MapBox] = field(default_factory=list)
    partial: str | None = None  #: the rack's `MapRack.partial` (see the module docstring)

    @property
    def cuboid(self) -> Cuboid:
        """The free space above the board up to the next board (the shelf's volume)."""
        x0, x1 = self.x_range
        z0, z1 = self.z_range
        return Cuboid(
            ((x0 + x1) / 2, -(self.board_height + self.clear_height / 2), (z0 + z1) / 2),
            (x1 - x0, self.clear_height, z1 - z0),
        )


@dataclass
class MapRack:
    id: str
    x_range: tuple[float, float]  #: the seen part when ``partial``
    shelves: list[MapShelf] = field(default_factory=list)
    partial: str | None = None  #: None (seen whole), "start" / "end" (cut at low / high X), "both"


@dataclass
class StepRecord:
    """One frame's registration: offset of its camera X in the map, and how it was found."""

    frame: int
    offset: float  #: camera X of this frame in the map frame
    shift: float  #: offset change since the previous merged frame
    direction: int  #: +1 moving to +X, -1 to -X, 0 still / unknown
    confidence: float
    method: str  #: 'first', 'edges' (box edges and rack ends), 'motion' (the given camera step), 'correlation', 'prediction'
    matches: int
    trusted: bool = True  #: False: no estimate agreed with the camera's recent motion; the offset is a guess


@dataclass
class WarehouseMap:
    racks: list[MapRack]
    steps: list[StepRecord]
    board_thickness: float
    origin_world: tuple[float, float, float] | None = None
    meta: dict[str, Any] = field(default_factory=dict)
    seen_x: list[tuple[float, float]] = field(default_factory=list)  #: X intervals seen; [] = not recorded
    #: upright frames found along the row (`stitching.uprights`): (centre X, support); [] = none marked
    uprights: list[tuple[float, float]] = field(default_factory=list)

    # ----------------------------------------------------------- queries
    def shelves(self) -> list[MapShelf]:
        return [s for r in self.racks for s in r.shelves]

    def boxes(self) -> list[MapBox]:
        return [b for s in self.shelves() for b in s.boxes]

    def box_cuboids(self) -> list[Cuboid]:
        return [b.cuboid for b in self.boxes()]

    def shelf(self, shelf_id: str) -> MapShelf:
        for s in self.shelves():
            if s.id == shelf_id:
                return s
        raise InputError(f"no shelf {shelf_id!r} in the map (have {[s.id for s in self.shelves()][:8]} ...)")

    @property
    def camera_offsets(self) -> list[float]:
        return [s.offset for s in self.steps]

    def scaled(self, factor: float) -> WarehouseMap:
        """The map with every length times ``factor`` about its origin: a map made at a wrong camera distance
        ``d`` corrected to the true ``D`` by ``factor = D / d`` (all lengths scale with the distance)."""
        from dataclasses import replace

        if not (math.isfinite(factor) and factor > 0):
            raise InputError(f"scale factor must be a positive number, got {factor!r}")

        def v(t):
            return tuple(float(x) * factor for x in t)

        racks = [
            replace(
                r,
                x_range=v(r.x_range),
                shelves=[
                    replace(
                        sh,
                        board_height=sh.board_height * factor,
                        clear_height=sh.clear_height * factor,
                        x_range=v(sh.x_range),
                        z_range=v(sh.z_range),
                        boxes=[replace(b, center=v(b.center), size=v(b.size)) for b in sh.boxes],
                    )
                    for sh in r.shelves
                ],
            )
            for r in self.racks
        ]
        steps = [replace(st, offset=st.offset * factor, shift=st.shift * factor) for st in self.steps]
        return replace(
            self,
            racks=racks,
            steps=steps,
            board_thickness=self.board_thickness * factor,
            seen_x=[v(iv) for iv in self.seen_x],
            uprights=[(x * factor, sup) for x, sup in self.uprights],
            meta={**self.meta, "scaled_by": factor},
        )

    # ----------------------------------------------------------- JSON
    def to_dict(self) -> dict[str, Any]:
        """The map as written to ``warehouse.json``, held to its schema first (`stitching.map_schema.check_built`:
        a map that breaks it raises `layouts.errors.ContractError`, so no writer publishes what readers refuse)."""
        from stitching.map_schema import check_built

        def r6(v):
            return [round(float(x), 6) for x in v]

        doc = {
            "format": MAP_FORMAT,
            "version": MAP_VERSION,
            "frame": "X along the row from the first camera X, Y down from slot 0's board top, Z about rack mid-depth (metres)",
            "origin_world": None if self.origin_world is None else r6(self.origin_world),
            "board_thickness": round(self.board_thickness, 6),
            "meta": self.meta,
            "seen_x": [r6(iv) for iv in self.seen_x],
            "steps": [
                {
                    "frame": s.frame,
                    "offset": round(s.offset, 6),
                    "shift": round(s.shift, 6),
                    "direction": s.direction,
                    "confidence": round(s.confidence, 4),
                    "method": s.method,
                    "matches": s.matches,
                    "trusted": s.trusted,
                }
                for s in self.steps
            ],
            "racks": [
                {
                    "id": r.id,
                    "x_range": r6(r.x_range),
                    "partial": r.partial,
                    "shelves": [
                        {
                            "id": s.id,
                            "slot": s.slot,
                            "board_height": round(s.board_height, 6),
                            "clear_height": round(s.clear_height, 6),
                            "x_range": r6(s.x_range),
                            "z_range": r6(s.z_range),
                            "confidence": round(s.confidence, 4),
                            "partial": s.partial,
                            "boxes": [
                                {
                                    "id": b.id,
                                    "center": r6(b.center),
                                    "size": r6(b.size),
                                    "yaw": round(b.yaw, 6),
                                    "confidence": round(b.confidence, 4),
                                    "observations": b.observations,
                                    **({} if b.colour is None else {"colour": [int(c) for c in b.colour]}),
                                }
                                for b in s.boxes
                            ],
                        }
                        for s in r.shelves
                    ],
                }
                for r in self.racks
            ],
        }
        if self.uprights:  # optional: a map without upright marks is written as before
            doc["uprights"] = [r6(u) for u in self.uprights]
        check_built(doc)
        return doc

    @classmethod
    def from_dict(cls, d: Any, source: str = "warehouse map") -> WarehouseMap:
        if not isinstance(d, dict) or d.get("format") != MAP_FORMAT:
            raise InputError(f"{source}: not a warehouse map (format must be {MAP_FORMAT!r})")
        if d.get("version") not in READ_VERSIONS:
            raise InputError(
                f"{source}: warehouse map version {d.get('version')!r} is not supported (reads {list(READ_VERSIONS)})"
            )
        from stitching.map_schema import check_map

        check_map(d, source)  # the declared schema: finite, in range, ids unique, boxes on their shelf
        try:
            racks = []
            for r in d["racks"]:
                shelves = []
                for s in r["shelves"]:
                    boxes = [
                        MapBox(
                            str(b["id"]),
                            _vec(b["center"], 3),
                            _vec(b["size"], 3),
                            float(b["yaw"]),
                            float(b["confidence"]),
                            int(b["observations"]),
                            _colour(b.get("colour")),
                        )
                        for b in s["boxes"]
                    ]
                    shelves.append(
                        MapShelf(
                            str(s["id"]),
                            int(s["slot"]),
                            float(s["board_height"]),
                            float(s["clear_height"]),
                            _vec(s["x_range"], 2),
                            _vec(s["z_range"], 2),
                            float(s["confidence"]),
                            boxes,
                            _partial(s.get("partial", r.get("partial"))),
                        )
                    )
                racks.append(MapRack(str(r["id"]), _vec(r["x_range"], 2), shelves, _partial(r.get("partial"))))
            steps = [
                StepRecord(
                    int(s["frame"]),
                    float(s["offset"]),
                    float(s["shift"]),
                    int(s["direction"]),
                    float(s["confidence"]),
                    str(s["method"]),
                    int(s["matches"]),
                    bool(s.get("trusted", True)),
                )
                for s in d["steps"]
            ]
            origin = d.get("origin_world")
            return cls(
                racks,
                steps,
                float(d["board_thickness"]),
                None if origin is None else _vec(origin, 3),
                dict(d.get("meta") or {}),
                [_vec(iv, 2) for iv in d.get("seen_x") or []],
                [_vec(u, 2) for u in d.get("uprights") or []],
            )
        except (KeyError, TypeError, ValueError) as e:
            raise InputError(f"{source}: malformed warehouse map ({type(e).__name__}: {e})") from None

    def save(self, path: str | os.PathLike) -> None:
        atomic_write_json(path, self.to_dict())

    @classmethod
    def load(cls, path: str | os.PathLike) -> WarehouseMap:
        return cls.from_dict(load_json(path), str(path))


def _partial(v: Any) -> str | None:
    if v not in PARTIAL_SIDES:
        raise ValueError(f"partial must be one of {list(PARTIAL_SIDES)}, got {v!r}")
    return v


def _colour(v: Any) -> tuple[int, int, int] | None:
    """A box's ``colour``: None (absent) or three integers 0-255."""
    if v is None:
        return None
    if not isinstance(v, (list, tuple)) or len(v) != 3 or not all(type(c) is int and 0 <= c <= 255 for c in v):
        raise ValueError(f"colour must be three integers 0-255, got {v!r}")
    return (int(v[0]), int(v[1]), int(v[2]))


def _vec(v: Any, n: int) -> tuple[float, ...]:
    if not isinstance(v, (list, tuple)) or len(v) != n:
        raise ValueError(f"expected {n} numbers, got {v!r}")
    out = tuple(float(x) for x in v)
    if not all(math.isfinite(x) for x in out):
        raise ValueError(f"non-finite value in {v!r}")
    return out


def origin_from_record(first: dict) -> tuple[float, float, float]:
    """World position of a map's origin from a generated sequence's first frame record: (the camera's X, slot 0's
    board top Y, the rack's middle Z), as `WarehouseMap.origin_world` holds it."""
    try:
        cam_x = float(first["camera_position"][0])
        board = float(first["slots"][0]["board_top_y"])
        mid = float(first["rack_mid_z"])
    except (KeyError, IndexError, TypeError) as e:
        raise InputError(f"first frame record lacks camera_position/slots/rack_mid_z ({e})") from None
    return cam_x, board, mid


def camera_in_map(first: dict) -> tuple[tuple[float, float, float], float, float]:
    """The map's world origin (`origin_from_record`) and the camera's height (Y) and depth (Z) in the map frame,
    from a generated sequence's first frame record: where a recording draws the camera path."""
    origin = origin_from_record(first)
    try:
        p0 = first["camera_position"]
        return origin, float(p0[1]) - origin[1], float(p0[2]) - origin[2]
    except (KeyError, IndexError, TypeError) as e:
        raise InputError(f"first frame record lacks camera_position ({e})") from None
