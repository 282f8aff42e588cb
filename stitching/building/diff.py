"""What changed between two scans of a building: per location first its count before and after (emptied, filled,
count changed: `layouts.location_changes`) with a confidence and ``recount`` where either scan's row is uncertain;
then the boxes added, removed, moved (from -> to) and shifted along their level, and the change of free space.

Both maps are `BuildingMap`s of the same building (any route poses, camera distances or passes; two maps whose
location codes or floor plans differ are refused, `building_difference`): their boxes
are compared in the building frame, per face and level, in four rounds (`DiffConfig`):

1. **the same box**: an old and a new box (of similar size) whose centres lie within ``same`` along the
   level, one to one, nearest first; nothing changed;
2. **shifted**: of the rest, an old and a new box of similar size in the same location, one to one, nearest
   first;
3. **moved**: of the rest, building-wide, an old and a new box of the same size (within ``move_tol``) and
   colour (where both scans saw it) in different locations, one to one by size (Hungarian); a move needs both
   ends confident (neither location's row flagged ``recount``), else it is a removal and an addition;
4. **removed** / **added**: what is left of the old / the new scan.

Where one scan did not see a box's place (its location not scanned by the other scan), the box is not
compared: its location is ``not scanned`` (never ``removed``). A change's confidence is the product of the
boxes' confidences and the shares of their locations each scan saw. The tolerances (`DiffConfig.for_maps`)
are wider between maps made from the network's layouts.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.optimize import linear_sum_assignment

from layouts.errors import InputError
from layouts.location_changes import UNCHANGED, count_change
from layouts.locations import NOT_SCANNED
from stitching.building.map import BuildingMap, FaceMap, Location
from stitching.building.route import FacePlan
from stitching.free_space import shelf_free_space
from stitching.warehouse_map import MapBox, MapShelf

CHANGES = ("added", "removed", "moved", "shifted")
#: how far two scans' floor plans may differ and still be one building's (metres): a face's front line, its
#: ends along X, each board's height (a plan measured again by hand)
SAME_FRONT, SAME_END, SAME_LEVEL = 0.25, 0.5, 0.15
#: ``location_changes.csv``: one row per location, its count before and after and its category
LOCATION_COLUMNS = ("location", "status", "before", "after", "change", "confidence", "recount")
CHANGE_COLUMNS = (
    "location", "change", "other_location", "boxes", "size", "box_ids", "old_box_ids", "x", "old_x", "note",
    "confidence",
)  # fmt: skip


@dataclass(frozen=True)
class DiffConfig:
    same: float = 0.08  #: metres along the level within which an old and a new box are the same box
    size_tol: float = 0.06  #: metres each of width, height, depth may differ for two boxes to be one in place
    move_tol: float = 0.015  #: the same for a box found elsewhere (a move: stricter, as any box may match)
    colour_tol: float = 40.0  #: RGB distance two boxes' colours may differ by to be one, where both maps saw them
    min_shift: float = 0.08  #: metres a box must move along its level to count as shifted

    @classmethod
    def for_maps(cls, old: BuildingMap, new: BuildingMap) -> DiffConfig:
        """The tolerances for these maps: wider where either was made from the network's layouts, whose boxes
        move by a few centimetres and change size by up to ten between two scans of the same stack."""
        if "net" in (old.meta.get("layouts"), new.meta.get("layouts")):
            return cls.network_made()
        return cls()

    @classmethod
    def network_made(cls) -> DiffConfig:
        """The tolerances between maps made from the network's layouts (`for_maps`)."""
        return cls(same=0.15, size_tol=0.15, move_tol=0.05, min_shift=0.15)


@dataclass
class _Box:
    code: str
    key: tuple[int, str, int]  #: (aisle, side, level)
    x: float  #: building X of its centre
    box: MapBox
    weight: float  #: its confidence times its location's seen share


@dataclass
class Change:
    location: str
    change: str  #: added | removed | moved | shifted
    other_location: str = ""  #: a move's old location
    size: tuple[float, float, float] = (0.0, 0.0, 0.0)  #: width x height x depth of the (new, else old) box
    box_ids: list[str] = field(default_factory=list)  #: in the new map
    old_box_ids: list[str] = field(default_factory=list)  #: in the old map
    x: float | None = None  #: building X of the new box
    old_x: float | None = None
    confidence: float = 1.0

    def row(self) -> dict[str, Any]:
        return {
            "location": self.location, "change": self.change, "other_location": self.other_location, "boxes": 1,
            "size": "x".join(f"{v:.3f}" for v in self.size), "box_ids": ";".join(self.box_ids),
            "old_box_ids": ";".join(self.old_box_ids), "x": "" if self.x is None else round(self.x, 4),
            "old_x": "" if self.old_x is None else round(self.old_x, 4), "note": "",
            "confidence": round(self.confidence, 4),
        }  # fmt: skip


