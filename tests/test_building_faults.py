"""Faults in the building formats and the commands around them, each the one-line error (exit status 2,
naming the file or option and the field) or the right answer, the inputs byte-identical afterwards:

* a corrupted ``building.json`` (a face or location listed twice, a front line at 1e308, a negative seen share,
  ...) and maps of two different buildings given to ``diff``;
* a route whose boards' heights or levels are unsorted or repeated, or a pass above its face's levels;
* a building config whose location code cannot tell locations apart; a rescan given another image size or
  layout spec than its building's; ``--layout-size`` below its minimum;
* ``eval-reconstruction`` of a split with no sequence; frames too small to read a distance from;
* what the code builds breaking its own schema: a defect, raised before anything is written.
"""

from __future__ import annotations

import copy
import json
import os
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from conftest import TINY_BUILDING, TINY_CONFIG
from PIL import Image
from test_faults import one_line, snapshot

from layouts.errors import ContractError, InputError
from layouts.spec import LayoutSpec
from mvracklay.building_job import MapSettings, map_building
from mvracklay.cli import main
from mvracklay.settings import OutputSettings
from stitching.building.diff import BuildingDiff, Change, diff_buildings
from stitching.building.diff_export import write_changes
from stitching.building.eval import evaluate_building, evaluate_changes
from stitching.building.map import BuildingMap
from stitching.building.schema import check_inventory


def _set(*path_and_value):
    """An edit setting ``doc[p0][p1]... = value``."""
    *path, value = path_and_value

    def edit(doc: dict) -> None:
        for k in path[:-1]:
            doc = doc[k]
        doc[path[-1]] = value

    return edit


def _twice(key: str, k: int):
    def edit(doc: dict) -> None:
        doc[key].append(copy.deepcopy(doc[key][k]))

    return edit


def _location_twice(doc: dict) -> None:
    doc["faces"][0]["locations"].append(copy.deepcopy(doc["faces"][0]["locations"][0]))


#: corruption -> (edit of the parsed building.json, what the error names)
BUILDING_FAULTS = {
    "a face listed twice": (_twice("faces", 1), "faces[4]: face 01-R is listed twice (faces[1])"),
    "front_z 1e308": (_set("faces", 2, "front_z", 1e308), "faces[2].front_z"),
    "a negative seen share": (_set("faces", 0, "locations", 1, "seen", -0.5), "faces[0].locations[1].seen"),
    "a seen share above 1": (_set("faces", 0, "locations", 1, "seen", 3.0), "faces[0].locations[1].seen"),
    "a location listed twice": (_location_twice, "is listed twice"),
    "a location under another code": (_set("faces", 0, "locations", 0, "location", "zz"), "has no location record"),
    "a reversed seen interval": (_set("faces", 0, "map", "seen_x", 0, [3.0, 1.0]), "faces[0].map"),
    "a bay numbered 0": (_set("faces", 0, "locations", 0, "bay", 0), "faces[0].locations[0].bay"),
    "a position past the positions": (_set("faces", 0, "locations", 0, "position", 2), "exceeds positions"),
    "a pass listed twice": (_twice("passes", 0), "passes[15]: pass 'pass_000' is listed twice"),
    "a pass on an unmapped face": (_set("passes", 0, "aisle", 9), "passes[0]: pass 'pass_000' is on face 09-L"),
    "an unknown pass": (_set("faces", 0, "locations", 0, "passes", ["nobody"]), "faces[0].locations[0].passes"),
    "trusted steps above 1": (_set("passes", 0, "trusted_steps", 1.5), "passes[0].trusted_steps"),
    "a face off its floor plan": (_set("plan", 0, "front_z", 5.0), "faces[0].front_z"),
    "a code without the level": (_set("code", "{aisle}-{side}-{bay}"), "code"),
}


@pytest.fixture
def good(tiny_building_map: Path) -> dict:
    return json.loads((tiny_building_map / "building.json").read_text())


