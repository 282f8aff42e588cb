"""Every file in weights/ is what its README promises: fp16, under 30 MB, its JSON beside it, and a
model that still reads shelves and boxes (Table I on the tiny generated dataset, far above chance)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch

from mvracklay import pipeline
from mvracklay.cli import main
from network.checkpoint import json_path, load_checkpoint, model_from

WEIGHTS = sorted((pipeline.REPO_ROOT / "weights").glob("*.pt"))
#: mIoU floors (percent, columns in view) on the tiny dataset; the shipped files score 84-91 top rack,
#: 57-76 top box, 95 front rack, 73-84 front box there, and the same model with its initial weights 0
FLOORS = {("top", "rack"): 70.0, ("top", "box"): 45.0, ("front", "rack"): 85.0, ("front", "box"): 60.0}


def test_default_model_is_shipped():
    assert pipeline.DEFAULT_CHECKPOINT in WEIGHTS


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
    assert main([*args, "--json", str(out), "--quiet", "--threads", "2"]) == 0
    table = json.loads(out.read_text())["visible"]
    for (view, cls), floor in FLOORS.items():
        assert 100 * table[view][cls]["miou"] >= floor, (view, cls, table[view][cls]["miou"])
