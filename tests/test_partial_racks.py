"""Partly seen racks: racks cut by the first or last view are marked partial in the map, and their unseen
length never counts as free space (free-space table, JSON, CSV, `fits`)."""

import csv
import io
import json

import numpy as np
import pytest

from layouts import InputError
from mvracklay.cli import main
from stitching.free_space import (
    PARTIAL_CONFIDENCE,
    PARTIAL_LEGEND,
    UPRIGHT_INSET,
    clear_span,
    fits,
    format_table,
    free_space,
    shelf_free_space,
)
from stitching.merge import _partial_run
from stitching.pipeline import reconstruct
from stitching.synthetic import make_sequence
from stitching.warehouse_map import MapBox, MapRack, MapShelf, StepRecord, WarehouseMap


@pytest.fixture(scope="module")
def short_map():
    """12 frames: rack_00 starts before the first view, rack_01 runs on past the last one."""
    seq = make_sequence(seed=3, frames=12, step=0.1)
    return reconstruct(seq.layouts, seq.spec).map


@pytest.fixture(scope="module")
def long_map():
    """40 frames of the same row: rack_01 and rack_02 are now seen whole."""
    seq = make_sequence(seed=3, frames=40, step=0.1)
    return reconstruct(seq.layouts, seq.spec).map


def _hand_map(partial: str | None) -> WarehouseMap:
    """One 2 m shelf, boxes over X 0.5..1.0 and 1.2..1.5: gaps 0..0.5, 1.0..1.2, 1.5..2.0."""
    boxes = [
        MapBox("rack_00/shelf_00/box_000", (0.75, -0.2, 0.0), (0.5, 0.4, 0.6), 0.0, 1.0, 5),
        MapBox("rack_00/shelf_00/box_001", (1.35, -0.2, 0.0), (0.3, 0.4, 0.6), 0.0, 1.0, 5),
    ]
    shelf = MapShelf("rack_00/shelf_00", 0, 0.0, 0.9, (0.0, 2.0), (-0.5, 0.5), 1.0, boxes, partial)
    steps = [StepRecord(0, 0, 0, 0, 1, "first", 0)]
    return WarehouseMap([MapRack("rack_00", (0.0, 2.0), [shelf], partial)], steps, 0.05, seen_x=[(0.0, 2.0)])


def test_cut_racks_are_partial_and_whole_racks_are_not(short_map, long_map):
    assert len(short_map.seen_x) == 1
    lo, hi = short_map.seen_x[0]
    assert lo == pytest.approx(-1.5) and hi == pytest.approx(1.1 + 1.5, abs=0.05)
    assert [r.partial for r in short_map.racks] == ["start", "end"]
    assert short_map.racks[0].x_range[0] == pytest.approx(lo)  # the seen part only
    for r in short_map.racks:
        assert r.shelves and all(s.partial == r.partial for s in r.shelves)
    # Seen for longer: rack_01 (0.14..2.78 from the first camera) and rack_02 are whole, rack_00 still cut.
    assert [r.partial for r in long_map.racks] == ["start", None, None]
    assert long_map.racks[1].x_range[1] == pytest.approx(2.781, abs=0.03)
    rows = {r.shelf: r for r in free_space(long_map)}
    whole = [r for sid, r in rows.items() if sid.startswith("rack_01/")]
    assert all(r.partial is None and r.unknown_length == 0 and not r.unknown for r in whole)


def test_unseen_length_is_not_free(short_map):
    rows = free_space(short_map)
    for r in rows:
        shelf = short_map.shelf(r.shelf)
        lo, hi = shelf.x_range
        c0, c1 = clear_span(shelf)  # inside the uprights; a cut end stays where the view ended
        assert (c0 == lo) == (shelf.partial in ("start", "both")) and (c1 == hi) == (shelf.partial in ("end", "both"))
        assert r.partial == shelf.partial and r.length == pytest.approx(c1 - c0)
        spans = [b.cuboid.x_range() for b in shelf.boxes]
        # The cut end is either in a box or ends the one unknown gap; every other gap stays free.
        if shelf.partial == "start":
            assert r.unknown == [] if min(a for a, _ in spans) <= lo else r.unknown[0][0] == pytest.approx(lo)
        else:
            assert r.unknown == [] if max(b for _, b in spans) >= hi else r.unknown[-1][1] == pytest.approx(hi)
        assert len(r.unknown) <= 1 and r.unknown_length == pytest.approx(sum(b - a for a, b in r.unknown))
        assert r.free_length == pytest.approx(sum(b - a for a, b in r.gaps))
        assert r.free_length + r.unknown_length < r.length
        assert r.free_area <= (r.length - r.unknown_length) * r.depth + 1e-9
    assert sum(r.unknown_length for r in rows) > 0.3
    # fits never offers a centre whose box would reach into unknown length.
    unknown = {r.shelf: r.unknown for r in rows}
    placed = fits(short_map, 0.2, 0.2, 0.2)
    for f in placed:
        for c0, c1 in f.centres:
            for a, b in unknown[f.shelf]:
                assert c1 + f.along_x / 2 <= a + 1e-9 or c0 - f.along_x / 2 >= b - 1e-9


