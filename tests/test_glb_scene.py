"""The .glb scene: rack -> shelf -> box nesting and names, extras, uprights and beams, colours
(from a synthetic frame with known box colours through `stitching.box_colours`), the cuboid round trip."""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image, ImageDraw

from layouts import InputError, Intrinsics
from layouts.canonical import CanonicalView, camera_rotation
from stitching.box_colours import BoxColours, assign_colours, robust_mean
from stitching.export_gltf import (
    BEAM_HEIGHT,
    DEFAULT_BOX_COLOUR,
    RACK_COLOURS,
    export_glb,
    glb_json,
    load_glb_cuboid_bounds,
    map_cuboids,
    srgb_to_linear,
)
from stitching.free_space import shelf_free_space
from stitching.lift import FrameBox, FrameReconstruction, FrameShelf
from stitching.warehouse_map import MapBox, MapRack, MapShelf, StepRecord, WarehouseMap

T = 0.06  # board thickness


def _shelf(rack: int, slot: int, board: float, x: tuple[float, float], boxes: list[MapBox]) -> MapShelf:
    return MapShelf(f"rack_{rack:02d}/shelf_{slot:02d}", slot, board, 0.74, x, (-0.5, 0.5), 0.9, boxes)


def _box(shelf: str, i: int, x0: float, x1: float, board: float, h: float, z=(-0.45, 0.05), colour=None) -> MapBox:
    centre = ((x0 + x1) / 2, -(board + h / 2), (z[0] + z[1]) / 2)
    return MapBox(f"{shelf}/box_{i:03d}", centre, (x1 - x0, h, z[1] - z[0]), 0.0, 0.8, 5, colour)


def _two_racks() -> WarehouseMap:
    a0 = _shelf(0, 0, 0.0, (0.0, 2.0), [])
    a0.boxes = [_box(a0.id, 0, 0.2, 0.8, 0.0, 0.4, colour=(200, 30, 30)), _box(a0.id, 1, 1.0, 1.5, 0.0, 0.3)]
    a1 = _shelf(0, 1, 0.8, (0.0, 2.0), [])
    a1.boxes = [_box(a1.id, 0, 0.5, 1.2, 0.8, 0.5, colour=(20, 40, 220))]
    b0 = _shelf(1, 0, 0.0, (2.5, 4.0), [])
    racks = [MapRack("rack_00", (0.0, 2.0), [a0, a1]), MapRack("rack_01", (2.5, 4.0), [b0])]
    # partial flags as the map may carry them (read with getattr, so maps without them work too)
    racks[1].partial = b0.partial = "end"
    return WarehouseMap(racks, [StepRecord(0, 0.0, 0.0, 0, 1.0, "first", 0)], T)


@pytest.fixture()
def glb(tmp_path):
    wmap = _two_racks()
    path = tmp_path / "w.glb"
    n = export_glb(wmap, path)
    return wmap, path, n, glb_json(path)


def _nodes(doc: dict) -> dict[str, dict]:
    return {n["name"]: n for n in doc["nodes"]}


def _children(doc: dict, node: dict) -> list[str]:
    return [doc["nodes"][i]["name"] for i in node.get("children", [])]


def test_nodes_nest_rack_shelf_box_with_unique_stable_names(glb):
    wmap, _, n, doc = glb
    names = [x["name"] for x in doc["nodes"]]
    assert len(names) == len(set(names))
    assert [doc["nodes"][i]["name"] for i in doc["scenes"][0]["nodes"]] == ["rack_00", "rack_01"]
    nodes = _nodes(doc)
    assert "mesh" not in nodes["rack_00"]
    assert _children(doc, nodes["rack_00"]) == [f"rack_00/upright_{i:02d}" for i in range(4)] + [
        "rack_00/shelf_00",
        "rack_00/shelf_01",
    ]
    assert _children(doc, nodes["rack_00/shelf_00"]) == [
        "rack_00/shelf_00/beam_front",
        "rack_00/shelf_00/beam_back",
        "rack_00/shelf_00/box_000",
        "rack_00/shelf_00/box_001",
    ]
    assert all(nodes[s.id].get("mesh") is not None for s in wmap.shelves())
    assert n == sum(1 for x in doc["nodes"] if "mesh" in x) == len(map_cuboids(wmap))
    assert all("matrix" not in x and "translation" not in x for x in doc["nodes"])  # identity transforms


