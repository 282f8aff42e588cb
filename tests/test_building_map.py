"""``mvracklay map``: a tiny generated building's passes placed, registered and fused into one building map with
a location code per slot, its inventory, scenes and free-space queries."""

from __future__ import annotations

import csv
import json
from dataclasses import replace
from pathlib import Path

import pytest

from layouts.errors import InputError
from layouts.locations import NOT_SCANNED, read_inventory
from mvracklay.building_job import MapSettings, map_building
from mvracklay.cli import main
from mvracklay.settings import ComputeSettings, OutputSettings, RunConfig
from stitching.building.config import BuildingConfig, FuseConfig, PlaceConfig
from stitching.building.eval import evaluate_building
from stitching.building.fuse_passes import fuse_building
from stitching.building.map import BuildingMap
from stitching.building.pipeline import build_map
from stitching.building.place import place_pass, register
from stitching.building.route import load_route, parse_pose_noise, perturb
from stitching.export_gltf import glb_json
from stitching.rerun_log import read_entities
from stitching.warehouse_map import WarehouseMap


@pytest.fixture
def building(tiny_building) -> Path:
    return tiny_building


@pytest.fixture
def mapped(tiny_building_map) -> Path:
    return tiny_building_map


def _truth(building: Path) -> tuple[dict, list[dict]]:
    truth = json.loads((building / "ground_truth/building.json").read_text())
    return truth, read_inventory((building / "ground_truth/inventory.csv").read_text())


def _score(building: Path, bmap: BuildingMap):
    return evaluate_building(bmap, *_truth(building))


def _fuse(route, placed, **how) -> BuildingMap:
    """The placed passes (`_placed`, changed by a test) registered and fused, as `build_map` does it."""
    register(route, placed)
    return fuse_building(route, placed, **how)


def _placed(building: Path, mapped: Path, route=None):
    route = route or load_route(building / "route.json")
    maps = {p.sequence: WarehouseMap.load(mapped / "passes" / p.sequence / "warehouse.json") for p in route.passes}
    return route, [place_pass(p, route.faces[p.key], maps[p.sequence]) for p in route.passes]


def test_every_location_coded_and_counted(building, mapped):
    bmap = BuildingMap.load(mapped / "building.json")
    ev = _score(building, bmap)
    assert ev.locations > 20 and ev.exact == ev.locations and ev.invented == 0 and ev.missed == 0
    assert ev.recall == 1.0 and ev.precision == 1.0 and ev.mean_iou > 0.8
    rows = list(csv.DictReader((mapped / "inventory.csv").open()))
    as_json = json.loads((mapped / "inventory.json").read_text())["locations"]
    assert [{k: str(v) for k, v in r.items()} for r in as_json] == rows
    assert all(r["last_seen"] == r["pass"].split(";")[-1] for r in rows)


def test_face_scanned_twice_is_not_doubled(building, mapped):
    route = json.loads((building / "route.json").read_text())["passes"]
    twice = {(p["aisle"], p["side"]) for p in route if p["scan"] == 2}
    assert twice, "the fixture's building scans a face twice"
    truth, rows = _truth(building)
    bmap = BuildingMap.load(mapped / "building.json")
    for aisle, side in twice:
        stacks = sum(int(r["boxes"]) for r in rows if (int(r["aisle"]), r["side"]) == (aisle, side) and r["pass"])
        assert len(bmap.face(aisle, side).map.boxes()) == stacks
    # the same pass fused in twice under another name adds nothing
    r, placed = _placed(building, mapped)
    again = [replace(placed[0], pose=replace(placed[0].pose, sequence="again"))]
    r.passes.append(again[0].pose)
    once, doubled = _fuse(load_route(building / "route.json"), placed), _fuse(r, placed + again)
    assert once.box_count() == doubled.box_count()


