"""Export a `WarehouseMap` to binary glTF (``.glb``) with trimesh: racks with uprights and beams,
shelf boards, and boxes in the colours the frames saw.

* Nodes nest rack -> shelf -> box, each named by its stable id (DESIGN.md): ``rack_00`` (no mesh)
  holds its uprights ``rack_00/upright_00`` ... ``_03`` and its shelves; a shelf node
  ``rack_00/shelf_01`` holds its board's mesh, its beams ``rack_00/shelf_01/beam_front`` and
  ``.../beam_back``, and its boxes ``rack_00/shelf_01/box_003``. Names are unique by construction.
* A rack's frame is drawn from the map (nothing in it is measured): four uprights
  (`UPRIGHT_WIDTH` x `UPRIGHT_DEPTH` section) inside the corners of the rack's X range and its
  shelves' depth range (none at an end where a partial rack is cut: ``upright_00`` / ``_01`` stand
  at its low-X end, ``_02`` / ``_03`` at its high-X end), from `BEAM_HEIGHT` under the lowest board to the top of the highest
  shelf's clear height; two beams per shelf (`BEAM_HEIGHT` x `BEAM_DEPTH`, the rack's length)
  under the board's front and back edges. Boards are slabs ``board_thickness`` thick under each
  shelf's board top.
* Every node carries glTF ``extras``: a rack its ``id``, ``x_range`` and ``partial``; a shelf its
  slot, board and clear height, confidence, ``partial`` and free space (`stitching.free_space`, over the
  clear span inside the uprights: ``clear_length``, ``free_length``, ``free_fraction`` of the clear length,
  ``occupancy``, the share of it under a box); a box its ``size`` (w, h, d),
  ``yaw``, ``confidence``, ``observations``, ``partial`` (its shelf's) and ``colour`` with
  ``colour_source`` ("frames", or "default" for a box no frame gave a colour).
* Materials are explicit PBR (metallic 0, roughness 0.8) with opaque RGBA base colours (alpha
  255; alpha 0 would hide the mesh), one per mesh (readers that group meshes by material still
  see one per object): boxes their `MapBox.colour` (sRGB, converted to glTF's linear factors),
  else `DEFAULT_BOX_COLOUR`; boards, uprights and beams `RACK_COLOURS`.
* glTF is Y-up, the map is Y-down (DESIGN.md). Every vertex is converted with
  ``(x, y, z) -> (x, -y, -z)``, a 180 degree turn about X (a proper rotation, so faces keep
  their winding and the scene is not mirrored). Vertices are written already in place (every
  node transform is the identity), so any reader gets the same coordinates.
"""

from __future__ import annotations

import json
import os
import struct
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from layouts.classes import BOX, CLASS_COLOURS
from layouts.errors import InputError
from layouts.fileio import atomic_write_bytes
from stitching.free_space import UPRIGHT_WIDTH, shelf_free_space
from stitching.geometry import Cuboid
from stitching.warehouse_map import MapRack, MapShelf, WarehouseMap

#: The glTF conversion: map (Y down, Z forward) -> glTF (Y up), a 180 degree rotation about X.
Y_UP = np.diag([1.0, -1.0, -1.0])

UPRIGHT_DEPTH = 0.08  #: metres along Z of an upright's section
BEAM_HEIGHT = 0.10  #: metres of a beam's face under the board
BEAM_DEPTH = 0.05  #: metres along Z of a beam
#: sRGB colours of the rack's parts: galvanised boards, blue uprights, orange beams
RACK_COLOURS: dict[str, tuple[int, int, int]] = {
    "shelf": (190, 190, 185),
    "upright": (35, 75, 150),
    "beam": (225, 95, 30),
}
DEFAULT_BOX_COLOUR = CLASS_COLOURS[BOX]  #: a box no frame gave a colour

# Faces of a cuboid whose corners come from `Cuboid.corners` (top face 0-3, bottom face 4-7),
# wound counter-clockwise seen from outside once converted to Y-up.
_FACES = np.array(
    [
        [0, 1, 2],
        [0, 2, 3],  # top
        [4, 6, 5],
        [4, 7, 6],  # bottom
        [0, 4, 5],
        [0, 5, 1],
        [1, 5, 6],
        [1, 6, 2],
        [2, 6, 7],
        [2, 7, 3],
        [3, 7, 4],
        [3, 4, 0],
    ]
)


@dataclass
class Part:
    """One node of the scene: ``cuboid`` None for a node without a mesh (a rack)."""

    name: str
    kind: str  #: 'rack', 'upright', 'shelf' (its board), 'beam' or 'box'
    parent: str | None
    cuboid: Cuboid | None
    colour: tuple[int, int, int] | None = None
    extras: dict[str, Any] = field(default_factory=dict)


