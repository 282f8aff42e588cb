"""The authors' metric (MVRackLay utils.py mean_IU / mean_precision in eval_vracklay.py's loop) on hand-made cases."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from layouts.errors import LayoutError
from layouts.metrics import ReferenceMetrics, reference_iou, reference_precision, reference_weights
from mvracklay.cli import main

E = np.zeros((2, 2), bool)  # empty
F = np.ones((2, 2), bool)  # full
A = np.array([[1, 1], [0, 0]], bool)
B = np.array([[1, 0], [0, 0]], bool)


@pytest.mark.parametrize(
    ("pred", "gt", "iou", "precision"),
    [
        (E, E, 1.0, 1.0),  # both empty: 1 and 1
        (A, E, 0.0, 1.0),  # a false positive on an empty slot: precision of "not the class" = 1
        (F, E, 0.0, 0.0),  # ... unless every cell is claimed (no background cell predicted)
        (E, A, 0.0, 0.0),  # nothing predicted of a present class: their NaN -> 0
        (A, B, 0.5, 0.5),
        (B, A, 0.5, 1.0),
        (F, F, 1.0, 1.0),
        (F, A, 0.5, 0.5),
    ],
)
def test_pair_rules(pred: np.ndarray, gt: np.ndarray, iou: float, precision: float) -> None:
    assert reference_iou(pred, gt) == iou and reference_precision(pred, gt) == precision


def test_windows_target_f0_twice_and_never_the_last() -> None:
    assert reference_weights(1) == [1]
    assert reference_weights(2) == [2, 0]
    assert reference_weights(5) == [2, 1, 1, 1, 0]
    assert sum(reference_weights(50)) == 50


def test_sums_are_divided_by_frames_times_slots() -> None:
    """Two slots: one shelf predicted half right (IoU 0.5), one empty slot predicted empty (1, 1)."""
    gt = np.zeros((2, 2, 2), np.uint8)
    gt[0] = A  # class 1 (shelf) on slot 0
    pred = np.zeros_like(gt)
    pred[0] = B
    m = ReferenceMetrics()
    m.update(pred, gt, "top", weight=2)
    m.update(gt, gt, "top", weight=1)
    m.update(gt, gt, "top", weight=0)  # a sequence's last frame: not a target
    r = m.result()["top"]
    # rack: frames (0.5 + 1) x2 and (1 + 1) once over 3 frames x 2 slots; precision (1 + 1) every time
    assert r["rack"]["miou"] == pytest.approx((2 * 1.5 + 2) / 6) and r["rack"]["map"] == pytest.approx(1.0)
    assert r["rack"]["pairs"] == 6 and m.frames["top"] == 3
    # box: absent everywhere, predicted nowhere: every pair scores 1
    assert r["box"]["miou"] == 1.0 and r["box"]["map"] == 1.0
    assert np.isnan(m.result()["front"]["box"]["miou"])
    with pytest.raises(LayoutError, match="reference metric"):
        m.update(pred[0], gt, "top")


def test_evaluate_metric_reference_beside_ours(
    tiny_checkpoint: Path, tiny_dataset: Path, tmp_path: Path, capsys
) -> None:
    out = tmp_path / "r.json"
    cmd = ["evaluate", "--checkpoint", str(tiny_checkpoint), "--data", str(tiny_dataset), "--split", "all"]
    assert (
        main([*cmd, "--max-frames", "3", "--metric", "both", "--threads", "1", "--quiet", "--json-out", str(out)]) == 0
    )
    text = capsys.readouterr().out
    assert "columns in view" in text and "reference metric, 9 windows of 3 sequences" in text
    res = json.loads(out.read_text())
    assert res["metric"] == "both" and res["reference_windows"] == 9 and res["frames"] == 9
    for view in ("top", "front"):
        for c in ("rack", "box"):
            assert 0.0 <= res["reference"][view][c]["miou"] <= 1.0 and res["reference"][view][c]["pairs"] == 9 * 3
    assert main([*cmd, "--max-frames", "2", "--metric", "reference", "--threads", "1", "--quiet"]) == 0
    assert "columns in view" not in capsys.readouterr().out
