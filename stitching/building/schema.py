"""The declared schemas of the building formats: the building map (``building.json``), its inventory rows
(``inventory.csv`` / ``.json``), the changes between two scans (``changes.csv`` / ``.json``) and a generated
building's ground truth (``ground_truth/building.json``, as far as it is read); the route file's is in
`stitching.building.route`.

Each ``check_*`` refuses, in one `InputError` line naming the source and the field path
(``faces[2].front_z``), a document whose figures would be printed as answers but cannot be true:

* every number finite and within range (lengths and coordinates within `map_schema.MAX_METRES`, shares
  in [0, 1], counts >= 0, aisles, bays, levels and positions from 1);
* faces, passes and location codes unique; each location's code the one ``code`` gives its aisle, side, bay,
  level and position (unless the codes came from a location list, ``location_list``); each shelf of a face's
  map with its location record and each record with its shelf;
* each pass on a face of the map, each location's passes among the map's passes;
* the floor plan (``plan``: the route's faces, the building's identity) listing each mapped face at its
  front line;
* a face's map as `stitching.map_schema` declares a row map (ordered intervals, boxes on their shelves, ...).

Each check with ``built=True`` holds what this program is about to write to the same schema: a map it built that
breaks it is a defect (`layouts.errors.ContractError`), raised before anything is written.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Annotated, Any

from pydantic import BaseModel, ConfigDict, Field, StrictInt, StrictStr, ValidationError, model_validator

from layouts.errors import ContractError, InputError, first_problem
from layouts.location_changes import count_change
from layouts.locations import NOT_SCANNED, check_code_format, location_code
from stitching.building.route import Aisle, FacePlan, Level, PlanFace, Side
from stitching.map_schema import Coord, Count, MapDoc, Size, Unit, Yaw

#: metres a mapped face's front line may differ from its floor plan's (rounding in the file)
PLAN_TOLERANCE = 1e-3

Positive = Annotated[StrictInt, Field(ge=1, le=9999)]
Name = Annotated[StrictStr, Field(min_length=1)]


class _Doc(BaseModel):
    model_config = ConfigDict(extra="allow", allow_inf_nan=False)


class LocationDoc(_Doc):
    location: Name
    bay: Positive
    level: Level
    position: Positive
    passes: list[Name]
    seen: Unit  #: the share of its length some pass's view held
    counts: dict[Name, Annotated[StrictInt, Field(ge=0, le=9999)]] | None = None  #: boxes per pass that saw it all


class FaceDoc(_Doc):
    aisle: Aisle
    side: Side
    front_z: Coord
    bays: dict[StrictStr, Positive]  #: rack id -> bay number
    locations: list[LocationDoc]
    map: MapDoc
    uncertain_cuts: list[Coord] | None = None  #: face X of bay boundaries found at uprights with little certainty

    @model_validator(mode="after")
    def _records(self) -> FaceDoc:
        codes = [loc.location for loc in self.locations]
        shelves = [str(s.id) for r in self.map.racks for s in r.shelves]
        lacking = [s for s in shelves if s not in set(codes)]
        if lacking:
            raise ValueError(f"shelf {lacking[0]!r} of the face's map has no location record")
        spare = [c for c in codes if c not in set(shelves)]
        if spare:
            raise ValueError(f"location {spare[0]!r} has no shelf in the face's map")
        racks = [str(r.id) for r in self.map.racks]
        if set(racks) != set(self.bays):
            raise ValueError(f"bays must number the face's racks {racks}, got {sorted(self.bays)}")
        if len(set(self.bays.values())) != len(self.bays):
            raise ValueError(f"bay numbers must be unique, got {sorted(self.bays.values())}")
        for k, loc in enumerate(self.locations):
            if loc.bay not in self.bays.values():
                raise ValueError(f"locations[{k}]: bay {loc.bay} is not among the face's bays")
        return self


class PassDoc(_Doc):
    name: Name
    aisle: Aisle
    side: Side
    x0: Coord
    shift: Coord
    levels: list[Level]
    edges: list[dict[str, Any]]
    boxes: Count
    trusted_steps: Unit


class BuildingDoc(_Doc):
    code: StrictStr
    positions: Annotated[StrictInt, Field(ge=1, le=99)]
    meta: dict[str, Any] | None = None
    passes: list[PassDoc]
    faces: list[FaceDoc]
    plan: list[PlanFace] | None = None  #: the floor plan (maps written before it was kept lack it)
    location_list: StrictStr | None = None  #: where its codes came from (they need not follow ``code``)
    outside: list[dict[str, Any]] | None = None  #: boxes outside every listed location

    @model_validator(mode="after")
    def _whole(self) -> BuildingDoc:
        try:
            check_code_format(self.code, self.positions)
        except InputError as e:
            raise ValueError(f"code: {e}") from None
        faces: dict[tuple[int, str], int] = {}
        for i, f in enumerate(self.faces):
            if (f.aisle, f.side) in faces:
                raise ValueError(f"faces[{i}]: face {_face(f)} is listed twice (faces[{faces[f.aisle, f.side]}])")
            faces[f.aisle, f.side] = i
        names: dict[str, int] = {}
        for i, p in enumerate(self.passes):
            if p.name in names:
                raise ValueError(f"passes[{i}]: pass {p.name!r} is listed twice (passes[{names[p.name]}])")
            names[p.name] = i
            if (p.aisle, p.side) not in faces:
                raise ValueError(f"passes[{i}]: pass {p.name!r} is on face {_face(p)}, which faces does not list")
        codes: dict[str, str] = {}
        for i, f in enumerate(self.faces):
            for k, loc in enumerate(f.locations):
                where = f"faces[{i}].locations[{k}]"
                if loc.location in codes:
                    raise ValueError(f"{where}: location {loc.location!r} is listed twice ({codes[loc.location]})")
                codes[loc.location] = where
                if loc.position > self.positions:
                    raise ValueError(f"{where}.position: {loc.position} exceeds positions ({self.positions})")
                want = location_code(self.code, f.aisle, f.side, loc.bay, loc.level, loc.position)
                if loc.location != want and self.location_list is None:
                    raise ValueError(f"{where}: location {loc.location!r} is not the code of its place ({want!r})")
                unknown = [p for p in loc.passes if p not in names]
                if unknown:
                    raise ValueError(f"{where}.passes: pass {unknown[0]!r} is not among the map's passes")
        if self.plan is not None:
            planned: dict[tuple[int, str], FacePlan] = {}
            for i, pf in enumerate(self.plan):
                if (pf.aisle, pf.side) in planned:
                    raise ValueError(f"plan[{i}]: face {_face(pf)} is listed twice")
                planned[pf.aisle, pf.side] = pf
            for i, f in enumerate(self.faces):
                pf = planned.get((f.aisle, f.side))
                if pf is None:
                    raise ValueError(f"faces[{i}]: face {_face(f)} is not in the floor plan (plan)")
                if abs(pf.front_z - f.front_z) > PLAN_TOLERANCE:
                    raise ValueError(f"faces[{i}].front_z: {f.front_z} differs from the floor plan's {pf.front_z}")
        return self


def _face(f: Any) -> str:
    return f"{f.aisle:02d}-{f.side}"


def _doc_problem(model: type[BaseModel], doc: Any) -> str | None:
    try:
        model.model_validate(doc)
    except ValidationError as e:
        return first_problem(e.errors())
    return None


def _refuse(said: str | None, source: str, what: str, built: bool) -> None:
    """One line naming ``source`` and the element: bad input (`InputError`), or with ``built`` (a file this
    program is about to write) a defect (`ContractError`), raised before anything is written."""
    if said and built:
        raise ContractError(f"{source}: {what} built here breaks its schema (a defect, nothing written): {said}")
    if said:
        raise InputError(f"{source}: malformed {what}: {said}")


def check_building(doc: Any, source: str, built: bool = False) -> None:
    """Refuse a parsed building map that breaks `BuildingDoc` (`_refuse`)."""
    _refuse(_doc_problem(BuildingDoc, doc), source, "building map", built)


# ----------------------------------------------------------------------------------------- rows
Cell = StrictStr | StrictInt | float  #: a CSV cell as read (text) or as written (a number)


def _number(v: Any, lo: float = 0.0, hi: float = math.inf, whole: bool = False) -> float:
    try:
        x = float(v)
    except (TypeError, ValueError):
        raise ValueError(f"a number, got {v!r}") from None
    if not (math.isfinite(x) and lo <= x <= hi) or (whole and x != int(x)):
        kind = "a whole number" if whole else "a number"
        raise ValueError(f"{kind} in [{lo:g}, {hi:g}], got {v!r}")
    return x


class InventoryRow(_Doc):
    """One location's inventory row; ``boxes`` a count or ``not scanned`` (then its free space empty)."""

    location: Name
    aisle: Cell
    side: Side
    bay: Cell
    level: Cell
    position: Cell
    boxes: Cell
    occupancy: Cell
    free_length_m: Cell
    free_area_m2: Cell
    free_volume_m3: Cell
    partial: Cell
    confidence: Cell
    last_seen: Cell
    pass_: Cell = Field(alias="pass")
    recount: StrictStr | None = None  #: a map's rows: ``true`` / ``false``, empty where not scanned (truth: none)

    @model_validator(mode="after")
    def _values(self) -> InventoryRow:
        for k in ("aisle", "bay", "level", "position"):
            _named(k, _number, getattr(self, k), 1, 9999, True)
        _named("confidence", _number, self.confidence, 0, 1)
        if self.boxes == NOT_SCANNED:
            if self.recount:
                raise ValueError(f"recount: empty where the location was not scanned, got {self.recount!r}")
            return self
        if self.recount is not None and self.recount not in ("true", "false"):
            raise ValueError(f"recount: true or false, got {self.recount!r}")
        _named("boxes", _number, self.boxes, 0, 1e6, True)
        _named("occupancy", _number, self.occupancy, 0, 1)
        for k in ("free_length_m", "free_area_m2", "free_volume_m3"):
            _named(k, _number, getattr(self, k), 0, 1e8)
        if str(self.partial) not in ("true", "false"):
            raise ValueError(f"partial: true or false, got {self.partial!r}")
        return self


