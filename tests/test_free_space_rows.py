"""Rows that mean what they say: free length inside the uprights, occupancy as a length share, and `free-space`
placements clear of uprights and boxes, only at locations the map has."""

from __future__ import annotations

import json
from dataclasses import replace

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from stitching.building.free import LocationFit, building_fits, format_fits
from stitching.building.free_space_eval import evaluate_fits
from stitching.building.map import BuildingMap, FaceMap, Location
from stitching.free_space import (
    NETWORK_EDGE_SLACK,
    UPRIGHT_INSET,
    UPRIGHT_WIDTH,
    clear_span,
    edge_slack,
    fits,
    free_space,
    shelf_free_space,
)
from stitching.warehouse_map import MapBox, MapRack, MapShelf, StepRecord, WarehouseMap


def _box(i: int, x0: float, x1: float, depth: float = 0.6, shelf: str = "rack_00/shelf_00") -> MapBox:
    return MapBox(f"{shelf}/box_{i:03d}", ((x0 + x1) / 2, -0.2, 0.0), (x1 - x0, 0.4, depth), 0.0, 0.9, 3)


def _row(length: float, boxes: list[MapBox], partial: str | None = None) -> WarehouseMap:
    shelf = MapShelf("rack_00/shelf_00", 0, 0.0, 0.9, (0.0, length), (-0.5, 0.5), 1.0, boxes, partial)
    rack = MapRack("rack_00", (0.0, length), [shelf], partial)
    return WarehouseMap([rack], [StepRecord(0, 0, 0, 0, 1, "first", 0)], 0.05)


def test_free_length_is_the_clear_span_between_uprights():
    (empty,) = free_space(_row(2.0, []))
    assert empty.length == pytest.approx(2.0 - 2 * UPRIGHT_INSET) and UPRIGHT_INSET > UPRIGHT_WIDTH
    assert empty.free_length == pytest.approx(empty.length) and empty.gaps == [pytest.approx((0.11, 1.89))]
    assert empty.occupancy == 0 and empty.free_area == pytest.approx(empty.length * 1.0)
    (one,) = free_space(_row(2.0, [_box(0, 0.5, 1.0)]))
    assert one.free_length == pytest.approx(2.0 - 2 * UPRIGHT_INSET - 0.5)
    assert one.gaps == [pytest.approx((UPRIGHT_INSET, 0.5)), pytest.approx((1.0, 2.0 - UPRIGHT_INSET))]
    # A box standing against the upright leaves no gap there; nothing past the upright is ever free.
    (wall,) = free_space(_row(2.0, [_box(0, 0.0, 0.6)]))
    assert wall.gaps == [pytest.approx((0.6, 2.0 - UPRIGHT_INSET))]
    # A rack cut at its high end: no upright seen there, the gap running to the cut is unknown, not free.
    (cut,) = free_space(_row(2.0, [_box(0, 0.5, 1.0)], partial="end"))
    assert clear_span(_row(2.0, [], "end").shelves()[0]) == pytest.approx((UPRIGHT_INSET, 2.0))
    assert cut.unknown == [pytest.approx((1.0, 2.0))] and cut.free_length == pytest.approx(0.5 - UPRIGHT_INSET)


def test_occupancy_is_the_length_share_under_boxes():
    # A shallow box (0.2 of the 1 m depth) over 0.5 m: half a metre of the clear length is under a box.
    (fs,) = free_space(_row(1.22, [_box(0, 0.3, 0.8, depth=0.2)]))
    assert fs.length == pytest.approx(1.0)
    assert fs.occupancy == pytest.approx(0.5)  # an area share would be 0.1
    assert fs.free_area == pytest.approx(1.0 - 0.5 * 0.2)
    # Two overlapping boxes count their union once; the share never passes 1.
    (full,) = free_space(_row(1.22, [_box(0, 0.0, 0.8), _box(1, 0.5, 1.22)]))
    assert full.occupancy == pytest.approx(1.0) and full.free_length == 0


def _positions(boxes_1: list[MapBox], boxes_2: list[MapBox]) -> WarehouseMap:
    """One rack (0..2 m) whose level is cut in two positions, as a building map's locations are."""
    s1 = MapShelf("01-R-01-01-1", 0, 0.0, 0.9, (0.0, 1.0), (-0.5, 0.5), 1.0, boxes_1)
    s2 = MapShelf("01-R-01-01-2", 0, 0.0, 0.9, (1.0, 2.0), (-0.5, 0.5), 1.0, boxes_2)
    return WarehouseMap([MapRack("01-R-01", (0.0, 2.0), [s1, s2])], [], 0.05)


