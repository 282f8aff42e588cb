"""``generate --building --rescan``: a tiny building changed by a seeded change set, its ground truth and
changes.csv consistent with the scan before, the same bytes for the same seed, and the refusals."""

from __future__ import annotations

import csv
import json
import math
import shutil
from collections import Counter
from pathlib import Path

import pytest

from layouts.errors import InputError
from layouts.spec import LayoutSpec
from mvracklay.cli import main
from waresynth.building.changes import MIN_SHIFT, apply_changes, changes_rows
from waresynth.building.generate import generate_building
from waresynth.building.plan import plan_building
from waresynth.building.schema import load_building
from waresynth.config import load_config

BUILDING = {
    "aisles": 1, "bays": [3, 3], "bay_width": [1.8, 2.2], "levels": [2, 3], "pass_length": 4.0,
    "overlap": [1.5, 1.5], "twice_share": 0.0,
}  # fmt: skip
CONFIG = {"camera": {"step": [2.0, 2.0]}}
SMALL = dict(building=BUILDING, config=CONFIG, image_size=(32, 24), spec=LayoutSpec(size=16), seed=1, progress=False)
RATES = {"removed": 0.15, "added": 0.15, "moved": 0.15, "shifted": 0.15, "replaced": 0.1}
CHANGED = {**BUILDING, "changes": RATES}