@dataclass
class LocationChange:
    """One location's summary: its count before and after and their category (`layouts.location_changes`), with
    the lower of the two rows' confidences and ``recount`` where either row is flagged; counts of each box change,
    the free length's change; or ``not scanned``."""

    location: str
    status: str  #: "changed", "unchanged", "not scanned" (the new scan did not see it), "new" (only in the new)
    before: int | None = None  #: box stacks in the old scan (None: not scanned there)
    after: int | None = None
    change: str = ""  #: emptied | filled | count changed | unchanged ("" where either scan did not see it)
    confidence: float = 0.0
    recount: bool = False
    added: int = 0
    removed: int = 0
    moved_in: int = 0
    moved_out: int = 0
    shifted: int = 0
    free_length_change_m: float | None = None


@dataclass
class BuildingDiff:
    changes: list[Change]
    locations: list[LocationChange]

    def rows(self) -> list[dict[str, Any]]:
        return [c.row() for c in self.changes]

    def counts(self) -> dict[str, int]:
        return {k: sum(1 for c in self.changes if c.change == k) for k in CHANGES}

    def location_rows(self) -> list[dict[str, Any]]:
        """``location_changes.csv``'s rows (`LOCATION_COLUMNS`), one per location."""
        return [{"location": c.location, "status": c.status, "before": "" if c.before is None else c.before,
                 "after": "" if c.after is None else c.after, "change": c.change, "confidence": round(c.confidence, 4),
                 "recount": "true" if c.recount else "false"} for c in self.locations]  # fmt: skip


def _faces(keys: Any) -> str:
    return ", ".join(f"{a:02d}-{s}" for a, s in sorted(keys)) or "none"


def _plan_difference(a: FacePlan, b: FacePlan) -> str | None:
    name = f"face {a.aisle:02d}-{a.side}"
    if abs(a.front_z - b.front_z) > SAME_FRONT:
        return f"{name}'s front line lies at z {a.front_z:g} in the old map, {b.front_z:g} in the new"
    for end in ("x_min", "x_max"):
        u, v = getattr(a, end), getattr(b, end)
        if u is not None and v is not None and abs(u - v) > SAME_END:
            return f"{name}'s {end} is {u:g} in the old map, {v:g} in the new"
    if a.levels_m and b.levels_m:
        if len(a.levels_m) != len(b.levels_m):
            return f"{name} has {len(a.levels_m)} levels in the old map, {len(b.levels_m)} in the new"
        for k, (u, v) in enumerate(zip(a.levels_m, b.levels_m), start=1):
            if abs(u - v) > SAME_LEVEL:
                return f"{name}'s level {k} board is {u:g} m high in the old map, {v:g} m in the new"
    return None


def building_difference(old: BuildingMap, new: BuildingMap) -> str | None:
    """Why ``old`` and ``new`` cannot be two scans of one building, or None: their location codes differ, or
    their floor plans (the route's faces, each face's front line, ends and boards' heights within `SAME_FRONT`,
    `SAME_END`, `SAME_LEVEL`) do; maps without a floor plan: a face both mapped whose front line differs, or
    no face in common."""
    if (old.code, old.positions) != (new.code, new.positions):
        return (
            f"their location codes differ ({old.code!r}, positions {old.positions} against {new.code!r}, positions "
            f"{new.positions}); map both with the same --code and --positions"
        )
    if old.plan and new.plan:
        a, b = {f.key: f for f in old.plan}, {f.key: f for f in new.plan}
        if set(a) != set(b):
            return f"their floor plans list other faces (old: {_faces(a)}; new: {_faces(b)})"
        plans = [(a[k], b[k]) for k in sorted(a)]
    else:
        a, b = {f.key: f for f in old.faces}, {f.key: f for f in new.faces}
        if not set(a) & set(b):
            return f"no rack face in common (old: {_faces(a)}; new: {_faces(b)})"
        plans = [(FacePlan(*k, a[k].front_z), FacePlan(*k, b[k].front_z)) for k in sorted(set(a) & set(b))]
    return next((said for pa, pb in plans if (said := _plan_difference(pa, pb))), None)


def _seen(bmap: BuildingMap) -> dict[str, tuple[FaceMap, MapShelf, Location]]:
    return {loc.code: (f, s, loc) for f, s, loc in bmap.locations()}


