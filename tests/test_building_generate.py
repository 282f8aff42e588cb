"""``generate --building``: a tiny building's passes, route record, location codes and inventory."""

from __future__ import annotations

import csv
import json
import shutil
from pathlib import Path

import pytest

from layouts.errors import InputError
from layouts.spec import LayoutSpec
from mvracklay.cli import main
from waresynth.building.generate import generate_building
from waresynth.dataset import open_dataset

BUILDING = {
    "aisles": 2, "bays": [3, 4], "bay_width": [1.6, 2.0], "levels": [2, 3], "pass_length": 4.0,
    "overlap": [1.5, 1.5], "twice_share": 0.5,
}  # fmt: skip
CONFIG = {"camera": {"step": [2.0, 2.0]}}  # two or three frames a pass
SMALL = dict(building=BUILDING, config=CONFIG, image_size=(32, 24), spec=LayoutSpec(size=16), seed=1, progress=False)


def tree_bytes(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def built(tmp_path_factory) -> Path:
    return generate_building(tmp_path_factory.mktemp("b") / "building", **SMALL)


def _route(root: Path) -> list[dict]:
    return json.loads((root / "route.json").read_text())["passes"]


def _to_building(rec: dict, center: list[float]) -> tuple[float, float, float]:
    """A pass's row-frame point in the building frame (route.json's row_frame)."""
    x, y, z = center
    front, flip = rec["row_frame"]["front_z"], rec["row_frame"]["flip"]
    return (-x if flip else x, y, front - z if flip else front + z)


def test_same_seed_same_bytes_any_worker_count(built, tmp_path):
    again = generate_building(tmp_path / "again", **{**SMALL, "workers": 2})
    assert tree_bytes(again) == tree_bytes(built)
    other = generate_building(tmp_path / "other", **{**SMALL, "seed": 2})
    assert tree_bytes(other)["ground_truth/building.json"] != tree_bytes(built)["ground_truth/building.json"]


def test_passes_are_sequences_with_a_route(built):
    ds = open_dataset(built)
    passes = _route(built)
    assert [s.name for s in ds.sequences("test")] == [p["sequence"] for p in passes]
    assert {(p["aisle"], p["side"]) for p in passes} == {(a, s) for a in (1, 2) for s in "LR"}
    for p, seq in zip(passes, ds.sequences()):
        assert seq.num_frames == p["frames"] and p["direction"] in ("+X", "-X") and p["bays"]
        first = seq.camera_positions()[0]
        x, _, z = _to_building(p, [first[0], first[1], first[2]])
        assert (x, z) == pytest.approx((p["start"]["x"], p["start"]["z"]), abs=1e-5)
        assert p["start"]["heading_deg"] == (90.0 if p["side"] == "R" else -90.0)


def test_overlapping_and_repeated_passes_show_the_same_boxes(built):
    passes = _route(built)
    by_face: dict[tuple, list[dict]] = {}
    for p in passes:
        by_face.setdefault((p["aisle"], p["side"]), []).append(p)
    assert any(len(v) > 1 and len({p["scan"] for p in v}) == 2 for v in by_face.values())  # a face scanned twice
    shared = 0
    for recs in by_face.values():
        seen: dict[str, tuple] = {}
        for p in recs:
            scene = json.loads((built / p["sequence"] / "scene.json").read_text())
            for rack in scene["racks"]:
                for shelf in rack["shelves"]:
                    for box in shelf["boxes"]:
                        where = _to_building(p, box["center"]) + tuple(box["size"])
                        if box["id"] in seen:
                            shared += 1
                            assert where == pytest.approx(seen[box["id"]], abs=1e-9)
                        seen[box["id"]] = where
    assert shared > 0


def test_codes_unique_and_inventory_matches_building(built):
    doc = json.loads((built / "ground_truth" / "building.json").read_text())
    rows = list(csv.DictReader((built / "ground_truth" / "inventory.csv").open()))
    positions = {
        pos["location"]: (rack, level, pos)
        for rack in doc["racks"]
        for level in rack["levels"]
        for pos in level["positions"]
    }
    codes = [r["location"] for r in rows]
    assert len(codes) == len(set(codes)) == len(positions) and set(codes) == set(positions)
    assert "01-L-01-01" in positions
    route = _route(built)
    for r in rows:
        rack, level, pos = positions[r["location"]]
        assert r["location"] == f"{int(r['aisle']):02d}-{r['side']}-{int(r['bay']):02d}-{int(r['level']):02d}"
        assert int(r["boxes"]) == len({b["stack"] for b in pos["boxes"]})  # stacks, as the map counts them
        assert 0.0 <= float(r["occupancy"]) <= 1.0 and r["confidence"] == "1" and r["partial"] == "false"
        want = [p["sequence"] for p in route
                if (p["aisle"], p["side"]) == (rack["aisle"], rack["side"]) and rack["bay"] in p["bays"]
                and level["level"] in p["levels"]]  # fmt: skip
        assert r["pass"] == ";".join(want) and r["last_seen"] == (want[-1] if want else "")
        for box in pos["boxes"]:
            assert (
                rack["x_min"] <= box["center"][0] <= rack["x_max"]
                and rack["z_min"] <= box["center"][2] <= rack["z_max"]
            )
    assert sum(int(r["boxes"]) for r in rows) > 0
    assert all(r["pass"] for r in rows)  # every pass's camera sees every level of its face here


def test_codes_stable_when_the_passes_change(built, tmp_path):
    """Codes and racks come from the rack positions alone: other passes over the same building keep them."""
    other = generate_building(
        tmp_path / "passes", **{**SMALL, "building": {**BUILDING, "pass_length": 6.0, "twice_share": 1.0}}
    )
    assert (other / "ground_truth" / "building.json").read_bytes() == (
        built / "ground_truth" / "building.json"
    ).read_bytes()
    assert len(_route(other)) != len(_route(built))


def test_resume_skips_complete_passes(built, tmp_path):
    root = tmp_path / "resume"
    shutil.copytree(built, root)
    before = tree_bytes(root)
    keep = (root / "pass_000" / "meta.json").stat().st_mtime_ns
    shutil.rmtree(root / "pass_001")
    (root / ".pass_001.tmp" / "rgb").mkdir(parents=True)  # an interrupted write
    generate_building(root, **SMALL)
    assert tree_bytes(root) == before
    assert (root / "pass_000" / "meta.json").stat().st_mtime_ns == keep


@pytest.mark.parametrize(
    "text, match",
    [
        ('{"aisles": 0}', "aisles: Input should be greater than or equal to 1"),
        ('{"bays": [5, 2]}', "bays: \\[low, high\\] with low <= high"),
        ('{"floors": 2}', "unknown key 'floors'"),
        ('{"positions": 2}', "code must hold \\{position\\}"),
        ("[1]", "must be a JSON object"),
        ("{not json", "not valid JSON"),
    ],
)
def test_bad_building_file_is_one_line(tmp_path, capsys, text, match):
    bad = tmp_path / "bad.json"
    bad.write_text(text)
    assert main(["generate", str(tmp_path / "out"), "--building", str(bad), "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "bad.json" in err
    assert pytest.raises(InputError, generate_building, tmp_path / "x", building=str(bad)).match(match)
    assert not (tmp_path / "out").exists()


def test_cli_building(tmp_path, capsys):
    spec = tmp_path / "b.json"
    spec.write_text(json.dumps({**BUILDING, "aisles": 1, "bays": [2, 2]}))
    cfg = tmp_path / "c.json"
    cfg.write_text(json.dumps(CONFIG))
    args = ["generate", str(tmp_path / "o"), "--building", str(spec), "--config", str(cfg), "--size", "32",
            "--layout-size", "16", "--quiet"]  # fmt: skip
    assert main(args) == 0
    assert "a building of" in capsys.readouterr().out
    assert (tmp_path / "o" / "ground_truth" / "inventory.csv").is_file()
    assert main([*args, "--shard", "0/2"]) == 2


@pytest.mark.parametrize("option", [["--frames", "20"], ["--sequences", "3"], ["--shard", "0/2"]])
def test_options_a_building_does_not_take_are_refused(tmp_path, capsys, option):
    assert main(["generate", str(tmp_path / "out"), "--building", *option, "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--building" in err[0]
    assert not (tmp_path / "out").exists()