def test_extras_of_racks_shelves_and_boxes(glb):
    wmap, _, _, doc = glb
    nodes = _nodes(doc)
    assert nodes["rack_00"]["extras"]["partial"] is None and nodes["rack_01"]["extras"]["partial"] == "end"
    assert nodes["rack_01"]["extras"]["x_range"] == [2.5, 4.0]
    for s in wmap.shelves():
        e, fs = nodes[s.id]["extras"], shelf_free_space(s)
        assert e["id"] == s.id and e["slot"] == s.slot and e["boxes"] == len(s.boxes)
        assert e["free_length"] == pytest.approx(fs.free_length, abs=1e-4)
        assert e["free_fraction"] == pytest.approx(fs.free_length / fs.length, abs=1e-4)
        assert e["partial"] == getattr(s, "partial", None)
        assert e["clear_length"] == pytest.approx(fs.length, abs=1e-4) and e["occupancy"] == pytest.approx(
            fs.occupancy, abs=1e-4
        )
    # 2 m inside the uprights (0.11 m each end), boxes over 0.6 m and 0.5 m of it
    assert nodes["rack_00/shelf_00"]["extras"]["free_length"] == pytest.approx(2.0 - 0.22 - 0.6 - 0.5)
    for b in wmap.boxes():
        e = nodes[b.id]["extras"]
        assert e["id"] == b.id and e["size"] == pytest.approx(list(b.size), abs=1e-4)
        assert e["confidence"] == pytest.approx(b.confidence) and e["observations"] == b.observations
        assert e["colour_source"] == ("frames" if b.colour else "default")
        assert tuple(e["colour"]) == (b.colour or DEFAULT_BOX_COLOUR)
    assert "partial" in nodes["rack_00/shelf_00/box_000"]["extras"]


def test_uprights_and_beams_per_rack(glb):
    wmap, path, _, _ = glb
    got = load_glb_cuboid_bounds(path)
    for rack in wmap.racks:
        ups = sorted(k for k in got if k.startswith(rack.id + "/upright_"))
        beams = sorted(k for k in got if k.startswith(rack.id + "/") and "/beam_" in k)
        assert len(beams) == 2 * len(rack.shelves)
        # 2 uprights at each end, none at an end where a partial rack is cut
        want = {None: ["00", "01", "02", "03"], "end": ["00", "01"], "start": ["02", "03"]}[
            getattr(rack, "partial", None)
        ]
        assert ups == [f"{rack.id}/upright_{i}" for i in want]
        lo_x, hi_x = rack.x_range
        for k in ups:  # inside the rack's footprint, from under the lowest board to the top shelf's top
            v = got[k]
            assert lo_x - 1e-6 <= v[:, 0].min() and v[:, 0].max() <= hi_x + 1e-6
            assert v[:, 1].max() == pytest.approx(T + BEAM_HEIGHT, abs=1e-5)
            assert v[:, 1].min() == pytest.approx(-max(s.board_height + s.clear_height for s in rack.shelves), abs=1e-5)
        for s in rack.shelves:  # beams run the rack's length just under the board
            v = got[s.id + "/beam_front"]
            assert v[:, 0].min() == pytest.approx(lo_x, abs=1e-5) and v[:, 0].max() == pytest.approx(hi_x, abs=1e-5)
            assert v[:, 1].min() == pytest.approx(-s.board_height + T, abs=1e-5)
            assert v[:, 2].min() == pytest.approx(s.z_range[0], abs=1e-5)


def test_materials_opaque_pbr_with_box_and_rack_colours(glb):
    wmap, _, _, doc = glb
    mats = doc["materials"]
    by_node = {
        x["name"]: mats[doc["meshes"][x["mesh"]]["primitives"][0]["material"]] for x in doc["nodes"] if "mesh" in x
    }
    for name, m in by_node.items():
        pbr = m["pbrMetallicRoughness"]
        assert pbr["baseColorFactor"][3] == 1.0 and pbr["metallicFactor"] == 0.0
        assert m.get("alphaMode", "OPAQUE") == "OPAQUE"
        kind = (
            "box" if "/box_" in name else "beam" if "/beam_" in name else "upright" if "/upright_" in name else "shelf"
        )
        b = next((b for b in wmap.boxes() if b.id == name), None)
        srgb = (b.colour or DEFAULT_BOX_COLOUR) if b is not None else RACK_COLOURS[kind]
        assert np.allclose(pbr["baseColorFactor"][:3], srgb_to_linear(srgb), atol=1.5 / 255)


