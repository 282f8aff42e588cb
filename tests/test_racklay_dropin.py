"""The RackLay export is a drop-in for the authors' code, and a folder in their layout reads back.

The walk below imports nothing of theirs: it repeats the exact path strings of MVRackLay's
``eval_vracklay.py`` / ``racklay/dataloader.py`` (branch VideoLayout) and RackLay's HEAD loader.
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from tiny_net import TINY_NET

from layouts.errors import InputError
from mvracklay.cli import main
from network.preprocess import DEFAULT_DISTANCE
from network.training.train_data import open_data
from waresynth.dataset import open_dataset
from waresynth.exporters import export_dataset
from waresynth.exporters.racklay_lists import list_plan
from waresynth.racklay_published import DEFAULT_DISTANCE_M

NUM_RACKS = 4  # eval_vracklay.py's --num_racks default


def _temporal_readlines(filename: str, seq_len: int) -> list[list[str]]:
    """MVRackLay's ``temporal_readlines``, line for line."""
    f = open(filename)
    files = [k.split("\n")[:-1] for k in f.read().split(",")[:-1]]
    f.close()
    temporal_files = []
    for seq_files in files:
        seq_files = [seq_files[0]] * seq_len + seq_files
        for i in range(seq_len, len(seq_files)):
            temporal_files.append(seq_files[i - seq_len : i])
    return temporal_files


def _their_layout(path_in_list: str, view: str) -> np.ndarray:
    """``get_top_path`` / ``get_front_path`` then ``process_topview``'s code mapping, per slot."""
    img_path = os.path.join(path_in_list)
    tv = np.load(img_path.replace("img/", f"topLayouts/{view}").replace("png", "npy"), allow_pickle=False)
    out = np.zeros((NUM_RACKS, *tv.shape[1:]))
    for i in range(NUM_RACKS):  # IndexError here with fewer slots
        out[i][tv[i] == 115] = 1
        out[i][tv[i] == 255] = 2
    return out