def test_positions_share_their_level_s_boxes_and_only_rack_ends_are_uprights():
    wmap = _positions([_box(0, 0.7, 1.3, shelf="01-R-01-01-1")], [])
    rack = wmap.racks[0]
    p1, p2 = (shelf_free_space(s, rack) for s in rack.shelves)
    assert p1.length == pytest.approx(1.0 - UPRIGHT_INSET) and p2.length == pytest.approx(1.0 - UPRIGHT_INSET)
    assert p1.gaps == [pytest.approx((UPRIGHT_INSET, 0.7))]
    # The box of position 1 standing over the boundary blocks position 2 too.
    assert p2.gaps == [pytest.approx((1.3, 2.0 - UPRIGHT_INSET))] and p2.occupancy == pytest.approx(0.3 / p2.length)
    for f in fits(wmap, 0.3, 0.3, 0.3):
        for c0, c1 in f.centres:
            assert c0 - 0.15 >= 1.3 - 1e-9 or c1 + 0.15 <= 0.7 + 1e-9


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    length=st.floats(0.3, 4.0),
    spans=st.lists(st.tuples(st.floats(-0.2, 4.2), st.floats(0.05, 1.2), st.floats(-1.0, 1.0)), max_size=6),
    carton=st.tuples(st.floats(0.05, 1.5), st.floats(0.05, 0.9)),
    margin=st.floats(0.0, 0.1),
    partial=st.sampled_from([None, "start", "end", "both"]),
)
def test_placements_never_touch_an_upright_or_a_box(length, spans, carton, margin, partial):
    boxes = [
        MapBox(f"rack_00/shelf_00/box_{i:03d}", (x, -0.2, 0.0), (w, 0.4, 0.5), yaw, 0.9, 3)
        for i, (x, w, yaw) in enumerate(spans)
    ]
    wmap = _row(length, boxes, partial)
    blocked = [b.cuboid.x_range() for b in boxes]
    cut_lo, cut_hi = partial in ("start", "both"), partial in ("end", "both")
    w, d = carton
    found = fits(wmap, w, d, 0.3, margin)
    for f in found:
        for c0, c1 in f.centres:
            assert c0 <= c1
            lo, hi = c0 - f.along_x / 2 - margin, c1 + f.along_x / 2 + margin  # every centre's box and margin
            assert (
                lo >= (0.0 if cut_lo else UPRIGHT_INSET) - 1e-9
                and hi <= length - (0 if cut_hi else UPRIGHT_INSET) + 1e-9
            )
            assert all(hi <= a + 1e-9 or lo >= b - 1e-9 for a, b in blocked), (lo, hi, blocked)
            if cut_lo or cut_hi:  # never in the unknown gap running to a cut end: next to a box or an upright
                assert (not cut_lo or any(lo >= b - 1e-9 for _, b in blocked)) and (
                    not cut_hi or any(hi <= a + 1e-9 for a, _ in blocked)
                )
    # And it does offer a place wherever one is free of everything: the property is not vacuous.
    if not boxes and partial is None and w + 2 * margin <= length - 2 * UPRIGHT_INSET and d <= 1.0:
        assert found and not found[0].rotated


def _building(scanned: bool = True) -> BuildingMap:
    wmap = _row(2.0, [_box(0, 0.5, 1.0, shelf="01-R-01-01")])
    shelf = wmap.racks[0].shelves[0]
    wmap.racks[0] = replace(wmap.racks[0], id="01-R-01")
    shelf.id = "01-R-01-01"
    loc = Location("01-R-01-01", 1, "R", 1, 1, 1, ["p0"] if scanned else [], 1.0 if scanned else 0.0)
    return BuildingMap([FaceMap(1, "R", 1.0, wmap, {"01-R-01-01": loc}, {"01-R-01": 1})], [])


def test_building_rows_and_placements_are_the_map_s_own_locations():
    bmap = _building()
    (row,) = bmap.inventory()
    assert row["free_length_m"] == pytest.approx(2.0 - 2 * UPRIGHT_INSET - 0.5, abs=1e-4)
    assert row["occupancy"] == pytest.approx(0.5 / (2.0 - 2 * UPRIGHT_INSET), abs=1e-4)
    found = building_fits(bmap, 0.3, 0.3, 0.3, margin=0.02)
    assert [f.location for f in found] == ["01-R-01-01"] and found[0].along_x == pytest.approx(0.3)
    assert found[0].centres[0][0] == pytest.approx(UPRIGHT_INSET + 0.02 + 0.15)
    # A shelf whose location record holds another code is never offered under its own id.
    face = bmap.faces[0]
    extra = MapShelf("01-R-02-01", 0, 0.0, 0.9, (2.1, 4.1), (-0.5, 0.5), 1.0, [])
    face.map.racks.append(MapRack("01-R-02", (2.1, 4.1), [extra]))
    face.locations["01-R-02-01"] = Location("01-R-02-09", 1, "R", 2, 1, 1, ["p0"], 1.0)
    assert [f.location for f in building_fits(bmap, 0.3, 0.3, 0.3)] == ["01-R-01-01"]
    assert building_fits(_building(scanned=False), 0.3, 0.3, 0.3) == []  # not scanned: never offered