def _boxes(bmap: BuildingMap) -> list[_Box]:
    out = []
    for f, shelf, loc in bmap.locations():
        if not loc.scanned:
            continue
        for b in shelf.boxes:
            out.append(_Box(loc.code, (loc.aisle, loc.side, loc.level), f.sign * b.center[0] + 0.0, b,
                            b.confidence * min(1.0, loc.seen)))  # fmt: skip
    return out


def _similar(a: MapBox, b: MapBox, tol: float, colour_tol: float = float("inf")) -> bool:
    if a.colour is not None and b.colour is not None:
        if sum((u - v) ** 2 for u, v in zip(a.colour, b.colour)) ** 0.5 > colour_tol:
            return False
    return all(abs(u - v) <= tol for u, v in zip(a.size, b.size))


def _covered(bmaps: _Box, other: dict[str, tuple[FaceMap, MapShelf, Location]]) -> bool:
    """Whether the other scan saw the place of this box (its location there exists and was scanned)."""
    t = other.get(bmaps.code)
    return t is not None and t[2].scanned


def _greedy(old: list[_Box], new: list[_Box], ok, cost) -> list[tuple[_Box, _Box]]:
    """One-to-one pairs, cheapest first, among the pairs ``ok`` allows."""
    pairs = sorted(((cost(o, n), i, j) for i, o in enumerate(old) for j, n in enumerate(new) if ok(o, n)))
    used_o, used_n, out = set(), set(), []
    for _, i, j in pairs:
        if i not in used_o and j not in used_n:
            used_o.add(i)
            used_n.add(j)
            out.append((old[i], new[j]))
    return out


def diff_buildings(old: BuildingMap, new: BuildingMap, config: DiffConfig | None = None) -> BuildingDiff:
    """The changes from ``old`` to ``new`` (see the module docstring)."""
    if not isinstance(old, BuildingMap) or not isinstance(new, BuildingMap):
        raise InputError("diff: both maps must be building maps (`mvracklay map`'s building.json)")
    said = building_difference(old, new)
    if said:
        raise InputError(f"{old.source} and {new.source} are maps of different buildings: {said}")
    cfg = config or DiffConfig.for_maps(old, new)
    seen_old, seen_new = _seen(old), _seen(new)
    rows_old, rows_new = {r["location"]: r for r in old.inventory()}, {r["location"]: r for r in new.inventory()}
    unsure = {c for rows in (rows_old, rows_new) for c, r in rows.items() if r.get("recount") == "true"}
    old_boxes = [b for b in _boxes(old) if _covered(b, seen_new)]
    new_boxes = [b for b in _boxes(new) if _covered(b, seen_old)]

    def drop(pairs: list[tuple[_Box, _Box]]) -> None:
        gone_o, gone_n = {id(o) for o, _ in pairs}, {id(n) for _, n in pairs}
        old_boxes[:] = [b for b in old_boxes if id(b) not in gone_o]
        new_boxes[:] = [b for b in new_boxes if id(b) not in gone_n]

    same = _greedy(old_boxes, new_boxes, lambda o, n: o.key == n.key and abs(o.x - n.x) <= cfg.same
                   and _similar(o.box, n.box, cfg.size_tol), lambda o, n: abs(o.x - n.x))  # fmt: skip
    drop(same)
    shifted = _greedy(old_boxes, new_boxes, lambda o, n: o.code == n.code and abs(o.x - n.x) >= cfg.min_shift
                      and _similar(o.box, n.box, cfg.size_tol), lambda o, n: abs(o.x - n.x))  # fmt: skip
    drop(shifted)
    moved = []
    if old_boxes and new_boxes:
        cost = np.array(
            [[sum(abs(u - v) for u, v in zip(o.box.size, n.box.size)) for n in new_boxes] for o in old_boxes]
        )
        rr, cc = linear_sum_assignment(cost)
        moved = [(old_boxes[i], new_boxes[j]) for i, j in zip(rr, cc)
                 if old_boxes[i].code != new_boxes[j].code and _similar(old_boxes[i].box, new_boxes[j].box, cfg.move_tol, cfg.colour_tol)
                 and not {old_boxes[i].code, new_boxes[j].code} & unsure]  # fmt: skip
        drop(moved)
    changes = []
    for o, n in shifted:
        changes.append(Change(n.code, "shifted", "", n.box.size, [n.box.id], [o.box.id], n.x, o.x, o.weight * n.weight))
    for o, n in moved:
        changes.append(
            Change(n.code, "moved", o.code, n.box.size, [n.box.id], [o.box.id], n.x, o.x, o.weight * n.weight)
        )
    for o in old_boxes:
        w = seen_new[o.code][2].seen
        changes.append(Change(o.code, "removed", "", o.box.size, [], [o.box.id], None, o.x, o.weight * w))
    for n in new_boxes:
        w = seen_old[n.code][2].seen
        changes.append(Change(n.code, "added", "", n.box.size, [n.box.id], [], n.x, None, n.weight * w))
    order = {code: k for k, code in enumerate(sorted(set(seen_old) | set(seen_new)))}
    changes.sort(key=lambda c: (order[c.location], CHANGES.index(c.change), c.x if c.x is not None else c.old_x))
    return BuildingDiff(changes, _per_location(seen_old, seen_new, changes, rows_old, rows_new))


