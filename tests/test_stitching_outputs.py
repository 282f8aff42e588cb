"""Outputs: WarehouseMap JSON, .glb round trip (trimesh, Open3D), .rrd round trip, free space."""

import json
import math

import numpy as np
import pytest

from layouts import InputError, LayoutSpec
from stitching.export_gltf import export_glb, load_glb_cuboid_bounds, map_cuboids
from stitching.free_space import UPRIGHT_INSET, fits, free_space, parse_box, shelf_free_space
from stitching.pipeline import reconstruct
from stitching.synthetic import make_sequence
from stitching.warehouse_map import MapBox, MapRack, MapShelf, StepRecord, WarehouseMap


@pytest.fixture(scope="module")
def wmap():
    seq = make_sequence(seed=0, frames=15, spec=LayoutSpec(size=64), step=0.12)
    return reconstruct(seq.layouts, seq.spec).map


def _hand_map():
    boxes = [
        MapBox("rack_00/shelf_00/box_000", (0.25, -0.2, 0.0), (0.5, 0.4, 0.6), 0.0, 0.9, 5),
        MapBox("rack_00/shelf_00/box_001", (1.5, -0.15, 0.0), (1.0, 0.3, 0.8), 0.0, 0.8, 4),
    ]
    shelf = MapShelf("rack_00/shelf_00", 0, 0.0, 0.9, (0.0, 2.0), (-0.5, 0.5), 1.0, boxes)
    return WarehouseMap([MapRack("rack_00", (0.0, 2.0), [shelf])], [StepRecord(0, 0, 0, 0, 1, "first", 0)], 0.05)


def test_map_json_round_trip_and_errors(tmp_path, wmap):
    p = tmp_path / "m.json"
    wmap.save(p)
    back = WarehouseMap.load(p)
    assert back.to_dict() == wmap.to_dict()
    assert [b.id for b in back.boxes()] == [b.id for b in wmap.boxes()]
    (tmp_path / "bad.json").write_text(json.dumps({"format": "other"}))
    with pytest.raises(InputError, match="not a warehouse map"):
        WarehouseMap.load(tmp_path / "bad.json")
    d = wmap.to_dict()
    d["racks"][0]["shelves"][0]["x_range"] = [0, "x"]
    (tmp_path / "bad2.json").write_text(json.dumps(d))
    with pytest.raises(InputError, match="malformed warehouse map"):
        WarehouseMap.load(tmp_path / "bad2.json")


def test_glb_round_trip_trimesh_and_open3d(tmp_path, wmap):
    import open3d as o3d
    import trimesh

    path = tmp_path / "w.glb"
    n = export_glb(wmap, path)
    items = map_cuboids(wmap)
    assert n == len(items) and len({name for name, _, _ in items}) == n
    # Same map -> same bytes.
    export_glb(wmap, tmp_path / "w2.glb")
    assert path.read_bytes() == (tmp_path / "w2.glb").read_bytes()
    # trimesh: every node by name, its vertices equal the cuboid's corners (map frame).
    got = load_glb_cuboid_bounds(path)
    assert set(got) == {name for name, _, _ in items}
    for name, _, c in items:
        assert np.allclose(np.sort(got[name], axis=0), np.sort(c.corners(), axis=0), atol=1e-5)
    scene = trimesh.load(str(path), force="scene")
    for g in scene.geometry.values():
        assert g.visual.material.baseColorFactor[3] == 255
        assert g.is_watertight and g.volume > 0  # outward, consistent winding
    # Y-up: box tops are above their boards in glTF coordinates.
    box_name = next(name for name, kind, _ in items if kind == "box")
    assert got[box_name][:, 1].min() < 0  # map frame is Y down: boxes have negative Y
    # Open3D reads the same vertices (glTF frame).
    mesh = o3d.io.read_triangle_mesh(str(path))
    o3d_v = np.asarray(mesh.vertices)
    want = np.vstack([c.corners() for _, _, c in items]) * np.array([1, -1, -1])
    assert len(o3d_v) == len(want)
    assert np.allclose(np.unique(o3d_v.round(4), axis=0), np.unique(want.round(4), axis=0), atol=1e-4)
    model = o3d.io.read_triangle_model(str(path))
    model_v = np.vstack([np.asarray(m.mesh.vertices) for m in model.meshes])
    assert np.allclose(np.unique(model_v.round(4), axis=0), np.unique(want.round(4), axis=0), atol=1e-4)