def test_cuboid_bounds_round_trip_and_same_bytes(glb, tmp_path):
    wmap, path, _, _ = glb
    got = load_glb_cuboid_bounds(path)
    items = map_cuboids(wmap)
    assert set(got) == {name for name, _, _ in items}
    for name, _, c in items:
        assert np.allclose(np.sort(got[name], axis=0), np.sort(c.corners(), axis=0), atol=1e-5)
    for b in wmap.boxes():
        assert np.allclose(got[b.id].mean(0), b.center, atol=1e-5)
    export_glb(wmap, tmp_path / "again.glb")
    assert (tmp_path / "again.glb").read_bytes() == path.read_bytes()


def test_a_rack_cut_at_both_ends_has_no_uprights(tmp_path):
    wmap = _two_racks()
    wmap.racks[0].partial = "both"
    export_glb(wmap, tmp_path / "b.glb")
    names = set(load_glb_cuboid_bounds(tmp_path / "b.glb"))
    assert not {k for k in names if k.startswith("rack_00/upright_")}
    assert {"rack_00/shelf_00/beam_front", "rack_01/upright_00"} <= names


def test_a_map_without_shelves_is_an_empty_scene(tmp_path):
    wmap = WarehouseMap([MapRack("rack_00", (0.0, 1.0), [])], [], T)
    assert export_glb(wmap, tmp_path / "e.glb") == 0
    assert "nodes" not in glb_json(tmp_path / "e.glb")
    (tmp_path / "bad.glb").write_bytes(b"nope")
    with pytest.raises(InputError, match="not a binary glTF"):
        glb_json(tmp_path / "bad.glb")


def test_box_colour_json_round_trip_and_old_maps(tmp_path):
    wmap = _two_racks()
    back = WarehouseMap.from_dict(wmap.to_dict())
    assert [b.colour for b in back.boxes()] == [(200, 30, 30), None, (20, 40, 220)]
    d = wmap.to_dict()
    assert "colour" not in d["racks"][0]["shelves"][0]["boxes"][1]  # unseen: nothing written, as before
    d["racks"][0]["shelves"][0]["boxes"][0]["colour"] = [1, 2, 300]
    with pytest.raises(InputError, match="colour must be three integers"):
        WarehouseMap.from_dict(d)


# ----------------------------------------------------------------------------- colours from frames
INTR = Intrinsics.from_fov(320, 240, 60.0)
VIEW = CanonicalView(128, 96, 3.0)
DIST = 2.6
Y_BOARD = (0.9, 0.1)  # slot 0's and slot 1's board tops, metres below the optical axis
CAMERA_X = 1.0
#: (slot, x0, x1, z0 (front), height, colour) in the frame's coordinates; the last hides behind the second
FACES = [
    (0, -0.9, -0.3, -0.45, 0.4, (200, 30, 30)),
    (0, 0.1, 0.7, -0.5, 0.3, (30, 180, 40)),
    (1, -0.4, 0.4, -0.3, 0.5, (20, 40, 220)),
    (0, 0.15, 0.65, 0.1, 0.25, (250, 250, 0)),
]


def _render(angles=(0.0, 0.0, 0.0)) -> np.ndarray:
    """The frame: each box's front face filled with its colour, drawn far to near (a pinhole camera)."""
    img = Image.new("RGB", (INTR.width, INTR.height), (128, 128, 128))
    draw = ImageDraw.Draw(img)
    rot = camera_rotation(*angles)
    for slot, x0, x1, z0, h, colour in sorted(FACES, key=lambda f: -f[3]):
        depth = DIST + (z0 - -0.5)
        y0 = Y_BOARD[slot]
        corners = np.array([[x0, y0, depth], [x1, y0, depth], [x1, y0 - h, depth], [x0, y0 - h, depth]])
        uv = INTR.project(corners @ rot)  # rows: R^T p, the level camera's point in the turned camera
        draw.polygon([tuple(p) for p in uv], fill=colour)
    return np.asarray(img)


def _frame_rec() -> FrameReconstruction:
    shelves = [FrameShelf(r, True, Y_BOARD[0] - Y_BOARD[r], 0.74, (-0.5, 0.5), [], np.ones(8, bool)) for r in (0, 1)]
    boxes = [
        FrameBox(s, (a + b) / 2, z0 + 0.2, b - a, 0.4, 0.0, h, a, b, z0, z0 + 0.4, False, False, 1.0, "top+front")
        for s, a, b, z0, h, _ in FACES
    ]
    return FrameReconstruction(shelves, boxes, 0, 8)