def tree_bytes(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def scans(tmp_path_factory) -> tuple[Path, Path]:
    tmp = tmp_path_factory.mktemp("rescan")
    before = generate_building(tmp / "before", **SMALL)
    after = generate_building(tmp / "after", rescan=before, building=CHANGED, seed=7, progress=False)
    return before, after


def _boxes(root: Path) -> dict[str, dict]:
    """Box id -> box (with its location and rack) of a scan's building.json."""
    doc = json.loads((root / "ground_truth" / "building.json").read_text())
    return {
        box["id"]: {**box, "location": pos["location"], "rack": rack, "clear": level["clear_height"]}
        for rack in doc["racks"]
        for level in rack["levels"]
        for pos in level["positions"]
        for box in pos["boxes"]
    }


def _counts(root: Path) -> dict[str, int]:
    return {r["location"]: int(r["boxes"]) for r in csv.DictReader((root / "ground_truth" / "inventory.csv").open())}


def _changes(root: Path) -> list[dict]:
    return list(csv.DictReader((root / "ground_truth" / "changes.csv").open()))


def test_every_change_appears_and_matches_both_inventories(scans):
    before, after = scans
    rows = _changes(after)
    assert {r["change"] for r in rows} == {"added", "removed", "moved", "shifted"}
    assert any(r["note"] == "replaced" for r in rows)
    old, new = _boxes(before), _boxes(after)
    delta: Counter[str] = Counter()
    for r in rows:
        ids = r["box_ids"].split(";") if r["box_ids"] else []
        old_ids = r["old_box_ids"].split(";") if r["old_box_ids"] else []
        for i in old_ids:  # the stack as it stood
            assert i in old and old[i]["location"] == (r["other_location"] if r["change"] == "moved" else r["location"])
        for i in ids:  # the stack as it stands
            assert i in new and new[i]["location"] == r["location"]
            assert "x".join(f"{v:.3f}" for v in (new[i]["size"][0], new[i]["size"][1], new[i]["size"][2])) == r["size"]
        n = int(r["boxes"])
        if r["change"] == "added":
            assert len(ids) == n and not old_ids and not r["old_x"]
            delta[r["location"]] += 1  # the inventory counts stacks
        elif r["change"] == "removed":
            assert len(old_ids) == n and not ids and not r["x"]
            delta[r["location"]] -= 1
        elif r["change"] == "moved":
            assert r["other_location"] and r["other_location"] != r["location"] and len(ids) == len(old_ids) == n
            delta[r["location"]] += 1
            delta[r["other_location"]] -= 1
        else:  # shifted: the same location, another x, by at least MIN_SHIFT
            assert not r["other_location"] and len(ids) == len(old_ids) == n
            assert abs(float(r["x"]) - float(r["old_x"])) >= MIN_SHIFT - 1e-4
            assert abs(new[ids[0]]["center"][0] - old[old_ids[0]]["center"][0]) >= MIN_SHIFT - 1e-4
    cb, ca = _counts(before), _counts(after)
    assert set(cb) == set(ca)
    assert {k: ca[k] - cb[k] for k in ca if ca[k] != cb[k]} == {k: v for k, v in delta.items() if v}
    # every box no change names stands where it stood
    named_new = {i for r in rows for i in r["box_ids"].split(";") if i}
    named_old = {i for r in rows for i in r["old_box_ids"].split(";") if i}

    def where(boxes: dict, skip: set) -> Counter:
        return Counter((b["location"], *b["center"], *b["size"]) for i, b in boxes.items() if i not in skip)

    assert where(new, named_new) == where(old, named_old)
    assert len(named_old) > 0 and len(named_new) > 0


def test_no_overlap_and_boxes_within_their_levels(scans):
    _, after = scans
    doc = json.loads((after / "ground_truth" / "building.json").read_text())
    for rack in doc["racks"]:
        for level in rack["levels"]:
            stacks = {}
            for pos in level["positions"]:
                for box in pos["boxes"]:
                    w, h, d = box["size"]
                    hx = 0.5 * (abs(math.cos(box["yaw"])) * w + abs(math.sin(box["yaw"])) * d)
                    stacks[box["id"].rsplit("/", 1)[0]] = (box["center"][0] - hx, box["center"][0] + hx)
                    top = -box["center"][1] + h / 2 - (-level["board_top_y"])
                    assert top <= level["clear_height"] + 1e-6
                    assert rack["z_min"] - 1e-6 <= box["center"][2] <= rack["z_max"] + 1e-6
            spans = sorted(stacks.values())
            assert all(a[1] <= b[0] + 1e-9 for a, b in zip(spans, spans[1:])), (rack["id"], level["level"], spans)
            assert all(rack["x_min"] <= a and b <= rack["x_max"] for a, b in spans)


def test_rescan_draws_its_own_cameras_and_records_its_source(scans):
    before, after = scans
    rb = json.loads((before / "route.json").read_text())["passes"]
    ra = json.loads((after / "route.json").read_text())["passes"]
    assert [(p["start"], p["height"]) for p in rb] != [(p["start"], p["height"]) for p in ra]
    m = json.loads((after / "manifest.json").read_text())
    assert m["rescan_of"]["seed"] == 1 and m["rescan_of"]["racks_seed"] == 1 and m["rescan_of"]["earlier_changes"] == []
    assert len(m["rescan_of"]["building_sha256"]) == 64 and m["building"]["changes"] == RATES
    own = json.loads((before / "manifest.json").read_text())
    assert (m["config"], m["spec"], m["image_size"]) == (own["config"], own["spec"], own["image_size"])


def test_same_seed_same_bytes_and_a_rescan_of_a_rescan(scans, tmp_path):
    before, after = scans
    again = generate_building(tmp_path / "again", rescan=before, building=CHANGED, seed=7, progress=False)
    assert tree_bytes(again) == tree_bytes(after)
    other = generate_building(tmp_path / "other", rescan=before, building=CHANGED, seed=8, progress=False)
    assert (other / "ground_truth" / "changes.csv").read_bytes() != (
        after / "ground_truth" / "changes.csv"
    ).read_bytes()
    third = generate_building(tmp_path / "third", rescan=after, seed=7, progress=False)  # OUT's own rates
    m = json.loads((third / "manifest.json").read_text())["rescan_of"]
    assert m["racks_seed"] == 1 and m["earlier_changes"] == [{"seed": 7, "rates": RATES}]
    assert _changes(third)


def test_rates_zero_keep_the_ground_truth(scans, tmp_path):
    before, _ = scans
    zero = {k: 0.0 for k in RATES}
    again = {**BUILDING, "changes": zero, "twice_share": 1.0}  # the pass keys may differ
    same = generate_building(tmp_path / "same", rescan=before, building=again, seed=3, progress=False)
    gt = "ground_truth"
    assert (same / gt / "building.json").read_bytes() == (before / gt / "building.json").read_bytes()
    assert (same / gt / "changes.csv").read_text().splitlines() == [
        "location,change,other_location,boxes,size,box_ids,old_box_ids,x,old_x,note"
    ]
    assert _counts(same) == _counts(before)
    passes = json.loads((same / "route.json").read_text())["passes"]
    assert {p["scan"] for p in passes} == {1, 2}
    assert len(passes) > len(json.loads((before / "route.json").read_text())["passes"])


def test_apply_changes_api():
    cfg = load_config(CONFIG)
    plan = plan_building(load_building(BUILDING), cfg, 2, (32, 24), 3)
    n = sum(len(s) for f in plan.faces for r in f.row.racks for s in r.stacks)
    changed, changes = apply_changes(plan, {**dict.fromkeys(RATES, 0.0), "removed": 0.25}, 5, cfg)
    assert [c.change for c in changes] == ["removed"] * math.floor(0.25 * n + 0.5)
    assert sum(len(s) for f in changed.faces for r in f.row.racks for s in r.stacks) == n - len(changes)
    assert sum(len(s) for f in plan.faces for r in f.row.racks for s in r.stacks) == n  # the input is kept
    again, _ = apply_changes(plan, {**dict.fromkeys(RATES, 0.0), "removed": 0.25}, 5, cfg)
    assert [r.stacks for f in again.faces for r in f.row.racks] == [
        r.stacks for f in changed.faces for r in f.row.racks
    ]
    with pytest.raises(InputError, match="removed \\+ moved"):
        apply_changes(plan, {"removed": 0.6, "moved": 0.6}, 5, cfg)
    with pytest.raises(InputError, match="unknown change|Extra inputs"):
        apply_changes(plan, {"stolen": 0.1}, 5, cfg)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"building": {**BUILDING, "bays": [4, 4]}}, "differs from its own in bays"),
        ({"image_size": (64, 64)}, "image size"),
        ({"spec": LayoutSpec(size=32)}, "layout spec"),
        ({"config": {**CONFIG, "boxes": {"max_stack": 1}}}, "--config differs from its config in boxes"),
        ({"building": {**BUILDING, "changes": {"removed": 2}}}, "changes.removed"),
    ],
)
def test_mismatched_options_are_refused(scans, tmp_path, kwargs, match):
    before, _ = scans
    with pytest.raises(InputError, match=match):
        generate_building(tmp_path / "out", rescan=before, seed=2, progress=False, **kwargs)
    assert not (tmp_path / "out").exists()


