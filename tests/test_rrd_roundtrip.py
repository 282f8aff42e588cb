"""warehouse.rrd from `mvracklay run` loads back with the Rerun SDK's own reader and holds what was logged."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from mvracklay.cli import main
from stitching.rerun_log import read_entities
from stitching.warehouse_map import WarehouseMap

FRAMES = 5


@pytest.fixture(scope="module")
def run_out(tiny_dataset: Path, tiny_checkpoint: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """`mvracklay run` with the tiny trained checkpoint (its noisy layouts give shelves and boxes)."""
    out = tmp_path_factory.mktemp("rrd") / "out"
    argv = ["run", str(tiny_dataset / "seq_00000"), "--out", str(out), "--checkpoint", str(tiny_checkpoint)]
    assert main([*argv, "--max-frames", str(FRAMES), "--no-opening", "--quiet"]) == 0
    return out


def _columns(path: Path, entity: str) -> dict[str, list]:
    """All rows logged to ``entity`` (non-static), column name -> values, in frame order."""
    from rerun.chunk import RrdReader

    rows: dict[str, list] = {}
    for chunk in RrdReader(str(path)).stream().collect().stream():
        if chunk.entity_path != entity or chunk.is_static:
            continue
        rb = chunk.to_record_batch()
        for name in rb.schema.names:
            if name == "log_time" or name.startswith("rerun."):
                continue
            rows.setdefault(name, []).extend(rb.column(name).to_pylist())
    order = np.argsort(rows["frame"], kind="stable")
    return {k: [v[i] for i in order] for k, v in rows.items()}


def test_rrd_holds_the_logged_entities(run_out: Path):
    ents = read_entities(run_out / "warehouse.rrd")
    want = {"/", "/layouts", "/camera/rgb", "/world/frame/boxes", "/world/map/shelves", "/world/camera/path"}
    want |= {f"/world/map/slot_{r}" for r in range(3)}
    want |= {f"/layouts/{v}/slot_{r}" for v in ("top", "front") for r in range(3)}
    assert want <= ents


def test_every_frame_is_on_the_frame_timeline(run_out: Path):
    for entity in ("/camera/rgb", "/world/frame/boxes", "/layouts/top/slot_0", "/world/map/slot_0"):
        assert sorted(_columns(run_out / "warehouse.rrd", entity)["frame"]) == list(range(FRAMES)), entity


def test_last_map_batch_matches_the_saved_map(run_out: Path):
    wmap = WarehouseMap.load(run_out / "warehouse.json")
    assert wmap.boxes(), "the tiny model's layouts should give some boxes"
    for r in range(3):
        cols = _columns(run_out / "warehouse.rrd", f"/world/map/slot_{r}")
        assert cols["frame"][-1] == FRAMES - 1
        boxes = sorted((b for s in wmap.shelves() if s.slot == r for b in s.boxes), key=lambda b: b.id)
        # a slot that never held a box has no label/centre columns at all
        labels = cols.get("Boxes3D:labels", [None])[-1] or []
        assert sorted(labels) == sorted(b.id.split("/", 1)[1] for b in boxes)
        centres = np.array(cols.get("Boxes3D:centers", [None])[-1] or np.zeros((0, 3)), float).reshape(-1, 3)
        want = np.array([b.cuboid.center for b in boxes], float).reshape(-1, 3)
        assert np.allclose(np.sort(centres, 0), np.sort(want, 0), atol=1e-4)