@pytest.mark.parametrize("fault", list(BUILDING_FAULTS))
def test_diff_refuses_a_corrupted_building_map(fault, good, tiny_building_map, tmp_path, capsys):
    edit, needle = BUILDING_FAULTS[fault]
    doc = copy.deepcopy(good)
    edit(doc)
    bad = tmp_path / "bad" / "building.json"
    bad.parent.mkdir()
    bad.write_text(json.dumps(doc))
    before = snapshot(tmp_path), snapshot(tiny_building_map)
    for old, new in ((tiny_building_map, bad.parent), (bad, tiny_building_map)):
        rc = main(["diff", str(old), str(new), "--out", str(tmp_path / "out"), "--no-rrd"])
        one_line(capsys, rc, "diff", f"{bad}: malformed building map: ", needle)
    assert (snapshot(tmp_path), snapshot(tiny_building_map)) == before  # no --out made, nothing changed
    with pytest.raises(InputError, match="malformed building map"):
        BuildingMap.load(bad)


def test_the_untouched_map_loads_and_round_trips(good, tiny_building_map):
    bmap = BuildingMap.load(tiny_building_map / "building.json")
    assert bmap.to_dict() == good and len(bmap.plan) == len(good["plan"]) == 4


@pytest.fixture(scope="module")
def one_aisle(tmp_path_factory) -> Path:
    """The tiny building with one aisle (the same seed: aisle 1's faces as the two-aisle building's), mapped."""
    from waresynth.building.generate import generate_building

    root = tmp_path_factory.mktemp("one_aisle")
    generate_building(root / "b", building={**TINY_BUILDING, "aisles": 1}, config=TINY_CONFIG, image_size=(32, 24),
                      spec=LayoutSpec(size=128), seed=3, progress=False)  # fmt: skip
    map_building(root / "b", root / "m", MapSettings(layouts="gt"), outputs=OutputSettings(rrd=False, quiet=True))
    return root / "m"


def test_diff_refuses_maps_of_two_buildings(one_aisle, tiny_building_map, tmp_path, capsys):
    before = snapshot(one_aisle), snapshot(tiny_building_map)
    rc = main(["diff", str(tiny_building_map), str(one_aisle), "--out", str(tmp_path / "out"), "--no-rrd"])
    one_line(capsys, rc, "diff", str(one_aisle / "building.json"), "maps of different buildings",
             "floor plans list other faces (old: 01-L, 01-R, 02-L, 02-R; new: 01-L, 01-R)")  # fmt: skip
    assert not (tmp_path / "out").exists() and (snapshot(one_aisle), snapshot(tiny_building_map)) == before


def test_two_maps_must_share_codes_and_floor_plan(tiny_building_map):
    bmap = BuildingMap.load(tiny_building_map / "building.json")
    moved = replace(bmap.plan[2], front_z=bmap.plan[2].front_z + 1.0)
    lower = replace(bmap.plan[3], levels_m=(bmap.plan[3].levels_m[0] + 0.3, *bmap.plan[3].levels_m[1:]))
    fewer = replace(bmap.plan[3], levels_m=bmap.plan[3].levels_m[:-1])
    faces = [replace(f, front_z=f.front_z + 1.0) if f.key == (2, "L") else f for f in bmap.faces]
    bare = replace(bmap, plan=())  # a map written before the floor plan was kept
    cases = {
        "location codes differ": (bmap, replace(bmap, code="{aisle}-{side}-{bay}-{level}")),
        "face 02-L's front line lies at z": (bmap, replace(bmap, plan=(*bmap.plan[:2], moved, bmap.plan[3]))),
        "face 02-R's level 1 board is": (bmap, replace(bmap, plan=(*bmap.plan[:3], lower))),
        "face 02-R has 3 levels in the old map, 2 in the new": (bmap, replace(bmap, plan=(*bmap.plan[:3], fewer))),
        # without floor plans: the faces both mapped
        "no rack face in common": (replace(bare, faces=bmap.faces[:2]), replace(bare, faces=bmap.faces[2:])),
        "front line lies at z": (bare, replace(bare, faces=faces)),
    }
    for needle, (old, new) in cases.items():
        with pytest.raises(InputError, match="are maps of different buildings: .*" + needle):
            diff_buildings(old, new)
    # a scan of part of the building (one aisle's passes, the whole floor plan) is the same building
    part = replace(bmap, faces=[f for f in bmap.faces if f.aisle == 1])
    d = diff_buildings(bmap, part)
    assert d.changes == [] and {loc.status for loc in d.locations} == {"unchanged", "not scanned"}


# --- the route ---------------------------------------------------------------------------------------------------


def _levels_below(doc: dict) -> None:
    p = doc["passes"][-1]
    del p["levels"]
    p["first_level"] = 9