def test_rrd_loads_back_with_the_logged_entities(tmp_path, wmap):
    from stitching import rerun_log

    seq = make_sequence(seed=1, frames=3, spec=LayoutSpec(size=32))
    from stitching.pipeline import Stitcher

    st = Stitcher(seq.spec)
    rec = rerun_log.start("test-stitching", save=tmp_path / "w.rrd")
    path = []
    for i, fl in enumerate(seq.layouts):
        frame, step = st.push(fl, i)
        path.append(rerun_log.camera_point(step.offset))
        rerun_log.log_frame(rec, i, fl, frame, step.offset, np.zeros((8, 8, 3), np.uint8), path)
        rerun_log.log_map(rec, st.map(), i, seq.spec.num_slots)
    rec.flush()
    rec.disconnect()
    ents = rerun_log.read_entities(tmp_path / "w.rrd")
    for e in (
        "/",
        "/layouts",
        "/camera/rgb",
        "/layouts/top/slot_0",
        "/layouts/front/slot_2",
        "/world/frame/boxes",
        "/world/map/slot_0",
        "/world/map/shelves",
        "/world/camera/path",
    ):
        assert e in ents, e


def test_free_space_numbers_and_fits():
    m = _hand_map()
    (fs,) = free_space(m)
    assert fs.gaps == [(0.5, 1.0)]
    assert fs.free_length == pytest.approx(0.5)
    clear = 2.0 - 2 * UPRIGHT_INSET  # the span inside the uprights; the boxes' footprints clipped to it
    a0, a1 = (0.5 - UPRIGHT_INSET) * 0.6, (1.0 - UPRIGHT_INSET) * 0.8
    assert fs.length == pytest.approx(clear)
    assert fs.free_area == pytest.approx(clear - a0 - a1)
    assert fs.free_volume == pytest.approx(clear * 0.9 - a0 * 0.4 - a1 * 0.3)
    assert fs.occupancy == pytest.approx((clear - 0.5) / clear)  # the length under a box
    assert fs.boxes == 2
    assert shelf_free_space(m.shelves()[0]).to_dict()["gaps"] == [[0.5, 1.0]]
    f, turned = fits(m, 0.4, 0.3, 0.3, margin=0.02)
    assert f.shelf == "rack_00/shelf_00" and not f.rotated and turned.rotated
    assert f.centres[0] == pytest.approx((0.72, 0.78))
    assert turned.centres[0] == pytest.approx((0.67, 0.83))
    (only,) = fits(m, 0.45, 0.9, 0.3)  # turned, 0.9 along X would not fit the 0.5 m gap
    assert not only.rotated
    (only,) = fits(m, 0.9, 0.45, 0.3)
    assert only.rotated and only.along_x == pytest.approx(0.45)
    assert fits(m, 0.4, 0.3, 0.95) == []  # taller than the clear height
    assert fits(m, 0.6, 0.55, 0.3) == []  # no gap long enough either way
    assert parse_box("0.4x0.3x0.3") == (0.4, 0.3, 0.3)
    with pytest.raises(InputError, match="--box must be WxDxH"):
        parse_box("0.4x0.3")
    with pytest.raises(InputError, match="no shelf"):
        m.shelf("rack_09/shelf_00")


def test_yawed_box_footprint_counts_exactly():
    m = _hand_map()
    b = m.racks[0].shelves[0].boxes[0]
    m.racks[0].shelves[0].boxes[0] = MapBox(b.id, b.center, b.size, math.pi / 2, b.confidence, b.observations)
    fs = free_space(m)[0]
    # Turned 90 degrees the 0.5 x 0.6 box spans [-0.05, 0.55] along X; only its part on the shelf counts.
    assert fs.free_length == pytest.approx(0.5 - 0.05, abs=1e-9)
    clear = 2.0 - 2 * UPRIGHT_INSET
    assert fs.free_area == pytest.approx(clear - (0.55 - UPRIGHT_INSET) * 0.5 - (1.0 - UPRIGHT_INSET) * 0.8)


def test_reconstruct_into_a_run_folder_keeps_its_layouts(tiny_dataset, tmp_path):
    """Re-stitching OUT/layouts into OUT itself must not delete the layouts it reads."""
    import shutil

    from mvracklay.cli import main

    seq = tiny_dataset / "seq_00000"
    out = tmp_path / "run"
    shutil.copytree(seq / "layouts", out / "layouts")
    before = sorted(p.name for p in (out / "layouts").iterdir())
    assert main(["reconstruct", str(out / "layouts"), "--out", str(out), "--no-rrd", "--quiet"]) == 0
    assert sorted(p.name for p in (out / "layouts").iterdir()) == before
    assert (out / "warehouse.json").is_file() and (out / "warehouse.glb").is_file()
    assert not any(p.name.startswith(".") for p in tmp_path.iterdir())
