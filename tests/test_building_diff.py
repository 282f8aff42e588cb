"""``mvracklay diff``: a tiny building and its rescan after seeded changes, both mapped from their ground-truth
layouts; every change category found, none where nothing changed, unseen locations never ``removed``; per
location the counts before and after (emptied, filled, count changed) as the rescan's truth has them, moves only
between confident rows; ``--expected``: a map against the WMS's counts."""

from __future__ import annotations

import copy
import csv
import json
from dataclasses import replace
from pathlib import Path

import pytest
from conftest import TINY_BUILDING

from layouts.location_changes import LOCATION_CHANGES, count_change
from layouts.locations import NOT_SCANNED, read_rows
from mvracklay.building_job import MapSettings, map_building
from mvracklay.cli import main
from mvracklay.settings import OutputSettings
from stitching.building.diff import CHANGES, LOCATION_COLUMNS, diff_buildings, format_diff
from stitching.building.eval import evaluate_changes
from stitching.building.location_counts import EXCEPTION_COLUMNS, evaluate_location_changes, read_location_truth
from stitching.building.map import BuildingMap
from stitching.building.schema import check_change_rows, check_changes
from stitching.export_gltf import glb_json
from stitching.rerun_log import read_entities
from waresynth.building.generate import generate_building

RATES = {"removed": 0.12, "added": 0.12, "moved": 0.1, "shifted": 0.12, "replaced": 0.05}


def _rescan(old: Path, out: Path, seed: int, rates: dict) -> Path:
    return generate_building(out, building={**TINY_BUILDING, "changes": rates}, rescan=old, seed=seed, progress=False)


