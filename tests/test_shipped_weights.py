"""Every shipped model file is what its README promises: fp16, under 30 MB, its JSON beside it, and a
model that still reads shelves and boxes (Table I on the tiny generated dataset, far above chance).
The inference models ship in the package (`mvracklay.models`), found by name or path; the training
intermediates stay in the repository's weights/."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch

from layouts.errors import InputError
from mvracklay import models, pipeline
from mvracklay.cli import main
from network.checkpoint import json_path, load_checkpoint, model_from

ROOT = Path(__file__).resolve().parents[1]
SHIPPED = [models.shipped_path(name) for name in models.SHIPPED]
WEIGHTS = SHIPPED + sorted((ROOT / "weights").glob("*.pt"))
#: mIoU floors (percent, columns in view) on the tiny dataset; the shipped files score 84-91 top rack,
#: 57-76 top box, 95 front rack, 73-84 front box there, and the same model with its initial weights 0
FLOORS = {("top", "rack"): 70.0, ("top", "box"): 45.0, ("front", "rack"): 85.0, ("front", "box"): 60.0}


def test_the_package_ships_the_inference_models_and_the_default():
    folder = models.default_checkpoint().parent
    assert sorted(p.stem for p in folder.glob("*.pt")) == sorted([*models.SHIPPED, models.DISTANCE_READER])
    assert models.distance_reader_path().is_file()
    assert all(p.is_file() and json_path(p).is_file() for p in SHIPPED)
    assert pipeline.DEFAULT_CHECKPOINT == models.default_checkpoint() == models.resolve_checkpoint(None)
    assert pipeline.DEFAULT_CHECKPOINT.stem == models.DEFAULT_MODEL
    assert not (ROOT / "weights" / f"{models.DEFAULT_MODEL}.pt").exists()  # one copy, in the package


def test_a_checkpoint_is_named_by_a_shipped_models_name_or_a_path(tmp_path: Path, monkeypatch):
    for name, path in zip(models.SHIPPED, SHIPPED):
        assert models.resolve_checkpoint(name) == path == models.checkpoint_arg(name)
    mine = tmp_path / "mine.pt"
    mine.write_bytes(b"")
    assert models.resolve_checkpoint(mine) == mine and models.resolve_checkpoint(str(mine)) == mine
    monkeypatch.chdir(tmp_path)  # a file of a shipped model's name in the working folder wins
    (tmp_path / models.DEFAULT_MODEL).write_bytes(b"")
    assert models.checkpoint_arg(models.DEFAULT_MODEL) == Path(models.DEFAULT_MODEL)
    with pytest.raises(InputError, match="--checkpoint mvracklay-disc-5: file not found .*mvracklay-disc-4-256"):
        models.resolve_checkpoint("mvracklay-disc-5")
    with pytest.raises(InputError, match="no shipped model named 'x'"):
        models.shipped_path("x")


@pytest.mark.parametrize("command", ["run", "predict", "evaluate", "eval-reconstruction"])
def test_commands_take_a_shipped_models_name(command: str):
    from mvracklay.cli import build_parser

    argv = [command, "in", "--out", "o", "--data", "d", "--checkpoint", "mvracklay-disc-4-256"]
    known, _ = build_parser().parse_known_args(argv)
    assert known.checkpoint == SHIPPED[1]


@pytest.mark.parametrize("weights", WEIGHTS, ids=[w.stem for w in WEIGHTS])
def test_shipped_file_is_fp16_small_and_documented(weights: Path):
    assert weights.stat().st_size <= 30 * 2**20
    payload, record = load_checkpoint(weights)
    assert json.loads(json_path(weights).read_text()) == record
    floats = [t for t in payload["model"].values() if t.is_floating_point()]
    assert floats and all(t.dtype == torch.float16 for t in floats)
    assert record.get("note"), "a shipped file says how it was trained"
    model = model_from(payload, record, weights)
    assert all(p.dtype == torch.float32 for p in model.parameters())


@pytest.mark.parametrize("weights", WEIGHTS, ids=[w.stem for w in WEIGHTS])
def test_shipped_model_reads_layouts(weights: Path, tiny_dataset: Path, tmp_path: Path):
    out = tmp_path / "table1.json"
    args = ["evaluate", "--checkpoint", str(weights), "--data", str(tiny_dataset), "--split", "all"]
    assert main([*args, "--json-out", str(out), "--quiet", "--threads", "2"]) == 0
    table = json.loads(out.read_text())["visible"]
    for (view, cls), floor in FLOORS.items():
        assert 100 * table[view][cls]["miou"] >= floor, (view, cls, table[view][cls]["miou"])
