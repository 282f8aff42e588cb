"""The train / evaluate / predict commands end to end on the tiny generated dataset."""

from __future__ import annotations

import json

import numpy as np
import pytest
from tiny_net import TINY_NET

from layouts.codecs import LayoutFolder
from mvracklay.cli import main
from network.model import frozen

TINY = TINY_NET


@pytest.fixture(scope="module")
def run_dir(tiny_dataset, tmp_path_factory):
    out = tmp_path_factory.mktemp("net") / "run"
    rc = main(
        [
            "train",
            "--data",
            str(tiny_dataset),
            "--out",
            str(out),
            "--epochs",
            "1",
            "--steps-per-epoch",
            "2",
            "--frames-per-step",
            "4",
            *TINY,
        ]
    )
    assert rc == 0
    return out


def test_train_writes_checkpoints_metrics_and_records(run_dir):
    for name in ("last.pt", "last.json", "best.pt", "best.json", "metrics.jsonl"):
        assert (run_dir / name).is_file()
    rec = json.loads((run_dir / "last.json").read_text())
    assert rec["variant"] == "mvracklay-disc-4" and rec["step"] == 2
    assert rec["spec"]["size"] == 16 and rec["intrinsics"]["width"] == 128
    assert rec["input_size"] == [64, 64]


def test_evaluate_prints_table_and_json(run_dir, tiny_dataset, tmp_path, capsys):
    out = tmp_path / "eval.json"
    rc = main(
        [
            "evaluate",
            "--checkpoint",
            str(run_dir / "best.pt"),
            "--data",
            str(tiny_dataset),
            "--split",
            "all",
            "--max-frames",
            "3",
            "--threads",
            "1",
            "--quiet",
            "--json-out",
            str(out),
        ]
    )
    assert rc == 0
    text = capsys.readouterr().out
    assert "top    rack" in text and "columns in view" in text and "all cells" in text
    res = json.loads(out.read_text())
    assert res["frames"] == 9 and set(res["visible"]) == {"top", "front"}


def test_evaluate_and_predict_take_flip_average(run_dir, tiny_dataset, tmp_path, capsys):
    out = tmp_path / "eval.json"
    ckpt = ["--checkpoint", str(run_dir / "best.pt"), "--threads", "1", "--quiet", "--flip-average"]
    rc = main(
        ["evaluate", *ckpt, "--data", str(tiny_dataset), "--split", "all", "--max-frames", "2", "--json-out", str(out)]
    )
    assert rc == 0
    assert "flip-averaged" in capsys.readouterr().out
    res = json.loads(out.read_text())
    assert res["flip_average"] is True and res["frames"] == 6
    seq = sorted(p for p in tiny_dataset.iterdir() if p.name.startswith("seq_"))[0]
    assert main(["predict", str(seq), *ckpt, "--out", str(tmp_path / "lay"), "--mode", "window"]) == 0
    assert LayoutFolder(tmp_path / "lay").indices() == list(range(8))


def test_evaluate_and_predict_run_a_bf16_trunk_on_request(run_dir, tiny_dataset, tmp_path, capsys, monkeypatch):
    built = []
    build = frozen._build

    def counted(model, part, fn, xs, bf16):
        built.append((part, bf16))
        return build(model, part, fn, xs, bf16)

    monkeypatch.setattr(frozen, "_build", counted)
    out = tmp_path / "eval.json"
    ckpt = ["--checkpoint", str(run_dir / "best.pt"), "--threads", "1", "--quiet", "--precision", "bf16"]
    assert (
        main(
            [
                "evaluate",
                *ckpt,
                "--data",
                str(tiny_dataset),
                "--split",
                "all",
                "--max-frames",
                "2",
                "--json-out",
                str(out),
            ]
        )
        == 0
    )
    assert ", the trunk in bf16" in capsys.readouterr().out
    res = json.loads(out.read_text())
    assert res["precision"] == "bf16" and res["frames"] == 6 and 0 <= res["visible"]["top"]["rack"]["miou"] <= 1
    assert ("trunk", True) in built and all(bf16 is (part == "trunk") for part, bf16 in built)
    built.clear()
    seq = sorted(p for p in tiny_dataset.iterdir() if p.name.startswith("seq_"))[0]
    assert main(["predict", str(seq), *ckpt, "--out", str(tmp_path / "lay")]) == 0
    assert LayoutFolder(tmp_path / "lay").indices() == list(range(8)) and ("trunk", True) in built


