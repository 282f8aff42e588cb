"""Depth-projection baseline: sees what is visible, nothing amodal, and checks its input."""

import numpy as np
import pytest

from layouts.errors import InputError
from layouts.metrics import LayoutMetrics
from mvracklay.baselines.depth_projection import depth_projection_layouts
from waresynth.dataset import open_dataset


def _score(ds):
    m = LayoutMetrics()
    for seq in ds.sequences():
        z_front = seq.scene()["row"]["z_front"]
        for i in range(seq.num_frames):
            got = depth_projection_layouts(
                seq.depth(i), seq.semantic(i), seq.intrinsics, seq.frame(i), z_front, seq.spec
            )
            gt = seq.layouts(i)
            assert got.top.shape == gt.top.shape == got.front.shape
            for view in ("top", "front"):
                m.update(getattr(got, view), getattr(gt, view), view)
    return m.result()


def test_depth_projection_agrees_with_ground_truth_where_visible(tiny_dataset):
    r = _score(open_dataset(tiny_dataset))
    # The front faces are seen: the front view is largely right and what it claims is precise.
    assert r["front"]["rack"]["miou"] > 0.6
    assert r["front"]["rack"]["map"] > 0.9
    assert r["front"]["box"]["pooled_iou"] > 0.4
    # Board tops are seen only obliquely or not at all: the top view is far from complete,
    # but the board surface it does see is placed correctly.
    assert r["top"]["rack"]["pooled_precision"] > 0.9
    assert r["top"]["rack"]["miou"] < r["front"]["rack"]["miou"]


def test_depth_projection_rejects_bad_input(tiny_dataset):
    seq = open_dataset(tiny_dataset).sequences()[0]
    z_front = seq.scene()["row"]["z_front"]
    depth, sem = seq.depth(0), seq.semantic(0)
    bad = depth.copy()
    bad[0, 0] = np.nan
    with pytest.raises(InputError, match="NaN"):
        depth_projection_layouts(bad, sem, seq.intrinsics, seq.frame(0), z_front, seq.spec)
    with pytest.raises(InputError, match="must both be"):
        depth_projection_layouts(depth[:10], sem, seq.intrinsics, seq.frame(0), z_front, seq.spec)


def test_evaluate_baseline_cli(tiny_dataset, tmp_path, capsys):
    import json

    from mvracklay.cli import main

    out = tmp_path / "r.json"
    assert (
        main(["evaluate-baseline", "--data", str(tiny_dataset), "--split", "all", "--json-out", str(out), "--quiet"])
        == 0
    )
    printed = capsys.readouterr().out
    assert "columns in view" in printed and "front  rack" in printed
    res = json.loads(out.read_text())
    assert res["frames"] == 24 and 0 < res["visible"]["front"]["rack"]["miou"] <= 1
    assert main(["evaluate-baseline", "--data", str(tmp_path / "nope")]) == 2
    assert "nope" in capsys.readouterr().err
