"""The camera distance of footage: read from its frames (or the camera height), given, or recorded; printed,
kept in warehouse.json, and the Python API on frames in memory."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

from layouts import Intrinsics
from layouts.errors import InputError
from mvracklay.cli import main
from network.inference.distance import (
    DistanceReading,
    check_camera_height,
    load_reader,
    read_distance,
    read_distances,
    save_reader,
)
from network.model.distance import DistanceReader, DistanceReaderConfig


class ConstantReader(DistanceReader):
    """Says the same thing of every image: log ratio ``t``, floor line ``floor_y`` canonical metres, in view."""

    def __init__(self, t: float, floor_y: float, floor_logit: float = 5.0) -> None:
        super().__init__(DistanceReaderConfig(size=64))
        self.out = torch.tensor([t, floor_y, floor_logit])

    def read(self, x: torch.Tensor) -> torch.Tensor:
        return self.out.expand(x.shape[0], 3)


def _frames(tiny_dataset: Path, n: int = 3) -> list[np.ndarray]:
    paths = sorted((tiny_dataset / "seq_00000" / "rgb").glob("*.png"))[:n]
    return [np.asarray(Image.open(p).convert("RGB")) for p in paths]


@pytest.fixture(scope="module")
def reader_file(tmp_path_factory) -> Path:
    torch.manual_seed(0)
    path = tmp_path_factory.mktemp("reader") / "reader.pt"
    save_reader(path, DistanceReader(DistanceReaderConfig(size=64)).eval(), {"note": "untrained"})
    return path


def test_each_round_corrects_the_assumed_distance_by_the_ratio_read(tiny_dataset: Path):
    frames = _frames(tiny_dataset)
    d, floor_ratio, p = read_distances(ConstantReader(0.1, 1.3), frames, None, start=2.0, rounds=2)
    assert np.allclose(d, 2.0 * math.exp(0.2))
    # the floor line read at the last assumed distance (2.0 e^0.1) is camera height / distance, free of scale
    assert np.allclose(floor_ratio, 1.3 / (2.0 * math.exp(0.1)))
    assert np.all(p > 0.99)


def test_the_camera_height_gives_the_distance_where_the_floor_line_is_seen(tiny_dataset: Path):
    frames = _frames(tiny_dataset)
    r = read_distance(ConstantReader(0.0, 0.5), frames, None, camera_height=1.0, start=2.5)
    assert r.source == "camera height" and r.distance == pytest.approx(1.0 * 2.5 / 0.5)
    # not in view: read from the sizes instead, and said why
    r = read_distance(ConstantReader(0.0, 0.5, floor_logit=-5.0), frames, None, camera_height=1.0, start=2.5)
    assert r.source == "read" and r.distance == pytest.approx(2.5) and "--camera-height 1 was not used" in r.note


def test_a_reading_describes_and_records_its_source():
    r = DistanceReading(2.543, "read", 12, (2.5, 2.6))
    assert r.describe() == "2.54 m, read from 12 frames, 2.50-2.60 m across them"
    assert r.to_record() == {
        "distance": 2.543,
        "distance_source": "read",
        "distance_frames": 12,
        "distance_spread": [2.5, 2.6],
    }
    assert DistanceReading(2.5, "given").describe() == "2.50 m, given (--distance)"


def test_reader_files_load_safely(reader_file: Path, tmp_path: Path):
    reader, record = load_reader(reader_file)
    assert record["note"] == "untrained" and reader.cfg.size == 64 and not reader.training
    (tmp_path / "bad.pt").write_bytes(b"not a checkpoint")
    with pytest.raises(InputError, match="bad.pt: not a distance reader"):
        load_reader(tmp_path / "bad.pt")
    with pytest.raises(InputError, match="missing.pt: distance reader not found"):
        load_reader(tmp_path / "missing.pt")


@pytest.mark.parametrize("value", [0, -1.0, float("nan"), "high", 40])
def test_a_camera_height_that_cannot_be_is_refused(value):
    with pytest.raises(InputError, match="--camera-height"):
        check_camera_height(value)


def _folder(tiny_dataset: Path, tmp_path: Path) -> Path:
    folder = tmp_path / "phone"
    folder.mkdir()
    for i, rgb in enumerate(_frames(tiny_dataset, 4)):
        Image.fromarray(rgb).save(folder / f"IMG_{i + 1:04d}.jpg", quality=92)
    return folder


def _meta(out: Path) -> dict:
    return json.loads((out / "warehouse.json").read_text())["meta"]


def test_run_on_footage_reads_prints_and_records_its_distance(
    tiny_dataset: Path, tiny_checkpoint: Path, reader_file: Path, tmp_path: Path, capsys
):
    folder = _folder(tiny_dataset, tmp_path)
    base = ["run", str(folder), "--checkpoint", str(tiny_checkpoint), "--threads", "1", "--quiet"]
    assert main([*base, "--out", str(tmp_path / "read"), "--distance-reader", str(reader_file)]) == 0
    meta = _meta(tmp_path / "read")
    assert meta["distance_source"] == "read" and meta["distance_frames"] == 4
    assert 0.8 <= meta["distance"] <= 8.0
    assert f"distance to the racks: {meta['distance']:.2f} m, read from 4 frames" in capsys.readouterr().out
    assert main([*base, "--out", str(tmp_path / "given"), "--distance", "2.4"]) == 0
    assert (_meta(tmp_path / "given")["distance"], _meta(tmp_path / "given")["distance_source"]) == (2.4, "given")
    # no reader file: the default, with a warning that says what to do
    assert main([*base, "--out", str(tmp_path / "none"), "--distance-reader", str(tmp_path / "absent.pt")]) == 0
    meta = _meta(tmp_path / "none")
    assert meta["distance_source"] == "default"
    assert f"the default {meta['distance']:.2f} m is used; pass --distance" in capsys.readouterr().err


def test_a_generated_sequence_keeps_its_recorded_distances(tiny_dataset: Path, tiny_checkpoint: Path, tmp_path):
    seq = tiny_dataset / "seq_00000"
    args = ["run", str(seq), "--checkpoint", str(tiny_checkpoint), "--threads", "1", "--quiet", "--out"]
    assert main([*args, str(tmp_path / "o")]) == 0
    recorded = [f["distance"] for f in json.loads((seq / "meta.json").read_text())["frames"]]
    meta = _meta(tmp_path / "o")
    assert meta["distance_source"] == "recorded" and meta["distance"] == pytest.approx(np.median(recorded), abs=1e-4)


def test_the_python_api_reconstructs_frames_in_memory(tiny_dataset: Path, tiny_checkpoint: Path, tmp_path: Path):
    import mvracklay

    frames = _frames(tiny_dataset, 4)
    cam = Intrinsics.from_fov(128, 128, 60.0)
    wmap = mvracklay.reconstruct(
        iter(frames), camera=cam, distance=2.5, checkpoint=tiny_checkpoint, threads=1, out=tmp_path / "api"
    )
    assert isinstance(wmap, mvracklay.WarehouseMap)
    assert wmap.meta["frames"] == 4 and wmap.meta["distance_source"] == "given"
    assert wmap.meta["input_kind"] == "arrays" and wmap.meta["intrinsics"]["fx"] == pytest.approx(cam.fx)
    assert (tmp_path / "api" / "warehouse.glb").is_file()
    rows = mvracklay.free_space(wmap)
    assert len(rows) == len(wmap.shelves())
    # no out: nothing kept, the map returned
    again = mvracklay.reconstruct(frames, distance=2.5, checkpoint=tiny_checkpoint, threads=1, quality="fast")
    assert again.meta["frames"] == 4


@pytest.mark.parametrize(
    ("frames", "options", "needle"),
    [
        ([], {}, "frames: no frames given"),
        ([np.zeros((8, 8, 3), np.float32)], {}, r"frames\[0\]: want a uint8 array"),
        ([np.zeros((8, 8, 3), np.uint8), np.zeros((8, 9, 3), np.uint8)], {}, r"frames\[1\]: 9x8, the first frame 8x8"),
        ([np.zeros((8, 8, 3), np.uint8)], {"quality": "best"}, "quality must be one of"),
        ([np.zeros((8, 8, 3), np.uint8)], {"speed": 2}, "unknown option"),
        ([np.zeros((8, 8, 3), np.uint8)], {"distance": -2.0}, "--distance must be a positive"),
        (5, {}, "frames: want an iterable"),
    ],
)
def test_the_python_api_refuses_bad_input_in_one_line(tiny_checkpoint: Path, frames, options, needle):
    import mvracklay

    with pytest.raises(InputError, match=needle):
        mvracklay.reconstruct(frames, checkpoint=tiny_checkpoint, **options)


def test_camera_advice_fits_what_differs():
    from mvracklay.camera import camera_advice, camera_warning

    trained = Intrinsics.from_fov(256, 256, 60.0)
    phone = Intrinsics.from_fov(640, 480, 60.0)  # same horizontal field of view, less of it vertically
    said = camera_advice(phone, trained, guessed=True)
    assert "--camera FILE" in said and "hfov_deg" not in said and "vertically" in said
    said = camera_warning(phone, {"intrinsics": trained.to_dict()}, "model.pt", guessed=False)
    assert "vertical FOV" in said and "--camera" not in said
    wide = camera_advice(Intrinsics.from_fov(640, 480, 75.0), trained)
    assert "camera.hfov_deg 75.0" in wide and "middle" in wide


def test_warehouse_json_records_the_camera_and_lens_used(tiny_dataset: Path, tiny_checkpoint: Path, tmp_path: Path):
    folder = _folder(tiny_dataset, tmp_path)
    cam = tmp_path / "camera.json"
    cam.write_text(json.dumps({**Intrinsics.from_fov(128, 128, 60.0).to_dict(), "k1": -0.05}))
    out = tmp_path / "o"
    args = ["run", str(folder), "--checkpoint", str(tiny_checkpoint), "--camera", str(cam), "--distance", "2.5"]
    assert main([*args, "--threads", "1", "--quiet", "--out", str(out)]) == 0
    meta = _meta(out)
    assert meta["lens"]["k1"] == pytest.approx(-0.05) and meta["intrinsics_source"].startswith(f"--camera {cam}")
    assert main([*args[:4], "--distance", "2.5", "--threads", "1", "--quiet", "--out", str(tmp_path / "p")]) == 0
    assert _meta(tmp_path / "p")["lens"] is None


def test_a_map_scales_every_length_about_its_origin():
    from stitching.warehouse_map import MapBox, MapRack, MapShelf, StepRecord, WarehouseMap

    box = MapBox("rack_00/shelf_00/box_000", (0.5, -0.2, 0.1), (0.4, 0.4, 0.3), 0.2, 0.9, 3)
    shelf = MapShelf("rack_00/shelf_00", 0, 0.0, 0.8, (0.0, 2.0), (-0.5, 0.5), 1.0, [box])
    step = StepRecord(1, 0.3, 0.3, 1, 1.0, "edges", 2)
    wmap = WarehouseMap([MapRack("rack_00", (0.0, 2.0), [shelf])], [step], 0.05, seen_x=[(-1.0, 3.0)])
    big = wmap.scaled(2.0)
    b = big.boxes()[0]
    assert b.center == (1.0, -0.4, 0.2) and b.size == (0.8, 0.8, 0.6) and b.yaw == 0.2
    assert big.shelves()[0].clear_height == 1.6 and big.racks[0].x_range == (0.0, 4.0)
    assert big.steps[0].offset == 0.6 and big.seen_x == [(-2.0, 6.0)] and big.board_thickness == 0.1
    assert wmap.boxes()[0].center == (0.5, -0.2, 0.1)  # the original untouched
    with pytest.raises(InputError, match="scale factor"):
        wmap.scaled(0.0)


def test_eval_reconstruction_scores_a_map_with_its_scale_corrected(
    tiny_dataset: Path, tiny_checkpoint: Path, tmp_path: Path, capsys
):
    seq = tiny_dataset / "seq_00000"
    recorded = float(np.median([f["distance"] for f in json.loads((seq / "meta.json").read_text())["frames"]]))
    out = tmp_path / "far"
    run = ["run", str(seq), "--checkpoint", str(tiny_checkpoint), "--threads", "1", "--quiet", "--no-rrd"]
    assert main([*run, "--distance", f"{recorded * 1.1:.4f}", "--out", str(out)]) == 0
    capsys.readouterr()
    args = ["eval-reconstruction", str(seq), "--map", str(out / "warehouse.json"), "--json", "--quiet"]
    assert main([*args, "--scale-corrected"]) == 0
    got = json.loads(capsys.readouterr().out)
    (name,) = got["scale_corrected"]
    assert name == f"seq_00000 x{1 / 1.1:.3f}"
    assert main(["eval-reconstruction", str(seq), "--scale-corrected", "--quiet"]) == 2
    assert "--scale-corrected rescales a given map: it needs --map" in capsys.readouterr().err


def test_predict_reads_footages_distance_as_run_does(tiny_dataset: Path, tiny_checkpoint: Path, tmp_path, capsys):
    folder = _folder(tiny_dataset, tmp_path)
    args = ["predict", str(folder), "--checkpoint", str(tiny_checkpoint), "--out", str(tmp_path / "lay")]
    assert main(args) == 0
    out = capsys.readouterr().out
    assert "distance to the racks: " in out and "read from 4 frames" in out
    assert main([*args[:-1], str(tmp_path / "given"), "--distance", "2.4"]) == 0
    assert "distance to the racks: 2.40 m, given (--distance)" in capsys.readouterr().out