def _count(row: dict[str, Any] | None) -> int | None:
    return None if row is None or row["boxes"] == NOT_SCANNED else int(row["boxes"])


def _per_location(
    seen_old: dict, seen_new: dict, changes: list[Change], rows_old: dict, rows_new: dict
) -> list[LocationChange]:
    out = []
    for code in sorted(set(seen_old) | set(seen_new)):
        o, n = seen_old.get(code), seen_new.get(code)
        ro, rn = rows_old.get(code), rows_new.get(code)
        before, after = _count(ro), _count(rn)
        flagged = any(r is not None and r.get("recount") == "true" for r in (ro, rn))
        if n is None or not n[2].scanned:
            out.append(LocationChange(code, NOT_SCANNED, before, None))
            continue
        if o is None or not o[2].scanned:
            out.append(LocationChange(code, "new", None, after, "", float(rn["confidence"]), flagged))
            continue
        conf = min(float(ro["confidence"]), float(rn["confidence"]))
        lc = LocationChange(code, "unchanged", before, after, count_change(before, after), conf, flagged)
        for c in changes:
            if c.location == code:
                kind = {"added": "added", "removed": "removed", "shifted": "shifted", "moved": "moved_in"}[c.change]
                setattr(lc, kind, getattr(lc, kind) + 1)
            if c.change == "moved" and c.other_location == code:
                lc.moved_out += 1
        lc.free_length_change_m = round(shelf_free_space(n[1]).free_length - shelf_free_space(o[1]).free_length, 4)
        if lc.added or lc.removed or lc.moved_in or lc.moved_out or lc.shifted:
            lc.status = "changed"
        out.append(lc)
    return out


def format_locations(d: BuildingDiff, limit: int = 40) -> list[str]:
    """The locations whose count changed (one line each: before -> after, category, confidence, recount)."""
    moved = [c for c in d.locations if c.change not in ("", UNCHANGED)]
    if not moved:
        return ["no location's count changed"]
    head = f"{'location':<14} {'before':>6} {'after':>6} {'change':<14} {'conf':>5} recount"
    lines = [head, "-" * len(head)]
    for c in moved[:limit]:
        lines.append(f"{c.location:<14} {c.before:>6} {c.after:>6} {c.change:<14} {c.confidence:>5.2f} "
                     f"{'yes' if c.recount else '-'}")  # fmt: skip
    if len(moved) > limit:
        lines.append(f"... and {len(moved) - limit} more (location_changes.csv lists all)")
    kinds = {k: sum(1 for c in moved if c.change == k) for k in ("emptied", "filled", "count changed")}
    lines.append(", ".join(f"{v} {k}" for k, v in kinds.items()) + f" ({sum(c.recount for c in moved)} to recount)")
    return lines


def format_diff(d: BuildingDiff, limit: int = 40) -> str:
    """The locations whose count changed, then a plain-text table of the box changes (one line each), then the
    counts."""
    lines = [*format_locations(d, limit), ""]
    if not d.changes:
        lines += ["no box changed"]
    else:
        head = f"{'location':<14} {'change':<8} {'from':<14} {'size (m)':<19} {'x':>7} {'old_x':>7} {'conf':>5}"
        lines += [head, "-" * len(head)]
        for c in d.changes[:limit]:
            r = c.row()
            lines.append(
                f"{c.location:<14} {c.change:<8} {c.other_location or '-':<14} {r['size']:<19} {str(r['x']):>7} "
                f"{str(r['old_x']):>7} {c.confidence:>5.2f}"
            )
        if len(d.changes) > limit:
            lines.append(f"... and {len(d.changes) - limit} more (changes.csv lists all)")
    counts = d.counts()
    unseen = sum(1 for loc in d.locations if loc.status == NOT_SCANNED)
    lines.append(", ".join(f"{v} {k}" for k, v in counts.items()) + f"; {unseen} locations not scanned by the new scan")
    return "\n".join(lines)