def test_pose_noise_keeps_codes_and_counts(building, mapped, tmp_path):
    clean = BuildingMap.load(mapped / "building.json")
    for seed in (0, 1):
        route, placed = _placed(building, mapped, perturb(load_route(building / "route.json"), 0.3, 3.0, seed))
        noisy = _fuse(route, placed)
        ev = _score(building, noisy)
        assert ev.exact == ev.locations and ev.invented == 0 and ev.recall == 1.0 and ev.precision == 1.0
        assert [t[2].code for t in noisy.locations()] == [t[2].code for t in clean.locations()]
        moved = [abs(p.shift) for p in noisy.passes]
        assert max(moved) > 0.1  # registration undid the noise
    # the CLI's option reaches it
    assert main(["map", str(building), "--out", str(tmp_path / "m"), "--layouts", "gt", "--pose-noise", "0.3,3",
                 "--quiet", "--no-rrd"]) == 0  # fmt: skip
    assert BuildingMap.load(tmp_path / "m/building.json").meta["pose_noise"] == [0.3, 3.0]


def test_rack_cut_at_a_pass_end_is_joined(building, mapped):
    _, placed = _placed(building, mapped)
    cut = [(p, r) for p in placed for r in p.racks if r.cut_lo or r.cut_hi]
    assert cut, "some pass ends inside a rack"
    truth, _ = _truth(building)
    bmap = BuildingMap.load(mapped / "building.json")
    for f in bmap.faces:
        for rack in f.map.racks:
            assert rack.partial is None
            t = next(r for r in truth["racks"] if r["id"] == rack.id)
            lo, hi = sorted(f.sign * v for v in rack.x_range)
            assert abs(lo - t["x_min"]) < 0.06 and abs(hi - t["x_max"]) < 0.06


def test_unseen_levels_are_not_scanned_never_empty(building, mapped):
    route, placed = _placed(building, mapped)
    key = next(iter(route.faces))
    plan = route.faces[key]
    route.faces[key] = replace(plan, levels_m=plan.levels_m + (plan.levels_m[-1] + 0.9,))
    top = len(plan.levels_m) + 1
    rows = [r for r in _fuse(route, placed).inventory() if (r["aisle"], r["side"]) == key]
    unseen = [r for r in rows if r["level"] == top]
    assert unseen and all(
        r["boxes"] == NOT_SCANNED and r["confidence"] == 0 and r["free_length_m"] == "" for r in unseen
    )
    assert all(r["boxes"] != NOT_SCANNED for r in rows if r["level"] < top)


def test_outputs_and_resume(building, mapped):
    bmap = BuildingMap.load(mapped / "building.json")
    assert BuildingMap.from_dict(bmap.to_dict()).to_dict() == bmap.to_dict()
    names = {n["name"] for n in glb_json(mapped / "building.glb")["nodes"] if "name" in n}
    codes = {t[2].code for t in bmap.locations()}
    assert codes <= names and "floor" in names and any(n.endswith("/upright_00") for n in names)
    entities = read_entities(mapped / "building.rrd")
    assert {"/building/boxes", "/building/shelves"} <= entities
    assert {f"/passes/{p.name}/camera" for p in bmap.passes} <= entities
    again = map_building(building, mapped, MapSettings(layouts="gt"), outputs=OutputSettings(quiet=True))
    assert again.mapped == 0 and again.map.to_dict() == bmap.to_dict()


def test_free_space_near_a_location(mapped, capsys):
    bmap = BuildingMap.load(mapped / "building.json")
    near = bmap.locations()[-1][2].code
    assert main(["free-space", str(mapped), "--box", "0.3x0.3x0.2", "--near", near, "--json"]) == 0
    fits = json.loads(capsys.readouterr().out)["box"]["fits"]
    assert fits and [f["distance"] for f in fits] == sorted(f["distance"] for f in fits)
    scanned = {r["location"] for r in bmap.inventory() if r["boxes"] != NOT_SCANNED}
    assert {f["location"] for f in fits} <= scanned
    assert main(["free-space", str(mapped), "--box", "0.3x0.3x0.2", "--near", "99-X-01-01"]) == 2
    assert "--near '99-X-01-01'" in capsys.readouterr().err


