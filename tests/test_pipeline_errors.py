"""`mvracklay run` on bad input: one line on stderr, exit 2, nothing written to OUT."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image
from tiny_net import tiny_config

from layouts.errors import InputError
from layouts.spec import LayoutSpec
from mvracklay import pipeline
from mvracklay.cli import main
from network.checkpoint import save_checkpoint
from network.model.net import MVRackLay


@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """An untrained tiny checkpoint (errors are caught before the network matters)."""
    torch.manual_seed(0)
    cfg = tiny_config(LayoutSpec(size=16))
    path = tmp_path_factory.mktemp("ckpt") / "tiny.pt"
    intr = {"fx": 110.85, "fy": 110.85, "cx": 64.0, "cy": 64.0, "width": 128, "height": 128}
    save_checkpoint(path, {"model": MVRackLay(cfg).state_dict()}, {"model_config": cfg.to_dict(), "intrinsics": intr})
    return path


def _frames(folder: Path, sizes: list[tuple[int, int]]) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(0)
    for i, (w, h) in enumerate(sizes):
        Image.fromarray(rng.integers(0, 255, (h, w, 3), dtype=np.uint8)).save(folder / f"f{i:03d}.png")
    return folder


def _fails(argv: list[str], capsys, *needles: str) -> str:
    rc = main(argv)
    err = capsys.readouterr().err.strip()
    assert rc == 2, err
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("mvracklay run: error: "), err
    for n in needles:
        assert n in lines[0], lines[0]
    return lines[0]


def _nothing_in(out: Path) -> None:
    assert not out.exists()
    assert not [p for p in out.parent.iterdir() if ".partial-" in p.name]


def test_empty_folder(tmp_path: Path, checkpoint: Path, capsys):
    (tmp_path / "empty").mkdir()
    out = tmp_path / "out"
    _fails(["run", str(tmp_path / "empty"), "--out", str(out), "--checkpoint", str(checkpoint)], capsys, "no images")
    _nothing_in(out)


def test_mixed_sizes_name_the_odd_file(tmp_path: Path, checkpoint: Path, capsys):
    src = _frames(tmp_path / "mixed", [(64, 64), (64, 64), (80, 64)])
    out = tmp_path / "out"
    _fails(["run", str(src), "--out", str(out), "--checkpoint", str(checkpoint)], capsys, "f002.png", "80x64")
    _nothing_in(out)


def test_unreadable_video(tmp_path: Path, checkpoint: Path, capsys):
    bad = tmp_path / "clip.mp4"
    bad.write_bytes(b"\x00not a video" * 100)
    out = tmp_path / "out"
    _fails(["run", str(bad), "--out", str(out), "--checkpoint", str(checkpoint)], capsys, "clip.mp4", "video")
    _nothing_in(out)


def test_missing_input(tmp_path: Path, checkpoint: Path, capsys):
    out = tmp_path / "out"
    _fails(["run", str(tmp_path / "nope"), "--out", str(out), "--checkpoint", str(checkpoint)], capsys, "not found")
    _nothing_in(out)


def test_missing_checkpoint(tmp_path: Path, capsys):
    src = _frames(tmp_path / "ok", [(64, 64)] * 2)
    out = tmp_path / "out"
    _fails(["run", str(src), "--out", str(out), "--checkpoint", str(tmp_path / "x.pt")], capsys, "x.pt", "not found")
    _nothing_in(out)


def test_no_shipped_weights(tmp_path: Path, capsys, monkeypatch):
    monkeypatch.setattr(pipeline, "DEFAULT_CHECKPOINT", tmp_path / "absent-model.pt")
    src = _frames(tmp_path / "ok", [(64, 64)] * 2)
    out = tmp_path / "out"
    _fails(["run", str(src), "--out", str(out)], capsys, "no trained model", "mvracklay train", "--checkpoint")
    _nothing_in(out)


def test_corrupt_checkpoint(tmp_path: Path, capsys):
    src = _frames(tmp_path / "ok", [(64, 64)] * 2)
    bad = tmp_path / "bad.pt"
    bad.write_bytes(b"garbage")
    out = tmp_path / "out"
    _fails(["run", str(src), "--out", str(out), "--checkpoint", str(bad)], capsys, "bad.pt")
    _nothing_in(out)


@pytest.mark.parametrize(
    "text, needle",
    [
        ("{not json", "cam.json"),
        (json.dumps({"fx": 100.0, "fy": 100.0, "cx": 32.0}), "cy"),
        (json.dumps({"fx": -1.0, "fy": 100.0, "cx": 32.0, "cy": 24.0}), "fx: Input should be greater than 0"),
        (json.dumps([1, 2, 3]), "cam.json"),
    ],
)
def test_bad_camera_json(tmp_path: Path, checkpoint: Path, capsys, text: str, needle: str):
    src = _frames(tmp_path / "ok", [(64, 64)] * 2)
    cam = tmp_path / "cam.json"
    cam.write_text(text)
    out = tmp_path / "out"
    _fails(["run", str(src), "--out", str(out), "--checkpoint", str(checkpoint), "--camera", str(cam)], capsys, needle)
    _nothing_in(out)


def test_corrupt_frame_mid_run_leaves_out_untouched(tmp_path: Path, checkpoint: Path, capsys):
    src = _frames(tmp_path / "frames", [(64, 64)] * 4)
    data = (src / "f002.png").read_bytes()
    (src / "f002.png").write_bytes(data[: len(data) // 2])  # header intact, pixels cut off
    out = tmp_path / "out"
    out.mkdir()
    from stitching.warehouse_map import WarehouseMap

    WarehouseMap(racks=[], steps=[], board_thickness=0.06, meta={"earlier": "run"}).save(out / "warehouse.json")
    earlier = (out / "warehouse.json").read_bytes()  # an earlier run's map
    _fails(["run", str(src), "--out", str(out), "--checkpoint", str(checkpoint), "--quiet"], capsys, "f002.png")
    assert sorted(p.name for p in out.iterdir()) == ["warehouse.json"]
    assert (out / "warehouse.json").read_bytes() == earlier
    assert not [p for p in tmp_path.iterdir() if ".partial-" in p.name]


@pytest.mark.parametrize(
    "extra, needle",
    [
        (["--max-frames", "-1"], "--max-frames"),
        (["--map-every", "0"], "--map-every"),
        (["--distance", "-2"], "--distance"),
    ],
)
def test_bad_options(tmp_path: Path, checkpoint: Path, capsys, extra: list[str], needle: str):
    src = _frames(tmp_path / "ok", [(64, 64)] * 2)
    out = tmp_path / "out"
    _fails(["run", str(src), "--out", str(out), "--checkpoint", str(checkpoint), *extra], capsys, needle)
    _nothing_in(out)


def test_run_config_refuses_an_unknown_precision():
    with pytest.raises(InputError, match="--precision must be one of fp32, bf16, got 'fp16'"):
        pipeline.RunConfig(precision="fp16").validate()
