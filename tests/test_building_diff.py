"""``mvracklay diff``: a tiny building and its rescan after seeded changes, both mapped from their ground-truth
layouts; every change category found, none where nothing changed, unseen locations never ``removed``."""

from __future__ import annotations

import csv
import json
from dataclasses import replace
from pathlib import Path

import pytest
from conftest import TINY_BUILDING

from mvracklay.building_job import map_building
from mvracklay.cli import main
from stitching.building_diff import CHANGES, diff_buildings
from stitching.building_eval import evaluate_changes
from stitching.building_map import BuildingMap
from stitching.export_gltf import glb_json
from stitching.rerun_log import read_entities
from waresynth.building_generate import generate_building

RATES = {"removed": 0.12, "added": 0.12, "moved": 0.1, "shifted": 0.12, "replaced": 0.05}


def _rescan(old: Path, out: Path, seed: int, rates: dict) -> Path:
    return generate_building(out, building={**TINY_BUILDING, "changes": rates}, rescan=old, seed=seed, progress=False)


@pytest.fixture(scope="module")
def scans(tiny_building, tiny_building_map, tmp_path_factory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("scans")
    changed = _rescan(tiny_building, root / "changed", 11, RATES)
    map_building(changed, root / "changed_map", layouts="gt", rrd=False, progress=False)
    return {"old": tiny_building_map, "new": root / "changed_map", "truth": changed / "ground_truth/changes.csv",
            "root": root, "old_data": tiny_building, "new_data": changed}  # fmt: skip


def _truth(path: Path) -> list[dict]:
    return list(csv.DictReader(path.open()))


def _load(folder: Path) -> BuildingMap:
    return BuildingMap.load(folder / "building.json")


def test_every_category_found(scans):
    truth = _truth(scans["truth"])
    assert {r["change"] for r in truth} == set(CHANGES)
    d = diff_buildings(_load(scans["old"]), _load(scans["new"]))
    scores = evaluate_changes(d.rows(), truth)
    for cat, s in scores.items():
        assert s["truth"] > 0 and s["precision"] >= 0.95 and s["recall"] >= 0.95, (cat, s)
    moved = [c for c in d.changes if c.change == "moved"]
    assert all(c.other_location and c.other_location != c.location for c in moved)
    changed = [loc for loc in d.locations if loc.status == "changed"]
    assert changed and all(loc.free_length_change_m is not None for loc in changed)


def test_pose_noise_on_both_scans(scans, tmp_path):
    old = map_building(scans["old_data"], tmp_path / "o", layouts="gt", pose_noise=(0.3, 3.0), seed=5, rrd=False,
                       progress=False).map  # fmt: skip
    new = map_building(scans["new_data"], tmp_path / "n", layouts="gt", pose_noise=(0.3, 3.0), seed=6, rrd=False,
                       progress=False).map  # fmt: skip
    scores = evaluate_changes(diff_buildings(old, new).rows(), _truth(scans["truth"]))
    assert all(s["precision"] >= 0.95 and s["recall"] >= 0.95 for s in scores.values()), scores


def test_a_rescan_without_changes_keeps_the_codes_and_reports_nothing(scans):
    quiet = _rescan(scans["old_data"], scans["root"] / "same", 12, {k: 0.0 for k in RATES})
    assert len(_truth(quiet / "ground_truth/changes.csv")) == 0
    new = map_building(quiet, scans["root"] / "same_map", layouts="gt", rrd=False, progress=False).map
    old = _load(scans["old"])
    # another scan (new passes, cameras, distances): the same codes for the same racks
    assert [t[2].code for t in new.locations()] == [t[2].code for t in old.locations()]
    for (fo, so, _), (fn, sn, _) in zip(old.locations(), new.locations()):
        assert abs(fo.to_building(so.cuboid).center[0] - fn.to_building(sn.cuboid).center[0]) < 0.05
    d = diff_buildings(old, new)
    assert d.changes == [] and {loc.status for loc in d.locations} == {"unchanged"}


def test_unseen_locations_are_not_scanned_never_removed(scans):
    old, new = _load(scans["old"]), _load(scans["new"])
    face = new.faces[0]
    for loc in face.locations.values():  # the new scan never went down this face
        loc.passes, loc.seen = [], 0.0
    d = diff_buildings(old, new)
    mine = set(face.locations)
    assert all(c.location not in mine and c.other_location not in mine for c in d.changes)
    status = {loc.location: loc.status for loc in d.locations}
    assert all(status[code] == "not scanned" for code in mine)
    # and the rest still found
    truth = [r for r in _truth(scans["truth"]) if r["location"] not in mine and r["other_location"] not in mine]
    scores = evaluate_changes(d.rows(), truth)
    assert all(s["recall"] >= 0.95 for s in scores.values() if s["truth"]), scores


def test_cli_writes_the_changes(scans, tmp_path, capsys):
    out = tmp_path / "d"
    assert main(["diff", str(scans["old"]), str(scans["new"]), "--out", str(out), "--truth", str(scans["truth"])]) == 0
    said = capsys.readouterr().out
    assert "moved" in said and "precision" in said
    rows = _truth(out / "changes.csv")
    doc = json.loads((out / "changes.json").read_text())
    assert len(rows) == len(doc["changes"]) > 0 and set(doc["evaluation"]) == set(CHANGES)
    names = {n.get("name") for n in glb_json(out / "changes.glb")["nodes"]}
    assert any(str(n).startswith("change_000") for n in names)
    assert {"/changes/added", "/changes/removed", "/changes/moved"} <= read_entities(out / "changes.rrd")
    assert main(["diff", str(tmp_path / "nothing"), str(scans["new"]), "--out", str(out)]) == 2
    assert "OLD_MAP" in capsys.readouterr().err


def test_the_same_map_twice_is_no_change(scans):
    bmap = _load(scans["new"])
    d = diff_buildings(bmap, replace(bmap))
    assert d.changes == [] and d.counts() == dict.fromkeys(CHANGES, 0)