class ChangeRow(_Doc):
    """One change of ``changes.csv``: what happened at a location (a move: from ``other_location``)."""

    location: Name
    change: StrictStr = Field(pattern="^(added|removed|moved|shifted)$")
    other_location: StrictStr = ""
    confidence: Cell = 1.0

    @model_validator(mode="after")
    def _values(self) -> ChangeRow:
        _named("confidence", _number, self.confidence, 0, 1)
        if self.change == "moved" and not self.other_location:
            raise ValueError("other_location: a move names the location the box came from")
        return self


def _named(key: str, check: Callable[..., Any], *args: Any) -> Any:
    try:
        return check(*args)
    except ValueError as e:
        raise ValueError(f"{key}: {e}") from None


def _rows_problem(rows: list[dict[str, Any]], row: type[BaseModel]) -> str | None:
    """The first row (from 1) that breaks ``row``'s schema, or names a location an earlier row named."""
    seen: dict[str, int] = {}
    for k, r in enumerate(rows, start=1):
        said = _doc_problem(row, r)
        if said:
            return f"row {k}: {said}"
        if row is InventoryRow and r["location"] in seen:
            return f"row {k}: location {r['location']!r} is listed twice (row {seen[r['location']]})"
        seen.setdefault(str(r["location"]), k)
    return None