def test_not_a_building_or_an_edited_one_is_refused(scans, tmp_path, capsys):
    before, _ = scans
    plain = tmp_path / "plain"
    plain.mkdir()
    m = json.loads((before / "manifest.json").read_text())
    del m["building"]
    (plain / "manifest.json").write_text(json.dumps(m))
    with pytest.raises(InputError, match="not a building dataset"):
        generate_building(tmp_path / "o1", rescan=plain, progress=False)
    edited = tmp_path / "edited"
    shutil.copytree(before, edited)
    truth = edited / "ground_truth" / "building.json"
    truth.write_text(truth.read_text().replace('"stack": 0', '"stack": 9', 1))
    with pytest.raises(InputError, match="not the building its manifest plans"):
        generate_building(tmp_path / "o2", rescan=edited, progress=False)
    with pytest.raises(InputError, match="only with --rescan"):
        generate_building(tmp_path / "o3", **{**SMALL, "building": CHANGED})
    for args in (["--rescan", str(before)], ["--building", "--rescan", str(before / "pass_000")],
                 ["--building", "--rescan", str(before), "--size", "64"]):  # fmt: skip
        assert main(["generate", str(tmp_path / "o4"), *args, "--quiet"]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "--rescan" in err[0]
    assert main(["generate", str(before / "inside"), "--building", "--rescan", str(before), "--quiet"]) == 2
    assert "--rescan" in capsys.readouterr().err
    assert not any((tmp_path / f"o{k}").exists() for k in range(1, 5))


def test_cli_rescan(scans, tmp_path, capsys):
    before, after = scans
    spec = tmp_path / "b.json"
    spec.write_text(json.dumps(CHANGED))
    out = tmp_path / "cli"
    assert main(["generate", str(out), "--building", str(spec), "--rescan", str(before), "--seed", "7", "--quiet"]) == 0
    assert "a rescan of" in capsys.readouterr().out
    assert tree_bytes(out) == tree_bytes(after)


def test_positions_shift_within_and_move_between_locations():
    cfg = load_config(CONFIG)
    bcfg = load_building({**BUILDING, "positions": 2, "code": "{aisle:02d}-{side}-{bay:02d}-{level:02d}-{position}"})
    plan = plan_building(bcfg, cfg, 4, (32, 24), 3)
    changed, changes = apply_changes(plan, {**RATES, "shifted": 0.3, "moved": 0.3, "removed": 0.0}, 9, cfg)
    rows = changes_rows(plan, changed, changes)
    shifted = [r for r in rows if r["change"] == "shifted"]
    moved = [r for r in rows if r["change"] == "moved"]
    assert shifted and moved
    for r in shifted:
        assert r["old_box_ids"].split("/")[0] == r["location"] and abs(r["x"] - r["old_x"]) >= MIN_SHIFT - 1e-4
    for r in moved:
        assert r["old_box_ids"].split("/")[0] == r["other_location"] != r["location"]