def test_bad_input_is_one_line(building, tmp_path, capsys):
    assert main(["map", str(tmp_path), "--out", str(tmp_path / "m"), "--layouts", "gt"]) == 2
    assert "no route.json" in capsys.readouterr().err
    assert main(["map", str(building), "--out", str(tmp_path / "m"), "--pose-noise", "0.3"]) == 2
    assert "--pose-noise" in capsys.readouterr().err
    with pytest.raises(InputError, match="METRES,DEGREES"):
        parse_pose_noise("a,b")
    bad = tmp_path / "route.json"
    doc = json.loads((building / "route.json").read_text())
    doc["passes"][0]["side"] = "Q"
    bad.write_text(json.dumps(doc))
    with pytest.raises(InputError, match=r"route.json: passes\[0\].side"):
        load_route(bad)


def test_a_route_file_of_ones_own(building, tmp_path):
    """A route file elsewhere naming its passes' folders relative to itself, levels by ``first_level``."""
    import os

    doc = json.loads((building / "route.json").read_text())
    face = (doc["passes"][0]["aisle"], doc["passes"][0]["side"])
    mine = [p for p in doc["passes"] if (p["aisle"], p["side"]) == face]
    route = {
        "faces": [f for f in doc["faces"] if (f["aisle"], f["side"]) == face],
        "passes": [
            {"sequence": os.path.relpath(building / p["sequence"], tmp_path), "aisle": p["aisle"], "side": p["side"],
             "start": p["start"], "first_level": p["levels"][0]}
            for p in mine
        ],
    }  # fmt: skip
    (tmp_path / "route.json").write_text(json.dumps(route))
    res = map_building(
        tmp_path / "route.json",
        tmp_path / "m",
        MapSettings(layouts="gt"),
        outputs=OutputSettings(rrd=False, quiet=True),
    )
    assert len(res.map.faces) == 1 and res.map.box_count() > 0
    rows = {r["location"]: r for r in res.inventory}
    truth = {r["location"]: r for r in _truth(building)[1] if r["pass"]}
    assert set(rows) <= set(truth) and all(rows[c]["boxes"] == int(truth[c]["boxes"]) for c in rows)


def _listed(building: Path):
    from layouts.location_list import read_location_list

    return read_location_list(building / "locations.csv")


def test_location_list_gives_codes_and_every_row(building, mapped):
    """Codes from the list, never from detection order: renamed codes come back as listed, every listed location
    has a row, and the counts are the ground truth's."""
    listed = _listed(building)
    renamed = [replace(e, code=f"WH1.{k:04d}") for k, e in enumerate(listed)]
    route, placed = _placed(building, mapped)
    bmap = _fuse(route, placed, listed=renamed, listed_source="wms.csv")
    rows = bmap.inventory()
    assert sorted(r["location"] for r in rows) == sorted(e.code for e in renamed)
    truth = {r["location"]: r for r in _truth(building)[1]}
    by_code = {e.code: old.code for e, old in zip(renamed, listed)}
    for r in rows:
        t = truth[by_code[r["location"]]]
        assert (r["aisle"], r["side"], r["bay"], r["level"]) == (
            int(t["aisle"]),
            t["side"],
            int(t["bay"]),
            int(t["level"]),
        )
        assert r["boxes"] == (int(t["boxes"]) if t["pass"] else NOT_SCANNED)
    assert bmap.outside == [] and bmap.location_list == "wms.csv"
    again = BuildingMap.from_dict(bmap.to_dict())  # held to the schema although the codes follow no format
    assert [t[2].code for t in again.locations()] == [t[2].code for t in bmap.locations()]