def test_predict_writes_a_layout_folder_reconstruct_can_read(run_dir, tiny_dataset, tmp_path):
    seq = sorted(p for p in tiny_dataset.iterdir() if p.name.startswith("seq_"))[0]
    for mode, src in (("stream", seq), ("window", seq / "rgb")):
        out = tmp_path / mode
        rc = main(
            [
                "predict",
                str(src),
                "--checkpoint",
                str(run_dir / "best.pt"),
                "--out",
                str(out),
                "--mode",
                mode,
                "--layout-size",
                "32",
                "--threads",
                "1",
                "--quiet",
            ]
        )
        assert rc == 0
        folder = LayoutFolder(out)
        assert folder.indices() == list(range(8)) and folder.spec.size == 32
        fl = folder.read(0)
        assert fl.top.shape == (3, 32, 32) and fl.visible is not None and fl.visible.dtype == np.bool_


def test_bad_inputs_are_one_line_errors(run_dir, tiny_dataset, tmp_path, capsys):
    bad = tmp_path / "bad.pt"
    bad.write_bytes(b"not a checkpoint")
    assert main(["evaluate", "--checkpoint", str(bad), "--data", str(tiny_dataset)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "bad.pt" in err
    assert main(["predict", str(tmp_path), "--checkpoint", str(run_dir / "best.pt"), "--out", str(tmp_path / "o")]) == 2
    assert "no images" in capsys.readouterr().err
    assert main(["train", "--data", str(tmp_path / "nope"), "--out", str(tmp_path / "r"), "--quiet"]) == 2
    assert "not found" in capsys.readouterr().err


def test_train_joins_several_datasets_and_refuses_a_different_spec(tiny_dataset, tmp_path, capsys):
    from layouts import LayoutSpec
    from waresynth.dataset import open_dataset
    from waresynth.generate import DatasetSettings, generate_dataset

    other = generate_dataset(
        tmp_path / "other",
        DatasetSettings(
            num_sequences=2, frames=4, image_size=(128, 128), spec=LayoutSpec(size=64), seed=8, progress=False
        ),
    )
    out = tmp_path / "run"
    args = ["train", "--data", str(tiny_dataset), str(other), "--out", str(out), "--epochs", "1"]
    assert main([*args, "--steps-per-epoch", "1", "--frames-per-step", "4", *TINY]) == 0
    rec = json.loads((out / "last.json").read_text())
    n_train = sum(len(open_dataset(d).sequences("train")) for d in (tiny_dataset, other))
    assert rec["data"]["root"] == [str(tiny_dataset), str(other)]
    assert rec["data"]["train_sequences"] == n_train and rec["data"]["seed"] == [7, 8]
    coarse = generate_dataset(
        tmp_path / "coarse",
        DatasetSettings(
            num_sequences=1, frames=2, image_size=(128, 128), spec=LayoutSpec(size=32), seed=9, progress=False
        ),
    )
    capsys.readouterr()
    assert main(["train", "--data", str(tiny_dataset), str(coarse), "--out", str(tmp_path / "r2"), *TINY]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "coarse" in err and "differs" in err


def test_eval_reconstruction_with_a_checkpoint_scores_the_predicted_layouts(run_dir, tiny_dataset, tmp_path, capsys):
    seq = sorted(p for p in tiny_dataset.iterdir() if p.name.startswith("seq_"))[0]
    ckpt = str(run_dir / "best.pt")
    capsys.readouterr()
    assert main(["eval-reconstruction", str(seq), "--checkpoint", ckpt, "--threads", "1", "--json", "--quiet"]) == 0
    direct = json.loads(capsys.readouterr().out)
    pred = tmp_path / "pred"
    assert main(["predict", str(seq), "--checkpoint", ckpt, "--out", str(pred), "--threads", "1", "--quiet"]) == 0
    capsys.readouterr()
    assert main(["eval-reconstruction", str(seq), "--layouts", str(pred), "--json", "--quiet"]) == 0
    via_folder = json.loads(capsys.readouterr().out)
    assert direct == via_folder
    gt = main(["eval-reconstruction", str(seq), "--json", "--quiet"])
    assert gt == 0 and json.loads(capsys.readouterr().out)["summary"]["recall"] == 1.0
    assert main(["eval-reconstruction", str(seq), "--checkpoint", ckpt, "--layouts", str(pred)]) == 2
    assert "--checkpoint" in capsys.readouterr().err
