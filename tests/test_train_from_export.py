"""Training and evaluation read a RackLay/MVRackLay export exactly as they read the dataset it came from."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch
from tiny_net import TINY_NET

from layouts.errors import InputError
from layouts.spec import LayoutSpec
from mvracklay.cli import main
from network.data import WindowDataset
from network.training.train_data import open_data
from waresynth.dataset import open_dataset
from waresynth.exporters import export_dataset
from waresynth.exporters.racklay import RACKLAY_CAMERAS, RACKLAY_MANIFEST


@pytest.fixture(scope="module")
def racklay_export(tiny_dataset: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    return export_dataset(tiny_dataset, tmp_path_factory.mktemp("rl") / "racklay", "racklay", progress=False)


def test_export_sequences_read_like_the_dataset(tiny_dataset: Path, racklay_export: Path) -> None:
    ds, ex = open_dataset(tiny_dataset), open_data(racklay_export)
    assert ex.spec == ds.spec and tuple(ex.image_size) == tuple(ds.image_size)
    for split in ("train", "val", "test", None):
        a, b = ds.sequences(split), ex.sequences(split)
        assert [s.name for s in a] == [s.name for s in b]
    for a, b in zip(ds.sequences(), ex.sequences()):
        assert b.num_frames == a.num_frames and b.intrinsics == a.intrinsics
        assert b.visible_board_ys() == a.visible_board_ys() and len(a.visible_board_ys()) >= 1
        assert np.array_equal(b.camera_positions(), a.camera_positions())
        for i in (0, a.num_frames - 1):
            assert b.frame(i) == a.frame(i)
            assert np.array_equal(b.rgb(i), a.rgb(i))
            la, lb = a.layouts(i), b.layouts(i)
            assert np.array_equal(la.top, lb.top) and np.array_equal(la.front, lb.front)
    # The training windows (canonical images, layouts, anchors, row targets, augmentation) are equal.
    spec = LayoutSpec(size=16)
    kw = dict(seq_len=3, input_size=(64, 64), spec=spec, augment=True, seed=5)
    wa, wb = WindowDataset(ds.sequences("train"), **kw), WindowDataset(ex.sequences("train"), **kw)
    assert len(wa) == len(wb)
    for idx in (0, len(wa) - 1):
        ia, ib = wa[idx], wb[idx]
        assert np.isfinite(ia["anchors"].numpy()).any()
        for k, v in ia.items():
            if isinstance(v, torch.Tensor):  # anchors are NaN where a slot has no shelf
                assert np.array_equal(v.numpy(), ib[k].numpy(), equal_nan=v.is_floating_point()), k
            else:
                assert v == ib[k], k


def test_train_and_evaluate_on_an_export(tiny_dataset: Path, racklay_export: Path, tmp_path: Path) -> None:
    run = tmp_path / "run"
    args = ["--epochs", "1", "--steps-per-epoch", "2", "--frames-per-step", "2", *TINY_NET]
    assert main(["train", "--data", str(racklay_export), "--out", str(run), *args]) == 0
    record = json.loads((run / "last.json").read_text())
    assert record["step"] == 2
    scores = {}
    for name, data in (("export", racklay_export), ("dataset", tiny_dataset)):
        out = tmp_path / f"{name}.json"
        cmd = ["evaluate", "--checkpoint", str(run / "last.pt"), "--data", str(data), "--split", "all"]
        assert main([*cmd, "--threads", "1", "--quiet", "--json-out", str(out)]) == 0
        scores[name] = json.loads(out.read_text())
    assert scores["export"]["frames"] == sum(s.num_frames for s in open_dataset(tiny_dataset).sequences())
    assert scores["export"]["visible"] == scores["dataset"]["visible"]


def test_export_without_camera_records_cannot_train(racklay_export: Path, tmp_path: Path, capsys) -> None:
    """A version-1 export (layouts only) still reads its layouts, but training says what is missing."""
    import shutil

    old = shutil.copytree(racklay_export, tmp_path / "v1")
    (old / RACKLAY_CAMERAS).unlink()
    (old / "img").rename(old / "images")  # version 1's folders
    (old / "frontLayouts").mkdir()
    for f in (old / "topLayouts").glob("front*.npy"):
        f.rename(old / "frontLayouts" / f.name)
    m = json.loads((old / RACKLAY_MANIFEST).read_text())
    m["version"] = 1
    del m["cameras"]
    (old / RACKLAY_MANIFEST).write_text(json.dumps(m))
    ex = open_data(old)
    assert ex.layouts(0).top.shape == ex.spec.shape
    with pytest.raises(InputError, match="no camera records"):
        ex.sequences("train")
    assert main(["train", "--data", str(old), "--out", str(tmp_path / "run"), *TINY_NET]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no camera records" in err[0] and "re-export" in err[0]


def test_export_with_a_broken_camera_record_is_one_line(racklay_export: Path, tmp_path: Path) -> None:
    import shutil

    bad = shutil.copytree(racklay_export, tmp_path / "bad")
    cams = json.loads((bad / RACKLAY_CAMERAS).read_text())
    name = sorted(cams["sequences"])[0]
    cams["sequences"][name]["frames"][1]["camera_position"] = [0.0, "x"]
    (bad / RACKLAY_CAMERAS).write_text(json.dumps(cams))
    with pytest.raises(InputError, match=rf"{RACKLAY_CAMERAS}: sequence {name} frame 1: camera_position"):
        open_data(bad).sequences()


def test_racklay_folder_without_our_manifest_reads_as_the_authors_layout(racklay_export: Path, tmp_path: Path) -> None:
    """Without racklay_export.json the folder is the authors' layout: its lists, a default camera."""
    import shutil

    foreign = shutil.copytree(racklay_export, tmp_path / "foreign")
    (foreign / RACKLAY_MANIFEST).unlink()
    data = open_data(foreign)
    assert data.spec.num_slots == 4 and "no camera records" in data.note
    val = [s.frames for s in open_data(racklay_export).records if s.split == "val"]
    assert [s.num_frames for s in data.sequences("val")] == val
