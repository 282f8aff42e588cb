"""The recount flag: each cue of an uncertain count flags a row, a confident well-seen row is not flagged; a
building map's inventory carries the column (empty where not scanned), held by its schema; on the tiny building
the rows without it have the exact count."""

from __future__ import annotations

import csv
from dataclasses import replace
from types import SimpleNamespace

import pytest

from layouts.errors import InputError
from stitching.building.map import BuildingMap
from stitching.building.recount import MAP_INVENTORY_COLUMNS, RULE, RowEvidence, needs_recount, uncertain_bays
from stitching.building.schema import check_inventory

SURE = RowEvidence(confidence=0.95, box_confidence=0.9, support=30)


def test_a_confident_well_seen_row_is_not_flagged():
    assert not needs_recount(SURE)
    assert not needs_recount(RowEvidence(confidence=0.9))  # no boxes: nothing to be unsure of


@pytest.mark.parametrize(
    "change",
    [
        {"confidence": RULE.min_confidence - 0.01},
        {"box_confidence": RULE.min_box_confidence - 0.01},
        {"support": RULE.min_support - 1},
        {"partial": True},
        {"disagree": True},
        {"uncertain_boundary": True},
    ],
)
def test_each_cue_flags_the_row(change):
    assert needs_recount(replace(SURE, **change))


def test_a_bay_breaking_the_faces_repetition_is_uncertain():
    racks = [
        SimpleNamespace(id=f"r{k}", x_range=(2.0 * k, 2.0 * k + w)) for k, w in enumerate([1.9, 2.0, 4.1, 2.1, 1.0])
    ]
    assert uncertain_bays(racks) == {"r2", "r4"}  # two bays run together, half a bay
    assert uncertain_bays(racks[:2]) == set()  # too few bays to tell a repetition


def test_a_bay_beside_an_uncertain_upright_cut_is_uncertain():
    racks = [SimpleNamespace(id=f"r{k}", x_range=(2.0 * k, 2.0 * k + 2.0)) for k in range(4)]  # touching bays
    assert uncertain_bays(racks, cuts=[(2.0, True), (4.0, True)]) == set()  # certain cuts: the widths repeat
    assert uncertain_bays(racks, cuts=[(2.0, True), (4.01, False)]) == {"r1", "r2"}  # both sides of that cut
    assert uncertain_bays(racks[:2], cuts=[(2.0, False)]) == {"r0", "r1"}  # too few for the widths, not for a cut


def test_the_inventory_carries_the_flag(tiny_building, tiny_building_map):
    header = (tiny_building_map / "inventory.csv").read_text().splitlines()[0]
    assert header.split(",") == list(MAP_INVENTORY_COLUMNS)
    bmap = BuildingMap.load(tiny_building_map / "building.json")
    rows = bmap.inventory()
    assert {r["recount"] for r in rows} <= {"true", "false"}
    truth = {r["location"]: int(r["boxes"]) for r in csv.DictReader(open(tiny_building / "ground_truth/inventory.csv"))}
    kept = [r for r in rows if r["recount"] == "false"]
    assert len(kept) >= 0.85 * len(rows)
    assert sum(truth.get(r["location"]) == r["boxes"] for r in kept) >= 0.98 * len(kept)
    # a row whose boxes were barely seen is flagged; one no pass saw has an empty flag
    (_, shelf, _), (_, _, unseen) = [t for t in bmap.locations() if t[1].boxes][:2]
    shelf.boxes[:] = [replace(b, observations=1) for b in shelf.boxes]
    unseen.passes, unseen.seen = [], 0.0
    again = {r["location"]: r for r in bmap.inventory()}
    assert again[shelf.id]["recount"] == "true" and again[unseen.code]["recount"] == ""
    check_inventory(list(again.values()), "inventory")


def test_the_schema_refuses_a_bad_flag(tiny_building_map):
    rows = BuildingMap.load(tiny_building_map / "building.json").inventory()
    with pytest.raises(InputError, match="row 1: recount"):
        check_inventory([{**rows[0], "recount": "maybe"}, *rows[1:]], "inventory.csv")
    check_inventory([{k: v for k, v in r.items() if k != "recount"} for r in rows], "truth")  # the ground truth's


def test_passes_that_counted_a_location_differently_flag_it(tiny_building_map):
    from stitching.building.config import FuseConfig
    from stitching.building.fuse_passes import _pass_counts

    box = SimpleNamespace()
    boxes = [(box, 1.2, ["a", "b"]), (box, 1.6, ["a"])]  # the second box only pass a found
    views = {"a": [(0.0, 3.0)], "b": [(0.5, 3.0)], "c": [(1.5, 3.0)]}
    assert _pass_counts(boxes, ["a", "b", "c"], views, 1.0, 2.0, FuseConfig()) == {"a": 2, "b": 1}  # c held half of it
    assert _pass_counts(boxes, ["a", "c"], views, 1.0, 2.0, FuseConfig()) == {}  # one whole view: nothing to compare
    bmap = BuildingMap.load(tiny_building_map / "building.json")
    f, shelf, loc = next(t for t in bmap.locations() if t[2].scanned)
    assert bmap.inventory()[0]["location"] == loc.code
    loc.counts = {"pass_a": 2, "pass_b": 2}
    assert not loc.disagree
    loc.counts = {"pass_a": 2, "pass_b": 1}
    assert loc.disagree and bmap.inventory()[0]["recount"] == "true"
    again = BuildingMap.from_dict(bmap.to_dict())  # the per-pass counts are kept in building.json
    assert again.faces[0].locations[loc.code].counts == {"pass_a": 2, "pass_b": 1}
    bad = bmap.to_dict()
    bad["faces"][0]["locations"][0]["counts"] = {"pass_a": -1}
    with pytest.raises(InputError, match="counts"):
        BuildingMap.from_dict(bad)
