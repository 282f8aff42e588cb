"""`BuildingMap`: every rack face of a building as a map in its own face frame, placed in the building frame,
with a location code for every slot; JSON I/O (``building.json``) and the inventory (one row per location).

Frames (DESIGN.md, "Buildings and locations"). Building: metres, X along the aisles, Y down (floor 0), Z across.
A face's frame is its row frame: X along the face with the camera's right, Y as the building's, Z into the
rack from the face's front line (0 at the front). For an ``R`` face (racks at the higher Z of their aisle)
building = (x, y, front_z + z); for an ``L`` face building = (-x, y, front_z - z), a half turn about Y (so
yaws are the same in both frames).

A face's map is a `WarehouseMap` in its face frame: each rack one bay (id ``AA-S-BB``), each shelf one location
(id = its code), a level's positions cut along X in equal parts. Codes come from the format in
``BuildingMap.code`` (default `layouts.locations.DEFAULT_CODE`); bays are numbered from 1 along building +X on both sides, by the
racks' positions alone, so a code names the same slot in every scan. A location no pass saw is ``not scanned``
(its inventory row says so), never empty.

A map made with a location list (``location_list``: where it came from) takes its codes, bays and spans from
that list instead (`stitching.building.fuse_passes`), and keeps the boxes outside every listed location aside
(``outside``: face, level, building X and centre, size, passes); `BuildingMap.listed` gives its locations back as
a list, so a later scan keeps its codes.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from typing import Any

from layouts.errors import InputError
from layouts.fileio import atomic_write_json, atomic_write_text, load_json
from layouts.location_list import ListedLocation
from layouts.locations import DEFAULT_CODE, INVENTORY_COLUMNS, NOT_SCANNED, check_code_format, rows_csv
from stitching.building.recount import MAP_INVENTORY_COLUMNS, RECOUNT, recount_cell, shelf_evidence, uncertain_bays
from stitching.building.route import FacePlan, OnFace, plan_dict, plan_face
from stitching.building.schema import check_building, check_inventory
from stitching.free_space import ShelfFreeSpace, rack_of, shelf_free_space
from stitching.geometry import Cuboid
from stitching.warehouse_map import MapShelf, WarehouseMap

BUILDING_FORMAT = "mvracklay-building-map"
BUILDING_VERSION = 1


@dataclass
class Location:
    """What the map knows of one location beyond its shelf: the passes that saw it (route order) and how much."""

    code: str
    aisle: int
    side: str
    bay: int
    level: int
    position: int
    passes: list[str] = field(default_factory=list)
    seen: float = 0.0  #: share of its length some pass's view held (0: not scanned)
    #: boxes counted by each pass that held all of it in view (route order), where two or more did
    counts: dict[str, int] = field(default_factory=dict)

    @property
    def disagree(self) -> bool:
        """Whether the passes that saw all of it counted differently."""
        return len(set(self.counts.values())) > 1

    @property
    def scanned(self) -> bool:
        return bool(self.passes) and self.seen > 0


@dataclass
class FaceMap(OnFace):
    """One rack face: its aisle and side, its front line, its map (face frame) and its locations by code."""

    aisle: int
    side: str
    front_z: float
    map: WarehouseMap
    locations: dict[str, Location] = field(default_factory=dict)
    bays: dict[str, int] = field(default_factory=dict)  #: rack id -> bay number
    #: face X of the bay boundaries found at uprights with little certainty (`stitching.uprights.bay_cuts`)
    uncertain_cuts: tuple[float, ...] = ()

    def to_building(self, c: Cuboid) -> Cuboid:
        """A face-frame cuboid in the building frame (a half turn keeps the yaw)."""
        x, y, z = c.center
        return Cuboid((self.sign * x + 0.0, y, self.front_z + self.sign * z), tuple(c.size), c.yaw)


@dataclass
class PassPlacement:
    """Where a pass's row map went: its face, the face-frame X of its first camera, the correction registration
    added to the route's, and the overlaps it was registered on."""

    name: str
    aisle: int
    side: str
    x0: float  #: face-frame X of the first camera as the route put it
    shift: float = 0.0  #: added by registration (metres along the face)
    levels: list[int] = field(default_factory=list)  #: the level (from 1) of each of its slots
    edges: list[dict[str, Any]] = field(default_factory=list)  #: overlaps: other pass, shift read, matches
    boxes: int = 0
    trusted_steps: float = 1.0  #: share of its frames the row stitcher placed on a confirmed path
    camera_z: float = -2.5  #: face-frame Z of its camera (from the route's start; for drawing its path)
    camera_height: float = 1.5  #: the camera above the floor (the route's, else a guess; for drawing)