def cuboid_mesh_arrays(c: Cuboid) -> tuple[np.ndarray, np.ndarray]:
    """(8, 3) glTF-frame vertices and (12, 3) outward-facing triangles of a map cuboid."""
    v = c.corners() @ Y_UP.T
    faces = _FACES.copy()
    # Make the winding outward regardless of how the footprint is ordered.
    centre = v.mean(axis=0)
    tri = v[faces]
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    outward = np.einsum("ij,ij->i", normal, tri.mean(axis=1) - centre) > 0
    faces[~outward] = faces[~outward][:, ::-1]
    return v, faces


def _box_xyz(x: tuple[float, float], y: tuple[float, float], z: tuple[float, float]) -> Cuboid:
    """The axis-aligned cuboid over map ranges ``x``, ``y``, ``z`` (each at least 1 mm thick)."""
    size = tuple(max(b - a, 1e-3) for a, b in (x, y, z))
    return Cuboid(tuple((a + b) / 2 for a, b in (x, y, z)), size)


def _r(v: float, n: int = 4) -> float:
    return round(float(v), n)


def rack_frame(rack: MapRack, board_thickness: float) -> tuple[list[Part], dict[str, list[Part]]]:
    """A rack's uprights and, per shelf id, its two beams (see the module docstring); nothing for no shelves."""
    if not rack.shelves:
        return [], {}
    x0, x1 = rack.x_range
    z0 = min(s.z_range[0] for s in rack.shelves)
    z1 = max(s.z_range[1] for s in rack.shelves)
    t = board_thickness
    bottom = -min(s.board_height for s in rack.shelves) + t + BEAM_HEIGHT  # map Y is down
    top = -max(s.board_height + s.clear_height for s in rack.shelves)
    uw, ud = min(UPRIGHT_WIDTH, (x1 - x0) / 2), min(UPRIGHT_DEPTH, (z1 - z0) / 2)
    partial = getattr(rack, "partial", None)
    cut = (partial in ("start", "both"),) * 2 + (partial in ("end", "both"),) * 2
    uprights = []
    for i, (xa, za) in enumerate(((x0, z0), (x0, z1 - ud), (x1 - uw, z0), (x1 - uw, z1 - ud))):
        if cut[i]:  # the rack goes on unseen past a cut end: no upright drawn there
            continue
        c = _box_xyz((xa, xa + uw), (top, bottom), (za, za + ud))
        uprights.append(Part(f"{rack.id}/upright_{i:02d}", "upright", rack.id, c, RACK_COLOURS["upright"]))
    beams: dict[str, list[Part]] = {}
    bd = min(BEAM_DEPTH, (z1 - z0) / 2)
    for s in rack.shelves:
        y = (-s.board_height + t, -s.board_height + t + BEAM_HEIGHT)
        beams[s.id] = [
            Part(f"{s.id}/beam_{side}", "beam", s.id, _box_xyz((x0, x1), y, zr), RACK_COLOURS["beam"])
            for side, zr in (("front", (s.z_range[0], s.z_range[0] + bd)), ("back", (s.z_range[1] - bd, s.z_range[1])))
        ]
    for p in uprights + [b for bs in beams.values() for b in bs]:
        p.extras = {"id": p.name, "kind": p.kind, "size": [_r(v) for v in p.cuboid.size], "measured": False}
    return uprights, beams


def _shelf_extras(s: MapShelf, rack: MapRack | None = None) -> dict[str, Any]:
    fs = shelf_free_space(s, rack)
    extras = {
        "id": s.id,
        "kind": "shelf",
        "slot": s.slot,
        "board_height": _r(s.board_height),
        "clear_height": _r(s.clear_height),
        "x_range": [_r(v) for v in s.x_range],
        "z_range": [_r(v) for v in s.z_range],
        "confidence": _r(s.confidence),
        "partial": getattr(s, "partial", None),
        "boxes": len(s.boxes),
        "clear_length": _r(fs.length),
        "free_length": _r(fs.free_length),
        "free_fraction": _r(fs.free_length / fs.length) if fs.length > 0 else 0.0,
        "occupancy": _r(fs.occupancy),
    }
    unknown = getattr(fs, "unknown_length", None)
    if unknown is not None:
        extras["unknown_length"] = _r(unknown)
    return extras