def _face_map() -> WarehouseMap:
    shelves = [_shelf(0, r, Y_BOARD[0] - Y_BOARD[r], (-1.0, 3.0), []) for r in (0, 1)]
    for i, (s, a, b, z0, h, _) in enumerate(FACES):
        board = shelves[s].board_height
        shelves[s].boxes.append(_box(shelves[s].id, i, a + CAMERA_X, b + CAMERA_X, board, h, (z0, z0 + 0.4)))
    return WarehouseMap([MapRack("rack_00", (-1.0, 3.0), shelves)], [], T)


def _anchors() -> np.ndarray:
    return np.array([VIEW.row_of(y) for y in Y_BOARD] + [np.nan])  # a third slot the frame does not have


@pytest.mark.parametrize("angles", [(0.0, 0.0, 0.0), (12.0, -3.0, -6.0)])
def test_box_colours_from_a_frame_with_known_box_colours(angles):
    colours = BoxColours(VIEW)
    for _ in range(3):
        colours.keep(_render(angles))
    for _ in range(3):
        assert colours.add(_frame_rec(), CAMERA_X, _anchors(), INTR, DIST, angles) == 3  # the hidden box: no sample
    wmap = _face_map()
    assert colours.paint(wmap) == 3
    got = {int(b.id[-3:]): b.colour for b in wmap.boxes()}  # box_00i is FACES[i]
    for i, (*_, want) in enumerate(FACES[:3]):
        assert got[i] is not None and np.abs(np.subtract(got[i], want)).max() <= 2, (i, got[i], want)
    assert got[3] is None  # never seen: the default colour in the .glb
    if any(angles):  # the camera's rotation matters: sampled as if level, the faces miss
        level = BoxColours(VIEW)
        level.keep(_render(angles))
        level.add(_frame_rec(), CAMERA_X, _anchors(), INTR, DIST)
        wrong = _face_map()
        level.paint(wrong)
        assert [b.colour for b in wrong.boxes()] != [b.colour for b in wmap.boxes()]


def test_box_colours_from_a_larger_frame_downsized():
    big = np.asarray(Image.fromarray(_render()).resize((960, 720), Image.NEAREST))
    colours = BoxColours(VIEW)
    colours.keep(big)
    assert colours.add(_frame_rec(), CAMERA_X, _anchors(), INTR, DIST) == 3  # intrinsics scaled to the frame
    wmap = _face_map()
    colours.paint(wmap)
    assert np.abs(np.subtract(wmap.boxes()[0].colour, FACES[0][5])).max() <= 2


def test_a_bounded_sample_history_keeps_the_newest_per_place_and_paints_the_same(monkeypatch):
    import stitching.box_colours as box_colours

    monkeypatch.setattr(box_colours, "COMPACT_ROWS", 12)
    frame = _render()
    whole, bounded = BoxColours(VIEW), BoxColours(VIEW, per_place=4)
    for colours in (whole, bounded):
        for _ in range(40):  # the same boxes seen 40 times (a camera walking back and forth)
            colours.keep(frame)
            assert colours.add(_frame_rec(), CAMERA_X, _anchors(), INTR, DIST) == 3
    assert len(whole.samples()) == 120
    assert len(bounded.samples()) < 3 * 4 + 12  # 3 places: 4 samples each, and those since the last compaction
    a, b = _face_map(), _face_map()
    whole.paint(a)
    bounded.paint(b)
    assert [x.colour for x in a.boxes()] == [x.colour for x in b.boxes()]
    newest = BoxColours(VIEW, per_place=1)
    rows = [[0, 0.1, 0.7, -0.45, -0.05, c, c, c] for c in range(20)]
    newest._rows, newest._new = [np.array(rows, float)], 20
    newest._compact()
    assert newest.samples().tolist() == [rows[-1]]  # one place: its newest sample
    for bad in (0, -1, 2.5, True):
        with pytest.raises(InputError, match="per_place"):
            BoxColours(VIEW, per_place=bad)


def test_samples_go_to_the_overlapping_box_of_their_slot_and_outliers_are_dropped():
    wmap = _face_map()
    #       slot  x0   x1   z0    z1   r    g    b
    rows = [[0, 0.1, 0.7, -0.45, -0.05, 10, 10, 10]] * 4 + [[0, 0.1, 0.7, -0.45, -0.05, 250, 0, 0]]
    rows += [[1, 0.1, 0.7, -0.45, -0.05, 99, 99, 99]]  # slot 1 has no box there
    got = assign_colours(wmap, np.array(rows, float))
    assert got == {"rack_00/shelf_00/box_000": (10, 10, 10)}
    assert robust_mean(np.array([[100, 100, 100], [104, 100, 96], [0, 255, 0]], float)) == (102, 100, 98)
