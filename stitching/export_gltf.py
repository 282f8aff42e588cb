"""Export a `WarehouseMap` to binary glTF (``.glb``) with trimesh.

* One node and one mesh per object, named by its stable id: ``rack_00/shelf_01`` for a shelf
  board, ``rack_00/shelf_01/box_003`` for a box. Names are unique by construction.
* Materials are explicit PBR (metallic 0, roughness 0.8) with opaque RGBA base colours
  (alpha 255; alpha 0 would hide the mesh): `layouts.classes.CLASS_COLOURS` for shelf and box.
* glTF is Y-up, the map is Y-down (DESIGN.md). Every vertex is converted with
  ``(x, y, z) -> (x, -y, -z)``, a 180 degree turn about X (a proper rotation, so faces keep
  their winding and the scene is not mirrored). Vertices are written already in place (node
  transforms are identity), so any reader gets the same coordinates.
* Shelf boards are drawn as slabs ``board_thickness`` thick under each shelf's board top.
"""

from __future__ import annotations

import json
import os
import struct

import numpy as np

from layouts.classes import BOX, CLASS_COLOURS, SHELF
from layouts.fileio import atomic_write_bytes
from stitching.geometry import Cuboid
from stitching.warehouse_map import WarehouseMap

#: The glTF conversion: map (Y down, Z forward) -> glTF (Y up), a 180 degree rotation about X.
Y_UP = np.diag([1.0, -1.0, -1.0])

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


def map_cuboids(wmap: WarehouseMap) -> list[tuple[str, str, Cuboid]]:
    """``(name, kind, cuboid)`` for every board and box, kind 'shelf' or 'box', in a stable order."""
    out = []
    t = wmap.board_thickness
    for rack in wmap.racks:
        for s in rack.shelves:
            x0, x1 = s.x_range
            z0, z1 = s.z_range
            board = Cuboid(((x0 + x1) / 2, -s.board_height + t / 2, (z0 + z1) / 2), (x1 - x0, max(t, 1e-3), z1 - z0))
            out.append((s.id, "shelf", board))
            for b in s.boxes:
                out.append((b.id, "box", b.cuboid))
    return out


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
    items = map_cuboids(wmap)
    if not items:
        atomic_write_bytes(path, _empty_glb_bytes())
        return 0
    import trimesh
    from trimesh.visual.material import PBRMaterial

    scene = trimesh.Scene()
    colours = {"shelf": CLASS_COLOURS[SHELF], "box": CLASS_COLOURS[BOX]}
    for name, kind, c in items:
        v, f = cuboid_mesh_arrays(c)
        mesh = trimesh.Trimesh(vertices=v, faces=f, process=False)
        # One material per mesh (same colour per class) so readers that group by material
        # (Open3D) still see one mesh per object.
        material = PBRMaterial(
            name=f"{kind}:{name}",
            baseColorFactor=np.array([*colours[kind], 255], np.uint8),
            metallicFactor=0.0,
            roughnessFactor=0.8,
        )
        mesh.visual = trimesh.visual.TextureVisuals(material=material)
        scene.add_geometry(mesh, node_name=name, geom_name=name)
    data = scene.export(file_type="glb")
    atomic_write_bytes(path, data)
    return len(items)


def load_glb_cuboid_bounds(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """Read a ``.glb`` back with trimesh: node name -> (8, 3) vertices in the *map* frame."""
    import trimesh

    scene = trimesh.load(str(path), force="scene")
    out = {}
    for node in scene.graph.nodes_geometry:
        transform, geom = scene.graph[node]
        mesh = scene.geometry[geom]
        v = trimesh.transformations.transform_points(mesh.vertices, transform)
        out[node] = v @ Y_UP  # Y_UP is its own inverse
    return out