def test_hand_map_partial_numbers():
    whole, cut = shelf_free_space(_hand_map(None).shelves()[0]), shelf_free_space(_hand_map("end").shelves()[0])
    u = UPRIGHT_INSET  # the gaps at the uprights end inside them
    assert whole.free_length == pytest.approx(1.2 - 2 * u) and whole.unknown_length == 0
    assert cut.free_length == pytest.approx(0.7 - u) and cut.unknown_length == pytest.approx(0.5)
    assert cut.unknown == [pytest.approx((1.5, 2.0))] and cut.gaps == [
        pytest.approx((u, 0.5)),
        pytest.approx((1.0, 1.2)),
    ]
    known = 1.5 - u  # the clear span's known part
    assert cut.free_area == pytest.approx(known - 0.48) and cut.occupancy == pytest.approx(0.8 / known)  # length
    assert cut.free_volume == pytest.approx(known * 0.9 - 0.48 * 0.4)
    assert cut.confidence == pytest.approx(whole.confidence * PARTIAL_CONFIDENCE)
    both = shelf_free_space(_hand_map("both").shelves()[0])
    assert both.free_length == pytest.approx(0.2) and both.unknown_length == pytest.approx(1.0)
    assert both.confidence == pytest.approx(PARTIAL_CONFIDENCE**2)
    # A 0.3 m box fits in u..0.5 and 1.5..2-u of the whole shelf, only in u..0.5 when the end is cut; a 0.4 m one
    # no longer fits next to an upright.
    assert [f.centres for f in fits(_hand_map(None), 0.3, 0.3, 0.3)][0] == [
        pytest.approx((u + 0.15, 0.35)),
        pytest.approx((1.65, 1.85 - u)),
    ]
    assert [f.centres for f in fits(_hand_map("end"), 0.3, 0.3, 0.3)][0] == [pytest.approx((u + 0.15, 0.35))]
    assert fits(_hand_map("both"), 0.3, 0.3, 0.3) == []
    assert fits(_hand_map(None), 0.4, 0.4, 0.4) == []


def test_table_marks_partial_shelves(short_map, long_map):
    text = format_table(free_space(short_map), racks=len(short_map.racks))
    head, rule, *body = text.splitlines()
    assert "partial" in head and "unknown" in head
    assert body[-1] == PARTIAL_LEGEND
    by_shelf = {line.split()[0]: line.split() for line in body[:-1]}
    assert by_shelf["rack_00/shelf_00"][-1] == "start" and by_shelf["rack_01/shelf_00"][-1] == "end"
    whole = format_table([r for r in free_space(long_map) if r.partial is None])
    assert PARTIAL_LEGEND not in whole and all(line.split()[-1] == "-" for line in whole.splitlines()[2:])


def test_free_space_json_and_csv_show_partial(tmp_path, capsys, short_map):
    path = tmp_path / "warehouse.json"
    short_map.save(path)
    assert main(["free-space", str(path), "--json", "--box", "0.2x0.2x0.2"]) == 0
    out = json.loads(capsys.readouterr().out)
    shelves = {s["shelf"]: s for s in out["shelves"]}
    assert shelves["rack_00/shelf_00"]["partial"] == "start" and shelves["rack_01/shelf_01"]["partial"] == "end"
    s = shelves["rack_01/shelf_01"]
    assert s["unknown_length"] > 0 and s["unknown"][0][1] == pytest.approx(short_map.racks[1].x_range[1], abs=1e-4)
    assert main(["free-space", str(path), "--csv"]) == 0
    rows = list(csv.DictReader(io.StringIO(capsys.readouterr().out)))
    assert {r["shelf"]: r["partial"] for r in rows}["rack_01/shelf_02"] == "end"
    assert sum(float(r["unknown_length"]) for r in rows) == pytest.approx(
        sum(x["unknown_length"] for x in shelves.values())
    )
    assert main(["free-space", str(path)]) == 0
    assert PARTIAL_LEGEND in capsys.readouterr().out


def test_map_json_keeps_partial_and_old_maps_load(tmp_path, short_map):
    d = short_map.to_dict()
    assert d["version"] == 2 and d["racks"][0]["partial"] == "start"
    assert d["racks"][1]["shelves"][0]["partial"] == "end" and len(d["seen_x"]) == 1
    back = WarehouseMap.from_dict(json.loads(json.dumps(d)))
    assert back.to_dict() == d
    # A version 1 file (written before partial racks were recorded) reads with every rack whole.
    old = json.loads(json.dumps(d))
    old["version"] = 1
    del old["seen_x"]
    for r in old["racks"]:
        del r["partial"]
        for s in r["shelves"]:
            del s["partial"]
    (tmp_path / "old.json").write_text(json.dumps(old))
    m = WarehouseMap.load(tmp_path / "old.json")
    assert m.seen_x == [] and all(r.partial is None for r in m.racks) and all(s.partial is None for s in m.shelves())
    assert len(m.boxes()) == len(short_map.boxes())
    bad = json.loads(json.dumps(d))
    bad["racks"][0]["partial"] = "left"
    with pytest.raises(InputError, match="partial must be one of"):
        WarehouseMap.from_dict(bad, "m.json")
    bad["version"] = 3
    with pytest.raises(InputError, match="version 3 is not supported"):
        WarehouseMap.from_dict(bad, "m.json")


def test_partial_margin():
    seen = np.array([False] + [True] * 20 + [False])
    assert _partial_run(seen, 1, 21, 0) == "both"  # the run fills the coverage
    assert _partial_run(seen, 3, 19, 2) == "both"  # ends within 2 bins of it
    assert _partial_run(seen, 4, 19, 2) == "end"
    assert _partial_run(seen, 4, 18, 2) is None
    assert _partial_run(np.ones(10, bool), 0, 10, 1) == "both"  # the strip's own ends are unseen beyond
