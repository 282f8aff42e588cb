"""The changes between two scans as 3D scenes: ``changes.glb`` and ``changes.rrd``, in the building frame.

The new scan's racks and unchanged boxes in their usual colours; added boxes green, removed ones a red outline
where they stood, moved ones blue at their new place with an arrow from the old, shifted ones orange (with an
arrow too). The ``.glb``'s change nodes are named ``change_NNN/<kind>`` with the change's row as extras.
"""

from __future__ import annotations

import math
import os

import numpy as np

from stitching.building.diff import BuildingDiff, Change
from stitching.building.export import building_parts
from stitching.building.map import BuildingMap
from stitching.export_gltf import Part, write_parts_glb
from stitching.geometry import Cuboid

#: what `write_changes` writes
CHANGE_FILES = ("location_changes.csv", "changes.csv", "changes.json", "changes.glb", "changes.rrd")
COLOURS = {"added": (40, 170, 60), "removed": (210, 40, 40), "moved": (40, 90, 210), "shifted": (240, 150, 20)}
EDGE = 0.02  #: metres: the thickness of a removed box's outline and of an arrow's shaft


def _box_at(bmap: BuildingMap, box_id: str) -> Cuboid | None:
    code = box_id.split("/")[0]
    try:
        face, shelf, _ = bmap.location(code)
    except Exception:  # a code the map lacks: nothing to draw
        return None
    for b in shelf.boxes:
        if b.id == box_id:
            return face.to_building(b.cuboid)
    return None


def _outline(c: Cuboid, name: str, colour: tuple[int, int, int], extras: dict) -> list[Part]:
    """The 12 edges of ``c`` as thin bars (its yaw kept)."""
    (cx, cy, cz), (w, h, d) = c.center, c.size
    ca, sa = math.cos(c.yaw), math.sin(c.yaw)
    parts = []

    def at(u: float, v: float, y: float, size: tuple[float, float, float], k: int) -> None:
        x, z = cx + u * ca - v * sa, cz + u * sa + v * ca
        parts.append(Part(f"{name}/edge_{k:02d}", "change", name, Cuboid((x, cy + y, z), size, c.yaw), colour, extras))

    k = 0
    for v in (-d / 2, d / 2):
        for y in (-h / 2, h / 2):
            at(0.0, v, y, (w, EDGE, EDGE), k)
            k += 1
    for u in (-w / 2, w / 2):
        for y in (-h / 2, h / 2):
            at(u, 0.0, y, (EDGE, EDGE, d), k)
            k += 1
    for u in (-w / 2, w / 2):
        for v in (-d / 2, d / 2):
            at(u, v, 0.0, (EDGE, h, EDGE), k)
            k += 1
    return parts


def _arrow(a: tuple[float, float, float], b: tuple[float, float, float], name: str, colour, extras) -> list[Part]:
    """A bar from ``a`` to ``b`` a little above them, with a head at ``b``."""
    dx, dz = b[0] - a[0], b[2] - a[2]
    length = math.hypot(dx, dz)
    if length < 1e-6:
        return []
    yaw = math.atan2(dz, dx)
    y = min(a[1], b[1]) - 0.3
    mid = ((a[0] + b[0]) / 2, y, (a[2] + b[2]) / 2)
    shaft = Part(f"{name}/arrow", "change", name, Cuboid(mid, (length, EDGE * 2, EDGE * 2), yaw), colour, extras)
    head = Part(f"{name}/head", "change", name, Cuboid((b[0], y, b[2]), (0.12, 0.12, 0.12), yaw), colour, extras)
    return [shaft, head]


def change_parts(new: BuildingMap, old: BuildingMap, d: BuildingDiff) -> list[Part]:
    """The new building's parts with each change drawn over it."""
    parts = building_parts(new)
    changed_new = {i for c in d.changes for i in c.box_ids}
    for p in parts:  # a changed box is drawn by its change
        if p.kind == "box" and p.name in changed_new:
            p.colour = COLOURS[next(c.change for c in d.changes if p.name in c.box_ids)]
    for k, c in enumerate(d.changes):
        parts += _change(k, c, new, old)
    return parts


def _change(k: int, c: Change, new: BuildingMap, old: BuildingMap) -> list[Part]:
    name, colour = f"change_{k:03d}", COLOURS[c.change]
    extras = {"id": name, "kind": "change", **{key: v for key, v in c.row().items()}}
    out = [Part(name, "change", None, None, None, extras)]
    was = _box_at(old, c.old_box_ids[0]) if c.old_box_ids else None
    now = _box_at(new, c.box_ids[0]) if c.box_ids else None
    if c.change == "removed" and was is not None:
        out += _outline(was, name, colour, extras)
    if c.change in ("moved", "shifted") and was is not None and now is not None:
        out += _arrow(was.center, now.center, name, colour, extras)
    return out