ROUTE_FAULTS = {
    "levels_m unsorted": (_set("faces", 3, "levels_m", [0.3, 0.2, 1.9]), "faces[3].levels_m: must rise"),
    "levels_m repeated": (_set("faces", 3, "levels_m", [0.3, 0.3, 1.9]), "faces[3].levels_m: must rise"),
    "levels repeated": (_set("passes", 0, "levels", [1, 1]), "passes[0].levels: must rise"),
    "first_level 9 on 3 levels": (_levels_below, "passes[14].first_level: level 9 of pass '"),
    "a level above the face's": (_set("passes", 0, "levels", [2, 3]), "passes[0].levels: level 3 of pass '"),
}


@pytest.mark.parametrize("fault", list(ROUTE_FAULTS))
def test_map_refuses_a_route_whose_levels_cannot_be(fault, tiny_building, tmp_path, capsys):
    edit, needle = ROUTE_FAULTS[fault]
    doc = json.loads((tiny_building / "route.json").read_text())
    for p in doc["passes"]:  # a route of one's own beside the building: its passes by relative path
        p["sequence"] = os.path.relpath(tiny_building / p["sequence"], tmp_path)
    edit(doc)
    (tmp_path / "route.json").write_text(json.dumps(doc))
    before = snapshot(tiny_building), snapshot(tmp_path)
    rc = main(["map", str(tmp_path / "route.json"), "--out", str(tmp_path / "m"), "--layouts", "gt", "--quiet"])
    said = one_line(capsys, rc, "map", f"{tmp_path / 'route.json'}: ", needle)
    assert "first_level" not in fault or "is above the 3 levels of face 02-R" in said
    assert (snapshot(tiny_building), snapshot(tmp_path)) == before


# --- generate ----------------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("argv", "needle"),
    [
        (["--building", "CFG", "--size", "32"], "code: location code format 'X' lacks aisle, side, bay, level"),
        (["--building", "--rescan", "SCAN", "--size", "256"], "image size (256, 256) differs from its own (32, 24)"),
        (["--building", "--rescan", "SCAN", "--layout-size", "64"], "differs from its own: size 64 (its own 128)"),
        (["--building", "--rescan", "SCAN", "--slots", "3", "--layout-size", "128", "--size", "8"], "--size must be"),
        (["--sequences", "1", "--frames", "1", "--size", "32", "--layout-size", "1"], "--layout-size must be in [8,"),
    ],
    ids=["code X", "rescan --size", "rescan --layout-size", "size 8", "layout-size 1"],
)
def test_generate_refuses_what_cannot_be_written(argv, needle, tiny_building, tmp_path, capsys):
    cfg = tmp_path / "codes.json"
    cfg.write_text(json.dumps({"code": "X"}))
    argv = [str(cfg) if a == "CFG" else str(tiny_building) if a == "SCAN" else a for a in argv]
    before = snapshot(tiny_building)
    rc = main(["generate", str(tmp_path / "out"), *argv, "--quiet"])
    one_line(capsys, rc, "generate", needle, *([str(cfg)] if str(cfg) in argv else []))
    assert not (tmp_path / "out").exists() and snapshot(tiny_building) == before


# --- eval-reconstruction, the distance ---------------------------------------------------------------------------


def test_eval_reconstruction_of_an_empty_split_is_refused(tmp_path, capsys):
    from waresynth.generate import DatasetSettings, generate_dataset

    ds = generate_dataset(tmp_path / "ds", DatasetSettings(num_sequences=1, frames=2, image_size=(32, 32), spec=LayoutSpec(size=32), seed=1, progress=False))  # fmt: skip
    split = json.loads((ds / "manifest.json").read_text())["sequences"][0]["split"]
    empty = next(s for s in ("train", "val", "test") if s != split)
    rc = main(["eval-reconstruction", str(ds), "--split", empty, "--quiet"])
    one_line(capsys, rc, "eval-reconstruction", f"{ds}: no sequence in split {empty!r}")
    assert main(["eval-reconstruction", str(ds), "--split", split, "--quiet"]) == 0
    assert "pooled" in capsys.readouterr().out