def scene_parts(wmap: WarehouseMap) -> list[Part]:
    """Every node of the ``.glb`` in a stable order, parents before their children."""
    parts = []
    t = wmap.board_thickness
    for rack in wmap.racks:
        partial = getattr(rack, "partial", None)
        extras = {"id": rack.id, "kind": "rack", "x_range": [_r(v) for v in rack.x_range], "partial": partial}
        parts.append(Part(rack.id, "rack", None, None, None, {**extras, "shelves": len(rack.shelves)}))
        uprights, beams = rack_frame(rack, t)
        parts.extend(uprights)
        for s in rack.shelves:
            x0, x1 = s.x_range
            board = _box_xyz((x0, x1), (-s.board_height, -s.board_height + t), s.z_range)
            parts.append(Part(s.id, "shelf", rack.id, board, RACK_COLOURS["shelf"], _shelf_extras(s, rack)))
            parts.extend(beams.get(s.id, []))
            for b in s.boxes:
                colour = getattr(b, "colour", None)
                extras = {
                    "id": b.id,
                    "kind": "box",
                    "size": [_r(v) for v in b.size],
                    "yaw": _r(b.yaw),
                    "confidence": _r(b.confidence),
                    "observations": b.observations,
                    "partial": getattr(s, "partial", None),
                    "colour": list(colour or DEFAULT_BOX_COLOUR),
                    "colour_source": "frames" if colour is not None else "default",
                }
                parts.append(Part(b.id, "box", s.id, b.cuboid, tuple(colour or DEFAULT_BOX_COLOUR), extras))
    return parts


def map_cuboids(wmap: WarehouseMap) -> list[tuple[str, str, Cuboid]]:
    """``(name, kind, cuboid)`` for every mesh of the ``.glb`` (kind 'upright', 'shelf' (a board), 'beam' or
    'box'), in a stable order."""
    return [(p.name, p.kind, p.cuboid) for p in scene_parts(wmap) if p.cuboid is not None]


def srgb_to_linear(rgb: tuple[int, int, int]) -> np.ndarray:
    """sRGB 0-255 -> glTF's linear base colour factors 0-1 (the sRGB transfer function)."""
    c = np.asarray(rgb, float) / 255.0
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def _empty_glb_bytes() -> bytes:
    """A valid binary glTF holding one empty scene (trimesh refuses to export a scene without meshes)."""
    doc = {
        "asset": {"version": "2.0", "generator": "mvracklay (empty map)"},
        "scene": 0,
        "scenes": [{"name": "warehouse"}],
    }
    body = json.dumps(doc, separators=(",", ":"), sort_keys=True).encode()
    body += b" " * (-len(body) % 4)
    return b"glTF" + struct.pack("<II", 2, 12 + 8 + len(body)) + struct.pack("<I", len(body)) + b"JSON" + body


def export_glb(wmap: WarehouseMap, path: str | os.PathLike) -> int:
    """Write ``wmap`` as a ``.glb`` (atomic; a map with no shelf or box gives a valid empty scene); returns the
    number of meshes written."""
    return write_parts_glb(scene_parts(wmap), path, "map (x, y, z) -> glTF (x, -y, -z); metres")


def write_parts_glb(parts: list[Part], path: str | os.PathLike, frame: str) -> int:
    """Write scene nodes as a ``.glb`` (atomic; no mesh gives a valid empty scene); returns the meshes written.
    ``frame``: how the cuboids' frame maps to glTF's, kept in the scene's metadata."""
    if not any(p.cuboid is not None for p in parts):
        atomic_write_bytes(path, _empty_glb_bytes())
        return 0
    import trimesh
    from trimesh.visual.material import PBRMaterial

    scene = trimesh.Scene()
    scene.metadata["map_frame"] = frame
    count = 0
    for p in parts:
        if p.cuboid is None:
            scene.graph.update(frame_to=p.name, frame_from=p.parent, metadata=p.extras)
            continue
        v, f = cuboid_mesh_arrays(p.cuboid)
        mesh = trimesh.Trimesh(vertices=v, faces=f, process=False)
        rgba = np.append(srgb_to_linear(p.colour), 1.0)
        material = PBRMaterial(name=f"{p.kind}:{p.name}", baseColorFactor=rgba, metallicFactor=0.0, roughnessFactor=0.8)
        mesh.visual = trimesh.visual.TextureVisuals(material=material)
        scene.add_geometry(mesh, node_name=p.name, geom_name=p.name, parent_node_name=p.parent, metadata=p.extras)
        count += 1
    atomic_write_bytes(path, scene.export(file_type="glb"))
    return count


def glb_json(path: str | os.PathLike) -> dict[str, Any]:
    """The JSON chunk of a ``.glb`` (nodes, their names, children and extras; materials), as a dict."""
    data = open(path, "rb").read()
    if len(data) < 20 or data[:4] != b"glTF" or data[16:20] != b"JSON":
        raise InputError(f"{path}: not a binary glTF (.glb) file")
    (n,) = struct.unpack("<I", data[12:16])
    return json.loads(data[20 : 20 + n])


def load_glb_cuboid_bounds(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """Read a ``.glb`` back with trimesh: mesh node name -> (8, 3) vertices in the *map* frame."""
    import trimesh

    scene = trimesh.load(str(path), force="scene")
    out = {}
    for node in scene.graph.nodes_geometry:
        transform, geom = scene.graph[node]
        mesh = scene.geometry[geom]
        v = trimesh.transformations.transform_points(mesh.vertices, transform)
        out[node] = v @ Y_UP  # Y_UP is its own inverse
    return out