def check_inventory(rows: list[dict[str, Any]], source: str, built: bool = False) -> None:
    """Refuse inventory rows (read from CSV or about to be written) that break `InventoryRow` (`_refuse`)."""
    _refuse(_rows_problem(rows, InventoryRow), source, "inventory", built)


def check_change_rows(rows: list[dict[str, Any]], source: str, built: bool = False) -> None:
    """Refuse changes rows (``changes.csv``: ours, or a generated rescan's ground truth) that break `ChangeRow`."""
    _refuse(_rows_problem(rows, ChangeRow), source, "changes", built)


class LocationChangeDoc(_Doc):
    location: Name
    status: StrictStr = Field(pattern=f"^(changed|unchanged|new|{NOT_SCANNED})$")
    added: Count
    removed: Count
    moved_in: Count
    moved_out: Count
    shifted: Count
    free_length_change_m: Annotated[float, Field(allow_inf_nan=False, ge=-1e4, le=1e4)] | None
    before: Count | None = None  #: box stacks in the old scan (None: not scanned there)
    after: Count | None = None
    change: StrictStr = Field("", pattern="^(|emptied|filled|count changed|unchanged)$")
    confidence: Unit = 0.0
    recount: bool = False

    @model_validator(mode="after")
    def _counts(self) -> LocationChangeDoc:
        if self.change and (self.before is None or self.after is None):
            raise ValueError(f"change: {self.change!r} needs both counts (before, after)")
        if self.change and count_change(self.before, self.after) != self.change:
            raise ValueError(f"change: {self.change!r} is not the change from {self.before} to {self.after}")
        return self