def test_location_list_not_scanned_and_outside(building, mapped):
    """A pass left out of the route: the locations only it saw are `not scanned` rows, never absent; a box
    outside every listed location is reported with its position, never coded."""
    listed = _listed(building)
    route, placed = _placed(building, mapped)
    truth = _truth(building)[1]
    face = placed[0].pose.key  # every pass of a face left out (each location of the tiny building has two)
    gone = {p.pose.sequence for p in placed if p.pose.key == face}
    route.passes = [p for p in route.passes if p.sequence not in gone]
    bmap = _fuse(route, [p for p in placed if p.pose.sequence not in gone], listed=listed)
    rows = {r["location"]: r for r in bmap.inventory()}
    only_gone = [r["location"] for r in truth if r["pass"] and set(r["pass"].split(";")) <= gone]
    assert only_gone and all(rows[c]["boxes"] == NOT_SCANNED for c in only_gone)
    assert set(rows) == {e.code for e in listed}
    # a bay the list lacks: its boxes lie outside every listed location
    full = {r["location"]: r for r in truth}
    held = next(e for e in listed if full[e.code]["pass"] and int(full[e.code]["boxes"]) > 0)
    gap = [e for e in listed if e.face != held.face or e.bay != held.bay]
    route, placed = _placed(building, mapped)
    bmap = _fuse(route, placed, listed=gap)
    lost = [e for e in listed if e.face == held.face and e.bay == held.bay]
    want = sum(int(full[e.code]["boxes"]) for e in lost if full[e.code]["pass"])
    out = bmap.outside
    assert len(out) == want and {o["face"] for o in out} == {f"{held.aisle:02d}-{held.side}"}
    assert all(held.start_m - 0.01 <= o["x"] <= held.end_m + 0.01 for o in out)
    assert {e.code for e in lost}.isdisjoint(r["location"] for r in bmap.inventory())


def test_locations_from_an_earlier_map_keep_codes(building, mapped, tmp_path, capsys):
    """``map --locations OLD_MAP``: the earlier map's codes, even where they follow no format; the model line."""
    old = BuildingMap.load(mapped / "building.json")
    listed = old.listed()
    assert [e.code for e in listed] == [t[2].code for t in old.locations()]
    from layouts.location_list import write_location_list

    wms = tmp_path / "wms.csv"
    write_location_list([replace(e, code="B-" + e.code) for e in listed], wms)
    first = tmp_path / "first"
    assert main(["map", str(building), "--out", str(first), "--layouts", "gt", "--locations", str(wms),
                 "--no-rrd", "--quiet", "--json-out", str(tmp_path / "s.json")]) == 0  # fmt: skip
    assert "0 boxes outside every listed location" in capsys.readouterr().out
    said = json.loads((tmp_path / "s.json").read_text())
    assert said["outside_listed_locations"] == 0 and said["model"] is None  # ground-truth layouts: no model
    rescan = tmp_path / "rescan"
    assert main(["map", str(building), "--out", str(rescan), "--layouts", "gt", "--locations", str(first),
                 "--no-rrd", "--quiet"]) == 0  # fmt: skip
    rows = read_inventory((rescan / "inventory.csv").read_text())
    assert [r["location"] for r in rows] == ["B-" + e.code for e in listed]
    assert [r["boxes"] for r in rows] == [str(r["boxes"]) for r in old.inventory()]
    bad = tmp_path / "bad.csv"
    bad.write_text("code,aisle,side,bay,level,start_m,end_m\nA,9,L,1,1,0,1\n")
    assert main(["map", str(building), "--out", str(tmp_path / "x"), "--layouts", "gt", "--locations", str(bad),
                 "--quiet"]) == 2  # fmt: skip
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "bad.csv" in err and "09-L" in err


def test_model_for_the_frames_size(building):
    from mvracklay.building_job import choose_model, frame_size

    assert choose_model(256) == "mvracklay-disc-4-256" and choose_model(480) == "mvracklay-disc-4-256"
    assert choose_model(128) == "mvracklay-disc-4" and choose_model(96) == "mvracklay-disc-4"
    route = load_route(building / "route.json")
    assert frame_size(route, building) == 24  # the tiny building's 32 x 24 frames