@pytest.fixture(scope="module")
def dropin(tiny_dataset: Path, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """The export, and a stand-in for their code folder with the export's lists copied where they read them."""
    base = tmp_path_factory.mktemp("dropin")
    out = export_dataset(tiny_dataset, base / "racklay", "racklay", progress=False)
    code = base / "MVRackLay"
    shutil.copytree(out / "splits" / "warehouse", code / "splits" / "warehouse")
    return out, code


def test_their_evaluation_finds_every_file(tiny_dataset: Path, dropin: tuple[Path, Path]) -> None:
    out, code = dropin
    ds = open_dataset(tiny_dataset)
    fpath = os.path.join(str(code), "splits", "warehouse", "{}_files.txt")
    windows = _temporal_readlines(fpath.format("val_temporal"), 8)
    val = ds.sequences("val")
    assert len(windows) == sum(s.num_frames for s in val)
    seq = val[0]
    first = json.loads((out / "racklay_export.json").read_text())["sequences"]
    start = next(r["first"] for r in first if r["name"] == seq.name)
    # the targets of their windows: f0, f0, f1, ..., f[N-2]
    targets = [int(Path(w[-1]).stem) - start for w in windows[: seq.num_frames]]
    assert targets == [0, *range(seq.num_frames - 1)]
    for w in windows[:3]:
        assert all(Path(p).is_absolute() and Path(p).parent == out.resolve() / "img" for p in w)
        with Image.open(w[0]) as im:  # pil_loader
            assert im.convert("RGB").size == tuple(ds.image_size)
    for w, t in zip(windows, targets):
        for view in ("top", "front"):
            lay = _their_layout(w[-1], view)
            want = getattr(seq.layouts(t), view)
            assert np.array_equal(lay[: want.shape[0]], want) and not lay[want.shape[0] :].any()
    # RackLay's HEAD: readlines(val_files.txt), one image path a line, the same replace rule
    for split in ("train", "val"):
        lines = Path(fpath.format(split)).read_text().splitlines()
        assert len(lines) == sum(s.num_frames for s in ds.sequences(split))
        for line in lines[:2]:
            assert Path(line).is_file() and _their_layout(line, "front").shape[0] == NUM_RACKS
    assert len(_temporal_readlines(fpath.format("train_temporal"), 8)) == sum(
        s.num_frames for s in ds.sequences("train")
    )


def test_val_list_is_always_written(tiny_dataset: Path, tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    recs = [{"name": n, "split": s, "first": 0, "frames": 1} for n, s in (("a", "train"), ("b", "train"))]
    plan = list_plan(recs)
    assert plan["train"]["sequences"] == ["a"] and plan["val"] == {"from": "train sequence b", "sequences": ["b"]}
    plan = list_plan([*recs, {"name": "c", "split": "test", "first": 0, "frames": 1}])
    assert plan["val"] == {"from": "test", "sequences": ["c"]} and plan["train"]["sequences"] == ["a", "b"]
    assert list_plan(recs[:1])["val"]["sequences"] == ["a"] == list_plan(recs[:1])["train"]["sequences"]
    # a dataset with train sequences only: the last one is held back as val
    data = shutil.copytree(tiny_dataset, tmp_path / "trainonly")
    m = json.loads((data / "manifest.json").read_text())
    for s in m["sequences"]:
        s["split"] = "train"
    (data / "manifest.json").write_text(json.dumps(m))
    out = tmp_path / "ex"
    assert main(["export", str(data), "--format", "racklay", "--out", str(out), "--quiet"]) == 0
    assert f"val from train sequence {m['sequences'][-1]['name']}" in capsys.readouterr().out
    val = (out / "splits" / "warehouse" / "val_temporal_files.txt").read_text()
    train = (out / "splits" / "warehouse" / "train_temporal_files.txt").read_text()
    assert val.count(",") == 1 and train.count(",") == len(m["sequences"]) - 1
    flat = {
        k: set((out / "splits" / "warehouse" / f"{k}_files.txt").read_text().splitlines()) for k in ("train", "val")
    }
    assert len(flat["val"]) == 8 and not flat["val"] & flat["train"]


def test_slots_and_output_paths(tiny_dataset: Path, tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    out = export_dataset(tiny_dataset, tmp_path / "five", "racklay", progress=False, slots=5)
    assert np.load(out / "topLayouts" / "front000000.npy").shape[0] == 5
    assert open_data(out).layouts(0).top.shape[0] == 3  # read back as the dataset's 3 slots
    for argv, what in (
        (["--slots", "2"], "at least"),
        (["--out", str(tmp_path / "png_exports")], "replace"),
        (["--out", str(tmp_path / "img")], "replace"),
        (["--format", "coco", "--slots", "4"], "--slots"),
    ):
        args = ["export", str(tiny_dataset), "--format", "racklay", "--out", str(tmp_path / "x"), "--quiet"]
        assert main([*args, *argv]) == 2
        err = capsys.readouterr().err.strip()
        assert err.startswith("mvracklay export: error: ") and "\n" not in err and what in err
    assert not (tmp_path / "png_exports").exists()


# ---------------------------------------------------------------- their layout, read back
def _write_published(root: Path, front_folder: str) -> dict[str, np.ndarray]:
    """Two sequences of 3 frames in the authors' layout (their absolute paths, 4 slots, 0/115/255)."""
    rng = np.random.default_rng(1)
    lays = {}
    (root / "img").mkdir(parents=True)
    (root / "topLayouts").mkdir()
    (root / front_folder).mkdir(exist_ok=True)
    names = [f"{s}_{i:06d}" for s in (9, 12) for i in range(3)]
    for n in names:
        Image.fromarray(rng.integers(0, 255, (48, 64, 3), np.uint8)).save(root / "img" / f"{n}.png")
        for view, folder in (("top", "topLayouts"), ("front", front_folder)):
            lay = np.zeros((4, 32, 32), np.uint8)
            lay[0, 8:20, 4:30] = 115
            lay[0, 10:14, 6:12] = 255
            lay[1, rng.integers(0, 32), :] = 115
            np.save(root / folder / f"{view}{n}.npy", lay)
            lays[view + n] = lay
    lists = root / "splits" / "warehouse"
    lists.mkdir(parents=True)
    far = "/scratch/RackLay/data/finalData/img/"
    # their file: the comma opens the next sequence's first line, the file ends with ","
    text = "".join(f"{far}{n}.png\n" for n in names[:3]) + "," + "".join(f"{far}{n}.png\n" for n in names[3:]) + ","
    (lists / "train_temporal_files.txt").write_text(text)
    (lists / "val_files.txt").write_text("".join(f"{far}{n}.png\n" for n in names[:2]))
    return lays


@pytest.mark.parametrize("front_folder", ["topLayouts", "frontLayouts"])
def test_a_dataset_in_their_layout_reads(tmp_path: Path, capsys: pytest.CaptureFixture, front_folder: str) -> None:
    lays = _write_published(tmp_path / "theirs", front_folder)
    data = open_data(tmp_path / "theirs")
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no camera records" in err[0] and "2.6 m" in err[0] and "60 deg" in err[0]
    assert (data.spec.num_slots, data.spec.size) == (4, 32) and data.image_size == (64, 48)
    train, val = data.sequences("train"), data.sequences("val")
    assert [s.num_frames for s in train] == [3, 3] and [s.num_frames for s in val] == [1, 1]
    lay = train[1].layouts(2)
    for view in ("top", "front"):
        codes = lays[f"{view}12_000002"]
        assert np.array_equal(getattr(lay, view), (codes == 115) * 1 + (codes == 255) * 2)
    assert train[0].rgb(0).shape == (48, 64, 3) and train[0].frame(1)["distance"] == DEFAULT_DISTANCE_M
    assert DEFAULT_DISTANCE_M == DEFAULT_DISTANCE and train[0].intrinsics.hfov_deg == pytest.approx(60.0)
    shutil.rmtree(tmp_path / "theirs" / "splits")
    with pytest.raises(InputError, match="no split lists"):
        open_data(tmp_path / "theirs")


def test_train_and_evaluate_on_their_layout(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    _write_published(tmp_path / "theirs", "topLayouts")
    run = tmp_path / "run"
    args = ["--epochs", "1", "--steps-per-epoch", "2", "--frames-per-step", "2", *TINY_NET]
    assert main(["train", "--data", str(tmp_path / "theirs"), "--out", str(run), *args]) == 0
    out = tmp_path / "eval.json"
    cmd = ["evaluate", "--checkpoint", str(run / "last.pt"), "--data", str(tmp_path / "theirs"), "--split", "train"]
    assert main([*cmd, "--metric", "reference", "--threads", "1", "--quiet", "--json-out", str(out)]) == 0
    res = json.loads(out.read_text())
    assert res["reference_windows"] == 6 and res["reference"]["top"]["rack"]["pairs"] == 6 * 4
    assert "reference metric" in capsys.readouterr().out