def export_changes_glb(new: BuildingMap, old: BuildingMap, d: BuildingDiff, path: str | os.PathLike) -> int:
    return write_parts_glb(change_parts(new, old, d), path, "building (x, y, z) -> glTF (x, -y, -z); metres")


def write_changes_rrd(new: BuildingMap, old: BuildingMap, d: BuildingDiff, path: str | os.PathLike) -> None:
    """``changes.rrd``: ``building/boxes`` (the new scan), ``changes/<kind>`` boxes, ``changes/arrows``."""
    import rerun as rr

    from stitching.rerun_log import _boxes, recording

    rec = recording("mvracklay-changes", path)  # written by us and read back when closed
    rec.log("/", rr.ViewCoordinates.RDF, static=True)
    boxes = [f.to_building(b.cuboid) for f, shelf, _ in new.locations() for b in shelf.boxes]
    rec.log("building/boxes", _boxes(boxes, (170, 170, 170)), static=True)
    origins, vectors = [], []
    for kind in COLOURS:
        mine = [c for c in d.changes if c.change == kind]
        cubes, labels = [], []
        for c in mine:
            was = _box_at(old, c.old_box_ids[0]) if c.old_box_ids else None
            now = _box_at(new, c.box_ids[0]) if c.box_ids else None
            shown = was if kind == "removed" else now
            if shown is not None:
                cubes.append(shown)
                labels.append(f"{c.location} {kind}" + (f" from {c.other_location}" if c.other_location else ""))
            if was is not None and now is not None:
                origins.append(was.center)
                vectors.append(np.subtract(now.center, was.center))
        rec.log(f"changes/{kind}", _boxes(cubes, COLOURS[kind], labels), static=True)
    if origins:
        rec.log("changes/arrows", rr.Arrows3D(origins=origins, vectors=vectors, colors=[COLOURS["moved"]]), static=True)
    rec.flush()
    rec.disconnect()


def is_changes_folder(folder: str | os.PathLike) -> bool:
    """Whether ``folder`` holds an earlier `write_changes`'s output (its changes.json a dict of columns and changes)."""
    import json

    try:
        with open(os.path.join(folder, "changes.json"), encoding="utf-8") as f:
            doc = json.load(f)
    except (OSError, ValueError, RecursionError):
        return False
    return isinstance(doc, dict) and {"columns", "changes"} <= set(doc)


def write_changes(
    old: BuildingMap, new: BuildingMap, d: BuildingDiff, out: str | os.PathLike, rrd: bool = True,
    evaluation: dict | None = None,
) -> list[str]:  # fmt: skip
    """``location_changes.csv`` (`LOCATION_COLUMNS`: per location its count before and after), ``changes.csv``
    (`CHANGE_COLUMNS`), ``changes.json`` (rows, counts, per location, ``evaluation`` when given), ``changes.glb``
    and (``rrd``) ``changes.rrd`` in ``out``, each atomically; returns their names."""
    from layouts.fileio import atomic_write_json, atomic_write_text
    from layouts.locations import rows_csv
    from stitching.building.diff import CHANGE_COLUMNS, LOCATION_COLUMNS
    from stitching.building.schema import check_changes

    os.makedirs(out, exist_ok=True)
    rows = d.rows()
    doc = {"columns": list(CHANGE_COLUMNS), "changes": rows, "counts": d.counts(),
           "locations": [vars(loc) for loc in d.locations]}  # fmt: skip
    check_changes(doc, os.path.join(out, "changes.json"), built=True)  # a defect raised before anything is written
    atomic_write_text(os.path.join(out, "location_changes.csv"), rows_csv(d.location_rows(), LOCATION_COLUMNS))
    atomic_write_text(os.path.join(out, "changes.csv"), rows_csv(rows, CHANGE_COLUMNS))
    if evaluation is not None:
        doc["evaluation"] = evaluation
    atomic_write_json(os.path.join(out, "changes.json"), doc)
    export_changes_glb(new, old, d, os.path.join(out, "changes.glb"))
    written = ["location_changes.csv", "changes.csv", "changes.json", "changes.glb"]
    if rrd:
        write_changes_rrd(new, old, d, os.path.join(out, "changes.rrd"))
        written.append("changes.rrd")
    return written