def test_unseen_stretch_of_the_plan_gets_bays(building, mapped):
    """Without a list: a stretch of a face that the floor plan holds and no pass saw is bays of the face's
    typical length, `not scanned`, numbered in their place; the rest keep their codes and counts."""
    route, placed = _placed(building, mapped)
    before = {r["location"]: r["boxes"] for r in _fuse(route, placed).inventory()}
    key = next(k for k in sorted(route.faces) if k[1] == "R")
    plan = route.faces[key]
    route.faces[key] = replace(plan, x_max=plan.x_max + 5.0)
    rows = {r["location"]: r for r in _fuse(route, placed).inventory()}
    added = {c: r for c, r in rows.items() if c not in before}
    assert {c: rows[c]["boxes"] for c in before} == before
    bays = sorted({r["bay"] for r in added.values()})
    top = max(r["bay"] for r in rows.values() if r["location"] in before and (r["aisle"], r["side"]) == key)
    assert bays == list(range(top + 1, top + 1 + len(bays))) and len(bays) >= 1
    assert all(r["boxes"] == NOT_SCANNED and (r["aisle"], r["side"]) == key for r in added.values())


def test_a_box_taller_than_its_level_stands_within_it(building, mapped, tmp_path):
    """A pass that measured its level higher than the plan's saw a box taller than the fused level: the map
    keeps it within its level, on its board, and writes (the row-map schema holds)."""
    route, placed = _placed(building, mapped)
    rack = next(r for p in placed for r in p.racks if r.boxes)
    bx = rack.boxes[0]
    rack.boxes[0] = replace(bx, size=(bx.size[0], 3.0, bx.size[2]), rel=1.5)
    for listed in (None, _listed(building)):
        bmap = _fuse(route, placed, listed=listed)
        bmap.save(tmp_path / "building.json")
        for _, shelf, _ in bmap.locations():
            for b in shelf.boxes:
                assert b.size[1] <= shelf.clear_height + 1e-9
                assert -b.center[1] - b.size[1] / 2 >= shelf.board_height - 1e-9


def _maps(building: Path, mapped: Path):
    route = load_route(building / "route.json")
    return route, {
        p.sequence: WarehouseMap.load(mapped / "passes" / p.sequence / "warehouse.json") for p in route.passes
    }


def test_one_call_places_registers_and_fuses(building, mapped):
    """`build_map` from the route and the row maps is the building `mvracklay map` wrote; its settings reach the
    steps: a registration that asks for more matches than any overlap has leaves the passes on their route poses,
    and a box of one pass never the same as another's counts every box seen twice twice."""
    saved = BuildingMap.load(mapped / "building.json")
    route, maps = _maps(building, mapped)
    how = {"code": saved.code, "positions": saved.positions, "meta": saved.meta}
    assert build_map(route, maps, **how).to_dict() == saved.to_dict()
    alone = build_map(route, maps, BuildingConfig(place=PlaceConfig(min_matches=10**6)), **how)
    assert all(e["with"] not in maps for p in alone.passes for e in p.edges)
    assert any(e["with"] in maps for p in saved.passes for e in p.edges)
    doubled = build_map(route, maps, BuildingConfig(fuse=FuseConfig(same_box=2.0, ghost=2.0)), **how)
    assert doubled.box_count() > saved.box_count()


def test_building_settings_are_checked(building, mapped):
    route, maps = _maps(building, mapped)
    with pytest.raises(InputError, match=r"^FuseConfig.same_box must be a finite number >= 0, got -1"):
        FuseConfig(same_box=-1)
    with pytest.raises(InputError, match=r"^PlaceConfig.outlier must be a finite number >= 0, got nan"):
        PlaceConfig(outlier=float("nan"))
    with pytest.raises(InputError, match=r"^BuildingConfig.fuse must be a FuseConfig, got PlaceConfig"):
        BuildingConfig(fuse=PlaceConfig())
    with pytest.raises(InputError, match="no row map for pass"):
        build_map(route, {k: v for k, v in list(maps.items())[1:]})
    with pytest.raises(InputError, match=r"^--layouts must be 'gt' or 'net', got 'truth'"):
        MapSettings(layouts="truth")
    with pytest.raises(InputError, match=r"^--workers must be >= 1, got 0"):
        map_building(building, mapped, compute=ComputeSettings(workers=0))