def test_placements_checked_against_the_ground_truth(tiny_building, tiny_building_map):
    truth = json.loads((tiny_building / "ground_truth/building.json").read_text())
    bmap = BuildingMap.load(tiny_building_map / "building.json")
    found = building_fits(bmap, 0.3, 0.3, 0.2, margin=0.02)
    ev = evaluate_fits(found, truth)
    assert ev.offered == len(found) > 5 and ev.share == 1.0 and ev.invented == ev.into_upright == ev.onto_box == 0
    # The check itself fails what does not fit: a code the building lacks, a box into the upright, onto a box.
    f = found[0]
    rack = next(r for r in truth["racks"] if f.location.startswith(r["id"]))
    x0 = min(rack["x_min"], rack["x_max"])
    bad = [
        replace(f, location="09-R-99-09"),
        replace(f, centres=[(x0 + 0.05, x0 + 0.05)]),
    ]
    stack = next((b for r in truth["racks"] for lv in r["levels"] for p in lv["positions"] for b in p["boxes"]), None)
    if stack is not None:
        code = stack["id"].split("/")[0]
        bad.append(LocationFit(code, False, 0.3, [(stack["center"][0], stack["center"][0])], 0.0, None, 1.0))
    ev = evaluate_fits(bad, truth)
    assert ev.invented == 1 and ev.into_upright >= 1 and ev.fit == 0 and ev.onto_box == (stack is not None)


def test_a_network_made_map_keeps_clear_of_its_boxes_by_the_edge_slack():
    gt = _row(2.0, [_box(0, 0.5, 1.0)])
    net = _row(2.0, [_box(0, 0.5, 1.0)])
    net.meta = {"checkpoint": "models/m.pt"}
    assert edge_slack(gt.meta) == 0 and edge_slack(net.meta) == NETWORK_EDGE_SLACK > 0
    assert edge_slack({"layouts": "net"}) == NETWORK_EDGE_SLACK and edge_slack({"layouts": "gt"}) == 0
    (a,) = fits(gt, 0.3, 0.3, 0.3, margin=0.02)
    (b,) = fits(net, 0.3, 0.3, 0.3, margin=0.02)
    s = NETWORK_EDGE_SLACK
    assert a.centres == [pytest.approx((UPRIGHT_INSET + 0.17, 0.33)), pytest.approx((1.17, 2.0 - UPRIGHT_INSET - 0.17))]
    assert b.centres == [
        pytest.approx((UPRIGHT_INSET + 0.17, 0.33 - s)),
        pytest.approx((1.17 + s, 2.0 - UPRIGHT_INSET - 0.17)),
    ]
    assert fits(net, 0.3, 0.3, 0.3, margin=0.02, slack=0.0) == [a]  # the slack given overrides the map's
    # Free length is what the map measured: no slack there.
    assert free_space(net)[0].free_length == pytest.approx(free_space(gt)[0].free_length)
    bmap = _building()
    bmap.meta = {"layouts": "net"}
    (f,) = building_fits(bmap, 0.3, 0.3, 0.3, margin=0.02)
    assert f.centres[0] == pytest.approx((UPRIGHT_INSET + 0.17, 0.33 - s))


def test_a_location_flagged_recount_is_offered_only_when_asked_and_after_the_sure_ones():
    bmap = _building()
    face = bmap.faces[0]
    extra = MapShelf("01-R-02-01", 0, 0.0, 0.9, (2.1, 4.1), (-0.5, 0.5), 1.0, [])
    face.map.racks.append(MapRack("01-R-02", (2.1, 4.1), [extra]))
    face.locations["01-R-02-01"] = Location("01-R-02-01", 1, "R", 2, 1, 1, ["p0", "p1"], 1.0)
    assert [f.location for f in building_fits(bmap, 0.3, 0.3, 0.3)] == ["01-R-01-01", "01-R-02-01"]
    face.locations["01-R-01-01"].counts = {"p0": 1, "p1": 2}  # the passes disagree: its row says recount
    assert [f.location for f in building_fits(bmap, 0.3, 0.3, 0.3)] == ["01-R-02-01"]
    both = building_fits(bmap, 0.3, 0.3, 0.3, with_recount=True)
    assert [(f.location, f.recount) for f in both] == [("01-R-02-01", False), ("01-R-01-01", True)]
    assert "recount" in format_fits(both, "0.3x0.3x0.3").splitlines()[0]
