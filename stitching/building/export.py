"""A building map as a 3D scene: ``building.glb`` (floor, aisles, racks with uprights and beams, boxes; nodes
named by location code, facts in their extras) and ``building.rrd`` (each pass on its own entity path and
timeline, then the fused building).

Both in the building frame (`stitching.building.map`): glTF gets (x, -y, -z) as for a row map; Rerun the frame
as it is (right / down / forward, ``ViewCoordinates.RDF``).
"""

from __future__ import annotations

import os
from dataclasses import replace
from typing import Any

from stitching.building.map import BuildingMap, FaceMap
from stitching.export_gltf import Part, scene_parts, write_parts_glb
from stitching.geometry import Cuboid
from stitching.warehouse_map import WarehouseMap

FLOOR_COLOUR = (150, 150, 145)
AISLE_COLOUR = (230, 200, 60)  #: the painted lines along each aisle
FLOOR_THICKNESS = 0.05
MARGIN = 2.0  #: metres of floor around the racks


def _extent(bmap: BuildingMap) -> tuple[float, float, float, float]:
    xs, zs = [], []
    for f in bmap.faces:
        for r in f.map.racks:
            for s in r.shelves:
                c = f.to_building(s.cuboid)
                xs += [c.center[0] - c.size[0] / 2, c.center[0] + c.size[0] / 2]
                zs += [c.center[2] - c.size[2] / 2, c.center[2] + c.size[2] / 2]
    if not xs:
        return (0.0, 1.0, 0.0, 1.0)
    return min(xs) - MARGIN, max(xs) + MARGIN, min(zs) - MARGIN, max(zs) + MARGIN


def _aisles(bmap: BuildingMap) -> list[tuple[int, float, float]]:
    """(aisle, z of its L face's front, of its R face's front) for aisles with both faces mapped."""
    fronts: dict[int, dict[str, float]] = {}
    for f in bmap.faces:
        fronts.setdefault(f.aisle, {})[f.side] = f.front_z
    return [(a, d["L"], d["R"]) for a, d in sorted(fronts.items()) if "L" in d and "R" in d]


def _face_parts(face: FaceMap) -> list[Part]:
    parts = []
    for p in scene_parts(face.map):
        if p.cuboid is None:
            parts.append(p)
            continue
        c = face.to_building(p.cuboid)
        if p.kind == "upright":  # a rack's uprights stand on the floor
            top = c.center[1] - c.size[1] / 2
            c = Cuboid((c.center[0], top / 2, c.center[2]), (c.size[0], -top, c.size[2]), c.yaw)
        extras: dict[str, Any] = dict(p.extras)
        if p.kind == "shelf":
            loc = face.locations[p.name]
            extras.update(location=loc.code, aisle=loc.aisle, side=loc.side, bay=loc.bay, level=loc.level,
                          position=loc.position, passes=loc.passes, scanned=loc.scanned)  # fmt: skip
        parts.append(replace(p, cuboid=c, extras=extras))
    return parts


def building_parts(bmap: BuildingMap) -> list[Part]:
    """Every node of ``building.glb`` in a stable order: the floor, the aisles' lines, then each face's racks."""
    x0, x1, z0, z1 = _extent(bmap)
    t = FLOOR_THICKNESS
    floor = Cuboid(((x0 + x1) / 2, t / 2, (z0 + z1) / 2), (x1 - x0, t, z1 - z0))
    parts = [Part("floor", "floor", None, floor, FLOOR_COLOUR, {"id": "floor", "kind": "floor"})]
    for a, zl, zr in _aisles(bmap):
        for k, z in enumerate((zl + 0.15, zr - 0.15)):
            line = Cuboid(((x0 + x1) / 2, -0.002, z), (x1 - x0 - 2 * MARGIN + 1.0, 0.004, 0.1))
            name = f"aisle_{a:02d}/line_{k}"
            parts.append(Part(name, "aisle", None, line, AISLE_COLOUR, {"id": name, "kind": "aisle", "aisle": a}))
    for f in bmap.faces:
        parts.extend(_face_parts(f))
    return parts


def export_building_glb(bmap: BuildingMap, path: str | os.PathLike) -> int:
    """Write the building as a ``.glb`` (atomic); returns the number of meshes."""
    return write_parts_glb(building_parts(bmap), path, "building (x, y, z) -> glTF (x, -y, -z); metres")


def _placed_cuboids(face: FaceMap, offset: float, wmap: WarehouseMap) -> list[Cuboid]:
    """A pass's own boxes (its row map) in the building frame, placed as registration left it."""
    shelves = wmap.shelves()
    front = sorted(s.z_range[0] for s in shelves)[len(shelves) // 2] if shelves else 0.0
    out = []
    for s in shelves:
        for b in s.boxes:
            x, y, z = b.center
            out.append(face.to_building(Cuboid((x + offset, y, z - front), tuple(b.size), b.yaw)))
    return out


def write_building_rrd(bmap: BuildingMap, pass_maps: dict[str, WarehouseMap], path: str | os.PathLike) -> None:
    """``building.rrd``: ``passes/NAME`` (its camera path on its own timeline ``NAME``, its boxes as it saw
    them) for every pass, then ``building/boxes`` and ``building/shelves`` labelled by location code."""
    import rerun as rr

    from stitching.rerun_log import _boxes, recording

    rec = recording("mvracklay-building", path)  # written by us and read back when closed
    rec.log("/", rr.ViewCoordinates.RDF, static=True)
    for p in bmap.passes:
        wmap = pass_maps.get(p.name)
        if wmap is None:
            continue
        face = bmap.face(p.aisle, p.side)
        off = p.x0 + p.shift
        rec.log(f"passes/{p.name}/boxes", _boxes(_placed_cuboids(face, off, wmap), (120, 160, 220)), static=True)
        pts = [
            face.to_building(Cuboid((off + s.offset, -p.camera_height, p.camera_z), (0, 0, 0))).center
            for s in wmap.steps
        ]
        for k, s in enumerate(wmap.steps):
            rec.set_time(p.name, sequence=s.frame)
            rec.log(f"passes/{p.name}/camera", rr.Points3D([pts[k]], radii=0.05))
    boxes, labels, shelves, shelf_labels = [], [], [], []
    for f, shelf, loc in bmap.locations():
        shelves.append(f.to_building(shelf.cuboid))
        shelf_labels.append(loc.code if loc.scanned else f"{loc.code} (not scanned)")
        for b in shelf.boxes:
            boxes.append(f.to_building(b.cuboid))
            labels.append(b.id)
    rec.log("building/boxes", _boxes(boxes, (200, 150, 90), labels), static=True)
    rec.log("building/shelves", _boxes(shelves, (90, 90, 95), shelf_labels), static=True)
    rec.flush()
    rec.disconnect()