def test_a_box_reaching_into_a_better_seen_one_is_dropped(building, mapped):
    """Boxes stand side by side on a level: a pass's box placed 40 % of its width into a box another pass saw
    better (a copy placed off) is none; with the rule off (``ghost`` above any overlap) it is counted."""

    def fused(ghost: bool, cfg: FuseConfig | None = None) -> int:
        route, placed = _placed(building, mapped)
        if ghost:
            r = next(r for p in placed for r in p.racks if r.boxes)
            b = max(r.boxes, key=lambda b: b.size[0])
            r.boxes.append(replace(b, x=b.x + 0.4 * b.size[0], observations=1, confidence=0.5))
        return _fuse(route, placed, cfg=cfg).box_count()

    base = fused(False)
    assert fused(True) == base
    assert fused(True, FuseConfig(ghost=2.0)) == base + 1


def test_a_pass_is_mapped_again_only_when_what_decides_its_row_map_changed(building, tmp_path):
    """The thread count (``--threads auto`` follows the machine's load) never makes a stored pass stale; the model
    does."""
    from mvracklay.building_job import pass_tasks

    route = load_route(building / "route.json")

    def keys(**run) -> list[str]:
        return [t.key for t in pass_tasks(route, building, tmp_path, "net", RunConfig(**run))]

    assert keys(checkpoint="a.pt", threads=1) == keys(checkpoint="a.pt", threads=2)
    assert keys(checkpoint="a.pt", threads=1) != keys(checkpoint="b.pt", threads=1)


def test_a_pass_key_is_the_one_earlier_maps_stored(building, tmp_path):
    """A map's stored passes stay reused: a network pass's key digests the same words as the maps made before the
    run settings were typed (the frames, the layouts, the settings the command names, never the threads), and a
    setting the command does not name enters it once it leaves its default."""
    import hashlib

    from mvracklay.building_job import pass_run, pass_tasks

    route = load_route(building / "route.json")
    settings = MapSettings(layouts="net", run=RunConfig(checkpoint=Path("a.pt"), distance=2.5))
    run = pass_run(settings, ComputeSettings(threads=3, device="cpu"))
    task = pass_tasks(route, building, tmp_path, "net", run)[0]
    said = {"checkpoint": "a.pt", "distance": 2.5, "camera_height": None, "device": "cpu", "rrd": False,
            "progress": False}  # fmt: skip
    assert task.key == hashlib.sha256(json.dumps([task.source, "net", said], sort_keys=True).encode()).hexdigest()[:16]
    gt = pass_tasks(route, building, tmp_path, "gt", None)[0]
    assert gt.key == hashlib.sha256(json.dumps([gt.source, "gt", {}]).encode()).hexdigest()[:16]
    flipped = replace(run, inference=replace(run.inference, flip=True))
    assert pass_tasks(route, building, tmp_path, "net", flipped)[0].key != task.key


def test_a_map_takes_typed_run_settings_and_its_own_compute(building, tmp_path):
    """``MapSettings.run`` is a `RunConfig`; the threads, device and precision of a pass are the map's
    `ComputeSettings` (said in one line when set on the run instead)."""
    from mvracklay.building_job import pass_run

    with pytest.raises(InputError, match=r"^MapSettings.run must be a RunConfig, got dict$"):
        MapSettings(run={"checkpoint": "a.pt"})
    with pytest.raises(InputError, match=r"^MapSettings.run: threads, device are the map's \(ComputeSettings\)"):
        MapSettings(run=RunConfig(threads=1, device="cpu"))
    run = pass_run(MapSettings(run=RunConfig(distance=3.0)), ComputeSettings(threads="auto", workers=2, device="cpu"))
    assert (run.distance, run.device, run.rrd, run.progress) == (3.0, "cpu", False, False)
    assert run.threads >= 1
    assert pass_run(MapSettings(), ComputeSettings(threads="auto", ray="127.0.0.1:1")).threads == 1
    with pytest.raises(InputError, match=r"^--workers must be in \[1, 256\], got 300"):
        map_building(building, tmp_path / "m", compute=ComputeSettings(workers=300))
