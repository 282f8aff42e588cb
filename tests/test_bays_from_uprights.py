"""Bays from upright frames: the per-frame upright vote along X, its place in warehouse.json, and a face's bays cut
at the fused uprights with the bay-width prior."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from layouts.errors import InputError
from layouts.spec import LayoutSpec
from stitching.building.fuse_passes import _split_at_uprights
from stitching.building.place import PlacedBox, PlacedPass, PlacedRack
from stitching.building.route import PassPose
from stitching.uprights import Upright, UprightStrip, bay_cuts, fuse_uprights
from stitching.warehouse_map import WarehouseMap


def test_strip_peaks_where_most_frames_mark():
    strip = UprightStrip(0.05)
    cols = np.zeros(40, bool)
    cols[10:12] = True
    strip.add(cols, 0.0, 0, 40)  # column 10 at X 0.5
    strip.add(np.roll(cols, -2), 0.1, 0, 40)  # the camera moved 0.1 m: the same upright two columns left
    once = np.zeros(40, bool)
    once[30] = True  # marked by one frame of three: no upright
    strip.add(once, 0.0, 0, 40)
    peaks = strip.peaks()
    assert len(peaks) == 1
    assert peaks[0].x == pytest.approx(0.55, abs=0.03)
    assert peaks[0].support == pytest.approx(2 / 3, abs=0.01)


def test_strip_refuses_bad_columns():
    with pytest.raises(InputError):
        UprightStrip(0.05).add(np.zeros((2, 3), bool), 0.0, 0, 3)
    with pytest.raises(InputError):
        UprightStrip(0.0)


def _map_doc() -> dict:
    return {"format": "mvracklay-warehouse-map", "racks": [], "steps": [], "board_thickness": 0.06}


def test_map_keeps_uprights_and_old_maps_load(tmp_path):
    m = WarehouseMap([], [], 0.06, uprights=[(1.25, 0.9), (3.5, 0.75)])
    m.save(tmp_path / "w.json")
    doc = json.loads((tmp_path / "w.json").read_text())
    assert doc["uprights"] == [[1.25, 0.9], [3.5, 0.75]]
    assert WarehouseMap.load(tmp_path / "w.json").uprights == [(1.25, 0.9), (3.5, 0.75)]
    del doc["uprights"]  # a map written before uprights were recorded
    (tmp_path / "old.json").write_text(json.dumps(doc))
    assert WarehouseMap.load(tmp_path / "old.json").uprights == []
    assert "uprights" not in WarehouseMap([], [], 0.06).to_dict()  # nothing marked: written as before
    doc["uprights"] = [[1.0, 1.5]]  # support is a share
    (tmp_path / "bad.json").write_text(json.dumps(doc))
    with pytest.raises(InputError, match="uprights"):
        WarehouseMap.load(tmp_path / "bad.json")


def test_bay_cuts_use_the_width_prior():
    ups = [Upright(2.0, 0.9), Upright(4.0, 0.9), Upright(4.9, 0.4), Upright(6.0, 0.9)]
    cuts = bay_cuts(0.0, 8.0, ups, None)
    assert [x for x, _ in cuts] == [2.0, 4.0, 4.9, 6.0]
    cuts = bay_cuts(0.0, 8.0, ups, 2.0)  # 4.9 leaves 0.9 m and 1.1 m: two half bays, one false upright
    assert [x for x, _ in cuts] == [2.0, 4.0, 6.0]
    assert all(ok for _, ok in cuts)
    weak = bay_cuts(0.0, 8.0, [Upright(2.0, 0.3), Upright(4.0, 0.9)], 2.0)
    assert weak == [(2.0, False), (4.0, False)]  # low support; the last bay is 4 m, twice the typical width
    assert bay_cuts(0.0, 8.0, [Upright(0.1, 1.0), Upright(7.9, 1.0)], 2.0) == []  # the stretch's own ends


def test_fuse_uprights_joins_passes():
    fused = fuse_uprights([[Upright(1.0, 1.0), Upright(3.0, 0.8)], [Upright(1.06, 0.6)]])
    assert len(fused) == 2
    assert fused[0].x == pytest.approx((1.0 * 1.0 + 1.06 * 0.6) / 1.6)
    assert fused[0].support == pytest.approx(0.8)


def _pass(name: str, x0: float, rack: tuple[float, float], ups: list[Upright]) -> PlacedPass:
    boxes = [PlacedBox(1, x, 0.4, 0.2, (0.4, 0.4, 0.4), 0.0, 0.9, 5, None) for x in (0.5, 2.5, 4.5)]
    return PlacedPass(PassPose(name, 1, "R", x0, 0.0, 90.0), x0, [PlacedRack(*rack, False, False, [], boxes)], [rack],
                      0.06, 1.0, uprights=ups)  # fmt: skip


def test_touching_bays_split_at_uprights_over_passes():
    # one run of three 2 m bays (frames at 0, 2, 4, 6), seen by two passes as one rack each; each pass found
    # some of the inner frames, together all
    a = _pass("a", 0.0, (0.0, 6.0), [Upright(0.0, 1.0), Upright(2.0, 0.9)])
    b = _pass("b", 1.0, (-1.0, 5.0), [Upright(3.02, 0.8), Upright(5.0, 1.0)])
    groups = [[(a, a.racks[0]), (b, b.racks[0])]]
    bays, uncertain = _split_at_uprights(groups, [a, b])
    spans = [sorted({(round(r.lo + p.offset, 2), round(r.hi + p.offset, 2)) for p, r in g}) for g in bays]
    assert len(bays) == 3
    assert spans[0] == [(0.0, 2.0)]
    assert spans[2][0][0] == pytest.approx(4.0, abs=0.02)
    assert [len({id(bx) for _, r in g for bx in r.boxes}) for g in bays] == [2, 2, 2]  # each pass's box once
    assert uncertain == []  # well supported, the three bays alike
    assert _split_at_uprights(groups, [_pass("c", 0.0, (0.0, 6.0), [])]) == (groups, [])  # no uprights: as found
    weak = _pass("d", 0.0, (0.0, 6.0), [Upright(2.0, 0.9), Upright(4.0, 0.3)])  # one frame barely seen
    bays, uncertain = _split_at_uprights([[(weak, weak.racks[0])]], [weak])
    assert len(bays) == 3 and uncertain == [pytest.approx(4.0)]


def test_an_uncertain_boundary_is_kept_in_the_map_and_reaches_the_recount(tiny_building_map, monkeypatch):
    import stitching.building.map as building_map

    bmap = building_map.BuildingMap.load(tiny_building_map / "building.json")
    face = bmap.faces[1]
    rack = min(face.map.racks, key=lambda r: r.x_range[0])
    cut = rack.x_range[1]  # its boundary with the next bay, found at an upright with little certainty
    flagged = replace(bmap, faces=[bmap.faces[0], replace(face, uncertain_cuts=(cut,)), *bmap.faces[2:]])
    again = building_map.BuildingMap.from_dict(flagged.to_dict())
    assert again.faces[1].uncertain_cuts == (pytest.approx(cut),)
    assert all("uncertain_cuts" not in f for f in bmap.to_dict()["faces"])  # none found: the file as before
    given = []
    real = building_map.uncertain_bays

    def spy(racks, *args, cuts=(), **kw):
        given.append(list(cuts))
        return real(racks, *args, cuts=cuts, **kw)

    monkeypatch.setattr(building_map, "uncertain_bays", spy)
    again.inventory()
    with_cut = [c for c in given if c]
    assert (
        len(given) == len(bmap.faces)
        and len(with_cut) == 1
        and all(c == [(pytest.approx(cut), False)] for c in with_cut)
    )
    assert rack.id in real(face.map.racks, cuts=[(cut, False)])


def test_gt_upright_columns_mark_rack_ends(tmp_path):
    from mvracklay.reconstruction import gt_upright_columns

    spec = LayoutSpec(size=128)
    (tmp_path / "scene.json").write_text(json.dumps({"racks": [{"x_min": 0.0, "x_max": 2.0}]}))
    (tmp_path / "meta.json").write_text(json.dumps({"frames": [{"index": 0, "camera_position": [1.0, 0, 0]}]}))
    cols = gt_upright_columns(tmp_path, spec.size, spec.x_extent)[0]
    xs = spec.col_to_x(np.flatnonzero(cols) + 0.5) + 1.0
    assert cols.sum() == 6
    assert set(np.round(xs).astype(int)) == {0, 2}
    assert gt_upright_columns(tmp_path / "none", spec.size, spec.x_extent) == {}


def test_network_upright_columns_threshold_and_resample():
    import torch

    from mvracklay.pipeline import upright_columns

    logits = torch.full((2, 8), -5.0)
    logits[0, 2] = 3.0  # a front upright in canonical column 2 of 8
    logits[1, 5] = 3.0  # a rear one: not the stitcher's
    logits[0, 7] = -0.1  # under the head's threshold
    cols = upright_columns(logits, 16)
    assert cols.dtype == bool and cols.shape == (16,)
    assert np.flatnonzero(cols).tolist() == [4, 5]  # canonical column 2 covers layout columns 4-5
    assert np.flatnonzero(upright_columns(logits[None], 4)).tolist() == [1]  # batch of one, coarser layouts
    assert upright_columns(None, 16) is None
    with pytest.raises(InputError, match="upright head output"):
        upright_columns(torch.zeros(3, 8), 16)


def test_network_uprights_reach_the_row_map(monkeypatch):
    """The run's row map (`mvracklay.pipeline.RunSinks.map`) pushes the frame's upright columns to the stitcher."""
    import types

    import torch

    from mvracklay import pipeline

    seen = {}

    class Stub:
        spec = types.SimpleNamespace(size=16)

        def push(self, layouts, index, uprights=None):
            seen["uprights"] = uprights
            raise StopIteration

    logits = torch.full((2, 16), -5.0)
    logits[0, 3] = 2.0
    frame = types.SimpleNamespace(layouts=None, index=0, prediction=types.SimpleNamespace(maps={"uprights": logits}))
    with pytest.raises(StopIteration):
        pipeline.RunSinks(None, Stub(), None, None).map(frame)
    assert np.flatnonzero(seen["uprights"]).tolist() == [3]