class ChangesDoc(_Doc):
    """``changes.json``: the rows, the counts per category and each location's summary."""

    columns: list[StrictStr]
    changes: list[ChangeRow]
    counts: dict[StrictStr, Count]
    locations: list[LocationChangeDoc]

    @model_validator(mode="after")
    def _whole(self) -> ChangesDoc:
        for cat in ("added", "removed", "moved", "shifted"):
            n = sum(1 for r in self.changes if r.change == cat)
            if self.counts.get(cat) != n:
                raise ValueError(f"counts.{cat}: {self.counts.get(cat)!r}, but the changes hold {n}")
        codes = [loc.location for loc in self.locations]
        if len(set(codes)) != len(codes):
            raise ValueError("locations: a location is listed twice")
        return self


def check_changes(doc: Any, source: str, built: bool = False) -> None:
    """Refuse a parsed ``changes.json`` that breaks `ChangesDoc` (`_refuse`)."""
    _refuse(_doc_problem(ChangesDoc, doc), source, "changes", built)


# ----------------------------------------------------------------------------------------- ground truth
class TruthBox(_Doc):
    center: tuple[Coord, Coord, Coord]
    size: tuple[Size, Size, Size]
    yaw: Yaw
    stack: Count


class TruthPosition(_Doc):
    location: Name
    boxes: list[TruthBox]


class TruthLevel(_Doc):
    level: Level
    positions: list[TruthPosition]


class TruthRack(_Doc):
    aisle: Aisle
    side: Side
    levels: list[TruthLevel]


class TruthDoc(_Doc):
    """A generated building's ``ground_truth/building.json``: racks -> levels -> positions -> boxes."""

    racks: list[TruthRack]

    @model_validator(mode="after")
    def _unique(self) -> TruthDoc:
        seen: set[str] = set()
        for i, r in enumerate(self.racks):
            for j, lv in enumerate(r.levels):
                for k, pos in enumerate(lv.positions):
                    if pos.location in seen:
                        raise ValueError(
                            f"racks[{i}].levels[{j}].positions[{k}]: location {pos.location!r} is listed twice"
                        )
                    seen.add(pos.location)
        return self


def check_truth(doc: Any, source: str) -> None:
    """Refuse a parsed ground-truth ``building.json`` that breaks `TruthDoc` (`_refuse`)."""
    _refuse(_doc_problem(TruthDoc, doc), source, "ground truth", False)