@pytest.fixture(scope="module")
def scans(tiny_building, tiny_building_map, tmp_path_factory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("scans")
    changed = _rescan(tiny_building, root / "changed", 11, RATES)
    map_building(
        changed, root / "changed_map", MapSettings(layouts="gt"), outputs=OutputSettings(rrd=False, quiet=True)
    )
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
    old, new = (
        map_building(scans[data], tmp_path / out, MapSettings("gt", pose_noise=(0.3, 3.0), seed=seed),
                     outputs=OutputSettings(rrd=False, quiet=True)).map
        for data, out, seed in (("old_data", "o", 5), ("new_data", "n", 6))
    )  # fmt: skip
    scores = evaluate_changes(diff_buildings(old, new).rows(), _truth(scans["truth"]))
    assert all(s["precision"] >= 0.95 and s["recall"] >= 0.95 for s in scores.values()), scores


def test_a_rescan_without_changes_keeps_the_codes_and_reports_nothing(scans):
    quiet = _rescan(scans["old_data"], scans["root"] / "same", 12, {k: 0.0 for k in RATES})
    assert len(_truth(quiet / "ground_truth/changes.csv")) == 0
    new = map_building(
        quiet, scans["root"] / "same_map", MapSettings(layouts="gt"), outputs=OutputSettings(rrd=False, quiet=True)
    ).map
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
    assert len(rows) == len(doc["changes"]) > 0 and set(doc["evaluation"]) == {*CHANGES, "locations"}
    names = {n.get("name") for n in glb_json(out / "changes.glb")["nodes"]}
    assert any(str(n).startswith("change_000") for n in names)
    assert {"/changes/added", "/changes/removed", "/changes/moved"} <= read_entities(out / "changes.rrd")
    check_changes(doc, "changes.json")  # what we write, we read: each file by the project's own reader
    check_change_rows(read_rows((out / "changes.csv").read_text(), ("location", "change"), "changes.csv"), "x")
    located = read_rows((out / "location_changes.csv").read_text(), LOCATION_COLUMNS, "location_changes.csv")
    assert located and {r["location"] for r in located} >= {r["location"] for r in rows}
    assert main(["diff", str(tmp_path / "nothing"), str(scans["new"]), "--out", str(out)]) == 2
    assert "OLD_MAP" in capsys.readouterr().err


def test_the_same_map_twice_is_no_change(scans):
    bmap = _load(scans["new"])
    d = diff_buildings(bmap, replace(bmap))
    assert d.changes == [] and d.counts() == dict.fromkeys(CHANGES, 0)


def test_per_location_categories_on_a_hand_made_pair(scans):
    old = _load(scans["old"])
    new = copy.deepcopy(old)
    shelves = {loc.code: s for _, s, loc in new.locations()}
    emptied = next(c for c, s in shelves.items() if len(s.boxes) == 1)
    fewer = next(c for c, s in shelves.items() if len(s.boxes) >= 2)
    shelves[emptied].boxes.clear()
    shelves[fewer].boxes.pop()
    d = diff_buildings(old, new)
    by = {c.location: c for c in d.locations}
    assert (by[emptied].before, by[emptied].after, by[emptied].change) == (1, 0, "emptied")
    assert by[fewer].change == "count changed" and by[fewer].after < by[fewer].before
    assert {c.location for c in d.locations if c.change in LOCATION_CHANGES} == {emptied, fewer}
    assert all(0 < by[c].confidence <= 1 and not by[c].recount for c in (emptied, fewer))
    back = {c.location: c.change for c in diff_buildings(new, old).locations}
    assert (back[emptied], back[fewer]) == ("filled", "count changed")
    said = format_diff(d)
    assert said.splitlines()[0].startswith("location") and said.index(emptied) < said.index("size (m)")


def test_a_move_needs_both_ends_confident(scans):
    old, new = _load(scans["old"]), _load(scans["new"])
    mv = next(c for c in diff_buildings(old, new).changes if c.change == "moved")
    _, shelf, _ = new.location(mv.location)
    shelf.boxes[:] = [replace(b, confidence=0.1) for b in shelf.boxes]  # its new place now uncertain: recount
    d = diff_buildings(old, new)
    assert not any(c.change == "moved" and mv.location in (c.location, c.other_location) for c in d.changes)
    kinds = {(c.change, c.location) for c in d.changes}
    assert ("removed", mv.other_location) in kinds and ("added", mv.location) in kinds
    assert next(c for c in d.locations if c.location == mv.location).recount


def test_location_changes_against_the_rescans_truth(scans):
    truth = read_location_truth(scans["truth"].parent / "location_changes.csv")
    before = {r["location"]: int(r["boxes"]) for r in _truth(scans["old_data"] / "ground_truth/inventory.csv")}
    after = {r["location"]: int(r["boxes"]) for r in _truth(scans["new_data"] / "ground_truth/inventory.csv")}
    assert {r["location"] for r in truth} == {c for c in after if before[c] != after[c]}
    assert all(r["change"] == count_change(before[r["location"]], after[r["location"]]) for r in truth)
    d = diff_buildings(_load(scans["old"]), _load(scans["new"]))
    scores = evaluate_location_changes(d.location_rows(), truth)
    assert sum(scores[k]["truth"] for k in LOCATION_CHANGES) == len(truth) > 0
    assert all(scores[k]["precision"] == 1.0 and scores[k]["recall"] == 1.0 for k in LOCATION_CHANGES), scores
    rows = d.location_rows()
    assert {r["location"] for r in rows} == set(after) and all(r["recount"] in ("true", "false") for r in rows)


def _exceptions(out: Path) -> list[dict[str, str]]:
    """``exceptions.csv`` as the project reads CSV rows (each row its columns, one line when malformed)."""
    return read_rows((out / "exceptions.csv").read_text(), EXCEPTION_COLUMNS, str(out / "exceptions.csv"))


def _wms(path: Path, rows: list[tuple[str, int]]) -> Path:
    path.write_text("location,expected\n" + "".join(f"{c},{n}\n" for c, n in rows))
    return path


def test_expected_lists_the_exceptions(scans, tmp_path, capsys):
    bmap = _load(scans["old"])
    rows = bmap.inventory()
    assert all(r["boxes"] != NOT_SCANNED for r in rows)
    differs, dropped, unseen = rows[0], rows[1], rows[2]
    _, _, loc = bmap.location(unseen["location"])
    loc.passes, loc.seen = [], 0.0
    (tmp_path / "m").mkdir()
    bmap.save(tmp_path / "m" / "building.json")
    listed = [(r["location"], r["boxes"] + (r is differs)) for r in rows if r is not dropped]
    wms = _wms(tmp_path / "wms.csv", [*listed, ("99-L-01-01", 4)])
    out = tmp_path / "x"
    assert main(["diff", str(tmp_path / "m"), "--expected", str(wms), "--out", str(out)]) == 0
    got = {(r["location"], r["exception"]): r for r in _exceptions(out)}
    assert set(got) == {(differs["location"], "count differs"), (dropped["location"], "not in the WMS"),
                        (unseen["location"], "not scanned"), ("99-L-01-01", "missing from the map")}  # fmt: skip
    assert got[differs["location"], "count differs"]["expected"] == str(differs["boxes"] + 1)
    assert "4 exceptions of" in capsys.readouterr().out
    exact = _wms(tmp_path / "exact.csv", [(r["location"], r["boxes"]) for r in _load(scans["old"]).inventory()])
    assert main(["diff", str(scans["old"]), "--expected", str(exact), "--out", str(out)]) == 0
    assert _exceptions(out) == []


@pytest.mark.parametrize(
    "text, said",
    [
        ("code,count\n01-L-01-01,1\n", "header must hold"),
        ("", "header must hold"),
        ("location,expected\n01-L-01-01,-1\n", "line 2"),
        ("location,expected\n01-L-01-01,two\n", "line 2"),
        ("location,expected\n01-L-01-01,1\n01-L-01-01,2\n", "listed twice"),
        ("location,expected\n", "no location"),
        (b"\xff\xfe\x00location", "UTF-8"),
    ],
)
def test_a_malformed_expected_is_one_line(scans, tmp_path, capsys, text, said):
    wms = tmp_path / "wms.csv"
    wms.write_bytes(text if isinstance(text, bytes) else text.encode())
    assert main(["diff", str(scans["old"]), "--expected", str(wms), "--out", str(tmp_path / "x")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and f"--expected {wms}" in err and said in err, err
    assert not (tmp_path / "x").exists()
    assert main(["diff", str(scans["old"]), str(scans["new"]), "--expected", str(wms), "--out", str(tmp_path)]) == 2
    assert "NEW_MAP" in capsys.readouterr().err