@dataclass
class BuildingMap:
    faces: list[FaceMap]
    passes: list[PassPlacement]
    code: str = DEFAULT_CODE
    positions: int = 1
    meta: dict[str, Any] = field(default_factory=dict)
    #: the floor plan (the route's faces, mapped or not): what makes two maps maps of one building; () unknown
    plan: tuple[FacePlan, ...] = ()
    source: str = field(default="building map", compare=False, repr=False)  #: the file it was read from
    location_list: str | None = None  #: the location list its codes came from (None: from the racks found)
    outside: list[dict[str, Any]] = field(default_factory=list)  #: boxes outside every listed location

    def face(self, aisle: int, side: str) -> FaceMap:
        for f in self.faces:
            if f.aisle == aisle and f.side == side:
                return f
        raise InputError(f"no face {aisle:02d}-{side} in the building map")

    def locations(self) -> list[tuple[FaceMap, MapShelf, Location]]:
        """Every location in building order (aisle, side, bay, level, position)."""
        out = []
        for f in self.faces:
            for rack in f.map.racks:
                for s in rack.shelves:
                    out.append((f, s, f.locations[s.id]))
        return sorted(out, key=lambda t: (t[2].aisle, t[2].side, t[2].bay, t[2].level, t[2].position))

    def location(self, code: str) -> tuple[FaceMap, MapShelf, Location]:
        for t in self.locations():
            if t[2].code == code:
                return t
        raise InputError(f"no location {code!r} in the building map")

    def listed(self) -> list[ListedLocation]:
        """Its locations as a location list: codes, places and spans along building X (building order)."""
        out = []
        for f, shelf, loc in self.locations():
            lo, hi = sorted((f.sign * shelf.x_range[0] + 0.0, f.sign * shelf.x_range[1] + 0.0))
            out.append(ListedLocation(loc.code, loc.aisle, loc.side, loc.bay, loc.level, lo, hi, loc.position))
        return out

    def box_count(self) -> int:
        return sum(len(f.map.boxes()) for f in self.faces)

    # ----------------------------------------------------------- inventory
    def inventory(self) -> list[dict[str, Any]]:
        """One row per location (`stitching.building.recount.MAP_INVENTORY_COLUMNS`), building order; ``boxes`` is ``not
        scanned`` where no pass saw the location (its free-space columns empty, confidence 0)."""
        rows = []
        odd = {
            s.id
            for f in self.faces
            for bad in [uncertain_bays(f.map.racks, cuts=[(x, False) for x in f.uncertain_cuts])]
            for r in f.map.racks
            if r.id in bad
            for s in r.shelves
        }
        for f, shelf, loc in self.locations():
            row: dict[str, Any] = {
                "location": loc.code, "aisle": loc.aisle, "side": loc.side, "bay": loc.bay, "level": loc.level,
                "position": loc.position,
            }  # fmt: skip
            if not loc.scanned:
                row.update({k: "" for k in INVENTORY_COLUMNS[6:]})
                row.update({"boxes": NOT_SCANNED, "confidence": 0.0, RECOUNT: ""})
            else:
                fs: ShelfFreeSpace = shelf_free_space(shelf, rack_of(f.map, shelf))
                row.update({
                    "boxes": fs.boxes, "occupancy": round(fs.occupancy, 4), "free_length_m": round(fs.free_length, 4),
                    "free_area_m2": round(fs.free_area, 4), "free_volume_m3": round(fs.free_volume, 4),
                    "partial": "true" if (shelf.partial or loc.seen < 0.999) else "false",
                    "confidence": round(fs.confidence * min(1.0, loc.seen), 4),
                    "last_seen": loc.passes[-1], "pass": ";".join(loc.passes),
                })  # fmt: skip
                said = shelf_evidence(
                    shelf,
                    row["confidence"],
                    row["partial"] == "true",
                    uncertain_boundary=shelf.id in odd,
                    disagree=loc.disagree,
                )
                row[RECOUNT] = recount_cell(said)
            rows.append(row)
        return rows

    # ----------------------------------------------------------- JSON
    def to_dict(self) -> dict[str, Any]:
        return {
            "format": BUILDING_FORMAT,
            "version": BUILDING_VERSION,
            "frame": "building: metres, X along the aisles, Y down (floor 0), Z across; each face's map in its face "
            "frame (X along the face, Z into the rack from its front line): building = (s*x, y, front_z + s*z), "
            "s = +1 for R faces, -1 for L faces",
            "code": self.code,
            "positions": self.positions,
            "meta": self.meta,
            **({"plan": [plan_dict(f) for f in self.plan]} if self.plan else {}),
            **({"location_list": self.location_list, "outside": self.outside} if self.location_list else {}),
            "passes": [
                {
                    "name": p.name,
                    "aisle": p.aisle,
                    "side": p.side,
                    "x0": round(p.x0, 6),
                    "shift": round(p.shift, 6),
                    "levels": p.levels,
                    "edges": p.edges,
                    "boxes": p.boxes,
                    "trusted_steps": round(p.trusted_steps, 4),
                }  # fmt: skip
                for p in self.passes
            ],
            "faces": [
                {
                    "aisle": f.aisle,
                    "side": f.side,
                    "front_z": round(f.front_z, 6),
                    "bays": f.bays,
                    "locations": [
                        {
                            "location": loc.code,
                            "bay": loc.bay,
                            "level": loc.level,
                            "position": loc.position,
                            "passes": loc.passes,
                            "seen": round(loc.seen, 4),
                            **({"counts": loc.counts} if loc.counts else {}),
                        }  # fmt: skip
                        for loc in f.locations.values()
                    ],
                    "map": f.map.to_dict(),
                    **({"uncertain_cuts": [round(x, 6) for x in f.uncertain_cuts]} if f.uncertain_cuts else {}),
                }
                for f in self.faces
            ],
        }

    @classmethod
    def from_dict(cls, d: Any, source: str = "building map") -> BuildingMap:
        if not isinstance(d, dict) or d.get("format") != BUILDING_FORMAT:
            raise InputError(f"{source}: not a building map (format must be {BUILDING_FORMAT!r})")
        if d.get("version") != BUILDING_VERSION:
            raise InputError(f"{source}: building map version {d.get('version')!r} is not supported")
        check_building(d, source)  # the declared schema: finite, in range, unique, each record with its shelf
        try:
            faces = []
            for f in d["faces"]:
                locs = {}
                for loc in f["locations"]:
                    code = str(loc["location"])
                    locs[code] = Location(code, int(f["aisle"]), str(f["side"]), int(loc["bay"]), int(loc["level"]),
                                          int(loc["position"]), [str(p) for p in loc["passes"]], float(loc["seen"]),
                                          {str(k): int(v) for k, v in loc.get("counts", {}).items()})  # fmt: skip
                wmap = WarehouseMap.from_dict(f["map"], f"{source}: face {f['aisle']}-{f['side']}")
                face = FaceMap(int(f["aisle"]), str(f["side"]), _finite(f["front_z"]), wmap, locs,
                               {str(k): int(v) for k, v in f["bays"].items()},
                               tuple(_finite(x) for x in f.get("uncertain_cuts", ())))  # fmt: skip
                if face.side not in ("L", "R"):
                    raise ValueError(f"side must be L or R, got {face.side!r}")
                missing = [s.id for s in wmap.shelves() if s.id not in locs]
                if missing:
                    raise ValueError(f"shelf {missing[0]!r} has no location record")
                faces.append(face)
            passes = [
                PassPlacement(
                    str(p["name"]),
                    int(p["aisle"]),
                    str(p["side"]),
                    _finite(p["x0"]),
                    _finite(p["shift"]),
                    [int(v) for v in p["levels"]],
                    list(p["edges"]),
                    int(p["boxes"]),
                    _finite(p["trusted_steps"]),
                )  # fmt: skip
                for p in d["passes"]
            ]
            positions = int(d["positions"])
            plan = tuple(plan_face(f) for f in d.get("plan") or ())
            listed = d.get("location_list")
            return cls(faces, passes, check_code_format(str(d["code"]), positions), positions,
                       dict(d.get("meta") or {}), plan, source, None if listed is None else str(listed),
                       [dict(b) for b in d.get("outside") or []])  # fmt: skip
        except (KeyError, TypeError, ValueError, AttributeError) as e:
            raise InputError(f"{source}: malformed building map ({type(e).__name__}: {e})") from None

    def save(self, path: str | os.PathLike) -> None:
        """Write ``building.json`` (atomic), held to its schema first (a map that breaks it: `ContractError`)."""
        doc = self.to_dict()
        check_building(doc, str(path), built=True)
        atomic_write_json(path, doc)

    @classmethod
    def load(cls, path: str | os.PathLike) -> BuildingMap:
        return cls.from_dict(load_json(path), str(path))


def _finite(v: Any) -> float:
    out = float(v)
    if not math.isfinite(out):
        raise ValueError(f"non-finite value {v!r}")
    return out


def write_inventory(bmap: BuildingMap, out_dir: str | os.PathLike) -> list[dict[str, Any]]:
    """``inventory.csv`` and ``inventory.json`` (the same rows) in ``out_dir``, atomically; returns the rows."""
    rows = bmap.inventory()
    check_inventory(rows, os.path.join(out_dir, "inventory.csv"), built=True)
    atomic_write_text(os.path.join(out_dir, "inventory.csv"), rows_csv(rows, MAP_INVENTORY_COLUMNS))
    atomic_write_json(
        os.path.join(out_dir, "inventory.json"),
        {"columns": list(MAP_INVENTORY_COLUMNS), "code": bmap.code, "locations": rows}
        | ({"location_list": bmap.location_list, "outside_listed_locations": bmap.outside} if bmap.location_list
           else {}),
    )  # fmt: skip
    return rows


def listed_code_format(positions: int) -> str:
    """The nominal code format of a map whose codes come from a location list (its codes need not follow it)."""
    return DEFAULT_CODE + ("-{position:02d}" if positions > 1 else "")
