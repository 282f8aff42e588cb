"""warehouse.rrd from `mvracklay run` loads back with the Rerun SDK's own reader and holds what was logged:
JPEG frames, a default blueprint, map boxes labelled with their unique map ids."""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from mvracklay.cli import main
from stitching import rerun_log
from stitching.rerun_log import read_entities
from stitching.warehouse_map import MapBox, MapRack, MapShelf, WarehouseMap

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
        assert sorted(labels) == sorted(b.id for b in boxes)
        centres = np.array(cols.get("Boxes3D:centers", [None])[-1] or np.zeros((0, 3)), float).reshape(-1, 3)
        want = np.array([b.cuboid.center for b in boxes], float).reshape(-1, 3)
        assert np.allclose(np.sort(centres, 0), np.sort(want, 0), atol=1e-4)


def test_rgb_is_logged_as_jpeg_close_to_the_frames_at_a_fraction_of_their_size(run_out: Path, tiny_dataset: Path):
    cols = _columns(run_out / "warehouse.rrd", "/camera/rgb")
    assert [m for ms in cols["EncodedImage:media_type"] for m in ms] == ["image/jpeg"] * FRAMES
    raw = jpeg = 0
    for i, blobs in enumerate(cols["EncodedImage:blob"]):
        data = bytes(blobs[0])
        assert data[:2] == b"\xff\xd8", "not a JPEG stream"
        frame = np.asarray(Image.open(tiny_dataset / "seq_00000" / "rgb" / f"{i:06d}.png").convert("RGB"), np.int16)
        decoded = np.asarray(Image.open(io.BytesIO(data)).convert("RGB"), np.int16)
        assert decoded.shape == frame.shape
        assert np.abs(decoded - frame).mean() < 8, f"frame {i} differs from its JPEG"
        raw, jpeg = raw + frame.size, jpeg + len(data)
    assert jpeg < raw / 4, f"{jpeg} JPEG bytes for {raw} raw"


def test_encoding_keeps_the_recording_much_smaller_than_raw_frames(tmp_path: Path, tiny_dataset: Path):
    """The same frames logged raw and as `rerun_log.encode_rgb` does: the JPEG recording is a fraction of the size."""
    import rerun as rr

    frames = [
        np.asarray(Image.open(p).convert("RGB")) for p in sorted((tiny_dataset / "seq_00000" / "rgb").glob("*.png"))
    ]
    sizes = {}
    for name, encode in (("jpeg", rerun_log.encode_rgb), ("raw", rr.Image)):
        rec = rerun_log.start("size", save=tmp_path / f"{name}.rrd")
        for i, rgb in enumerate(frames):
            rec.set_time("frame", sequence=i)
            rec.log("camera/rgb", encode(rgb))
        rec.flush()
        rec.disconnect()
        sizes[name] = (tmp_path / f"{name}.rrd").stat().st_size
    assert sizes["jpeg"] * 3 < sizes["raw"], sizes


def test_rrd_holds_a_blueprint_of_the_3d_map_beside_the_rgb_and_layouts(run_out: Path):
    from rerun.chunk import RrdReader

    reader = RrdReader(str(run_out / "warehouse.rrd"))
    (bp,) = reader.blueprints()
    assert bp.application_id == reader.recordings()[0].application_id
    views = {}
    for chunk in reader.stream(store=bp).collect().stream():
        rb = chunk.to_record_batch()
        if "ViewBlueprint:space_origin" in rb.schema.names:
            for kind, origin in zip(
                rb.column("ViewBlueprint:class_identifier").to_pylist(),
                rb.column("ViewBlueprint:space_origin").to_pylist(),
            ):
                views[origin[0]] = kind[0]
    want = {"/world": "3D", "/camera/rgb": "2D"}
    want |= {f"/layouts/{v}/slot_{r}": "2D" for v in ("top", "front") for r in range(3)}
    assert views == want


def _box(rack: int, j: int, x: float) -> MapBox:
    return MapBox(f"rack_{rack:02d}/shelf_00/box_{j:03d}", (x, -0.2, 0.0), (0.4, 0.4, 0.4), 0.0, 1.0, 3)


def test_map_box_labels_are_unique_across_racks(tmp_path: Path):
    """Two racks both holding shelf_00/box_000: the labels are the whole ids, so none repeats."""
    racks = []
    for k in range(2):
        x0 = 3.0 * k
        shelf = MapShelf(f"rack_{k:02d}/shelf_00", 0, 0.0, 0.8, (x0, x0 + 2.5), (-0.5, 0.5), 1.0)
        shelf.boxes = [_box(k, 0, x0 + 0.5), _box(k, 1, x0 + 1.5)]
        racks.append(MapRack(f"rack_{k:02d}", (x0, x0 + 2.5), [shelf]))
    wmap = WarehouseMap(racks, [], 0.05)
    rec = rerun_log.start("labels", save=tmp_path / "m.rrd", num_slots=1)
    rerun_log.log_map(rec, wmap, 0, 1)
    rec.flush()
    rec.disconnect()
    (labels,) = _columns(tmp_path / "m.rrd", "/world/map/slot_0")["Boxes3D:labels"]
    assert len(set(labels)) == len(labels) == 4
    assert sorted(labels) == sorted(b.id for b in wmap.boxes())


def test_partial_shelves_say_so_in_their_labels(tmp_path: Path):
    cut = MapShelf("rack_00/shelf_00", 0, 0.0, 0.8, (0.0, 1.0), (-0.5, 0.5), 1.0, partial="start")
    whole = MapShelf("rack_01/shelf_00", 0, 0.0, 0.8, (2.0, 4.0), (-0.5, 0.5), 1.0)
    wmap = WarehouseMap(
        [MapRack("rack_00", (0.0, 1.0), [cut], "start"), MapRack("rack_01", (2.0, 4.0), [whole])], [], 0.05
    )
    rec = rerun_log.start("partial", save=tmp_path / "p.rrd", num_slots=1)
    rerun_log.log_map(rec, wmap, 0, 1)
    rec.flush()
    rec.disconnect()
    (labels,) = _columns(tmp_path / "p.rrd", "/world/map/shelves")["Boxes3D:labels"]
    assert sorted(labels) == ["rack_00/shelf_00 (partial: start)", "rack_01/shelf_00"]