def test_frames_too_small_give_the_default_distance_and_say_so(tiny_checkpoint, tmp_path, capsys):
    frames = tmp_path / "frames"
    frames.mkdir()
    for i in range(8):
        Image.fromarray(np.full((1, 1, 3), 120, np.uint8)).save(frames / f"IMG_{i:04d}.png")
    out = tmp_path / "out"
    argv = ["run", str(frames), "--out", str(out), "--checkpoint", str(tiny_checkpoint), "--threads", "1"]
    assert main([*argv, "--quiet", "--no-rrd"]) == 0
    said = capsys.readouterr()
    assert "distance to the racks: 2." in said.out and "the default (not read)" in said.out
    assert "read from 8 frames" not in said.out
    assert "frames of 1x1 pixels are too small to read the distance from" in said.err
    meta = json.loads((out / "warehouse.json").read_text())["meta"]
    assert meta["distance_source"] == "default" and "too small" in meta["distance_note"]


# --- what we write, we read --------------------------------------------------------------------------------------


def test_a_building_map_that_breaks_its_schema_is_never_written(tiny_building_map, tmp_path):
    bmap = BuildingMap.load(tiny_building_map / "building.json")
    path = tmp_path / "building.json"
    bmap.save(path)
    earlier = path.read_bytes()
    assert BuildingMap.load(path).to_dict() == bmap.to_dict()
    bmap.faces[2].front_z = 1e308
    with pytest.raises(ContractError, match=rf"{path}: building map built here breaks its schema .*faces\[2\]"):
        bmap.save(path)
    assert path.read_bytes() == earlier and sorted(p.name for p in tmp_path.iterdir()) == ["building.json"]


def test_changes_that_break_their_schema_are_never_written(tiny_building_map, tmp_path):
    bmap = BuildingMap.load(tiny_building_map / "building.json")
    code = bmap.locations()[0][2].code
    bad = BuildingDiff([Change(code, "added", confidence=1.5, box_ids=[f"{code}/box_99"])], [])
    with pytest.raises(ContractError, match=r"changes.json: changes built here .*changes\[0\].*confidence"):
        write_changes(bmap, bmap, bad, tmp_path / "d", rrd=False)
    assert not list((tmp_path / "d").glob("changes*"))


def test_truth_files_are_held_to_their_schema(tiny_building, tiny_building_map):
    bmap = BuildingMap.load(tiny_building_map / "building.json")
    truth = json.loads((tiny_building / "ground_truth/building.json").read_text())
    rows = [dict(r) for r in bmap.inventory()]
    check_inventory(rows, "inventory.csv")  # the map's own rows pass
    for k, v, needle in [("boxes", -1, "row 1: boxes"), ("confidence", 2, "row 1: confidence"),
                         ("side", "Q", "row 1: side"), ("occupancy", "lots", "row 1: occupancy")]:  # fmt: skip
        bad = [{**rows[0], k: v}, *rows[1:]]
        with pytest.raises(InputError, match=f"gt.csv: malformed inventory: {needle}"):
            evaluate_building(bmap, truth, bad, source="gt.csv")
    with pytest.raises(InputError, match="row 2: location .* is listed twice"):
        check_inventory([rows[0], rows[0]], "inventory.csv")
    assert evaluate_building(bmap, truth, rows).recall == 1.0  # the ground truth itself passes
    box = truth["racks"][0]["levels"][0]["positions"][0]["boxes"][0]
    for k, v, needle in [("center", [0, 0, 1e308], "center.2"), ("size", [0.4, -1, 0.3], "size.1")]:
        bad = copy.deepcopy(truth)
        bad["racks"][0]["levels"][0]["positions"][0]["boxes"][0] = {**box, k: v}
        with pytest.raises(
            InputError, match=rf"building.json: malformed ground truth: racks\[0\].*boxes\[0\].{needle}"
        ):
            evaluate_building(bmap, bad, rows)
    found = [{"location": "a", "change": "added"}]
    for row, needle in [({"location": "a", "change": "exploded"}, "row 1: change"),
                        ({"location": "a", "change": "moved"}, "row 1: other_location"),
                        ({"change": "added"}, "row 1: location")]:  # fmt: skip
        with pytest.raises(InputError, match=f"--truth: malformed changes: {needle}"):
            evaluate_changes(found, [row])


def test_diff_refuses_a_malformed_truth_before_it_compares(tiny_building_map, tmp_path, capsys):
    truth = tmp_path / "truth.csv"
    truth.write_text("location,change\n01-R-01-1,exploded\n")
    rc = main(["diff", str(tiny_building_map), str(tiny_building_map), "--out", str(tmp_path / "out"), "--no-rrd",
               "--truth", str(truth)])  # fmt: skip
    one_line(capsys, rc, "diff", f"--truth {truth}: malformed changes: row 1: change")
    assert not (tmp_path / "out").exists()
