"""A known rack depth imposed on predicted top views (`layouts.rackdepth`, `--rack-depth`)."""

from __future__ import annotations

import numpy as np
import pytest

from layouts import BOX, SHELF, InputError, LayoutSpec
from layouts.codecs import LayoutFolder
from layouts.rackdepth import check_rack_depth, depth_rows, impose_rack_depth
from layouts.raster import fill_rect
from mvracklay.cli import main
from stitching.warehouse_map import WarehouseMap

SPEC = LayoutSpec(num_slots=2, size=64)


def shelf_top(
    depth: float, boxes: list[tuple[float, float, float]], x: tuple[float, float] = (-1.5, 1.5)
) -> np.ndarray:
    """One slot: a footprint ``depth`` deep over ``x``, boxes ``(x centre, width, depth)`` set 2 cm back from its front."""
    slot = np.zeros((SPEC.size, SPEC.size), np.uint8)
    fill_rect(slot, SPEC, "top", ((x[0] + x[1]) / 2, 0.0), (x[1] - x[0], depth), SHELF)
    front = -depth / 2  # +Z is away from the camera: the front face is the smallest Z
    for cx, w, d in boxes:
        fill_rect(slot, SPEC, "top", (cx, front + 0.02 + d / 2), (w, d), BOX)
    return slot


def test_a_misjudged_depth_is_redrawn_to_the_truth():
    boxes = [(-0.8, 0.4, 0.3), (0.5, 0.6, 0.5)]
    truth = np.stack([shelf_top(0.9, boxes), shelf_top(0.9, boxes[:1], x=(-1.5, 0.2))])
    pred = np.stack([shelf_top(1.16, boxes), shelf_top(1.16, boxes[:1], x=(-1.5, 0.2))])
    assert not np.array_equal(pred, truth)
    out = impose_rack_depth(pred, SPEC, 0.9)
    # Rows of the footprint, and the boxes moved with the front edge: the truth back, up to one
    # row of rounding where a box's rasterised front falls between rows.
    assert np.array_equal(out > 0, truth > 0)
    assert np.abs(out.astype(int) - truth).sum() <= 2 * 2 * SPEC.size
    assert ((out == BOX) ^ (truth == BOX)).sum() < 0.1 * (truth == BOX).sum()
    # The boxes kept their own depth and columns.
    assert np.array_equal((out == BOX).any(1), (pred == BOX).any(1))
    assert (out[0] == BOX).sum(0).max() == (pred[0] == BOX).sum(0).max()


def test_rows_and_columns_follow_the_depth_and_the_prediction():
    pred = np.stack([shelf_top(1.0, [], x=(-0.5, 0.5)), np.zeros((SPEC.size, SPEC.size), np.uint8)])
    for depth in (0.6, 1.2):
        out = impose_rack_depth(pred, SPEC, depth)
        rows = depth_rows(SPEC, depth)
        assert rows.sum() == pytest.approx(depth / SPEC.pixel_size("top")[1], abs=1)
        cols = (pred[0] > 0).any(0)
        assert np.array_equal(out[0] > 0, rows[:, None] & cols[None, :])
        assert not out[1].any()  # an empty slot stays empty
    assert (impose_rack_depth(pred, SPEC, 1.2) > 0).sum() > (impose_rack_depth(pred, SPEC, 0.6) > 0).sum()


@pytest.mark.parametrize("bad", [0.0, -1.0, float("nan"), float("inf"), 2.0, True])
def test_a_bad_depth_is_a_one_line_error(bad):
    with pytest.raises(InputError, match="--rack-depth"):
        check_rack_depth(bad, SPEC)


def test_a_wrong_shape_is_refused():
    with pytest.raises(InputError, match="shape"):
        impose_rack_depth(np.zeros((2, 32, 32), np.uint8), SPEC, 1.0)


def test_predict_and_run_take_a_rack_depth(tiny_checkpoint, tiny_dataset, tmp_path, capsys):
    seq = sorted(p for p in tiny_dataset.iterdir() if p.name.startswith("seq_"))[0]
    common = ["--checkpoint", str(tiny_checkpoint), "--threads", "1", "--quiet"]
    assert main(["predict", str(seq), "--out", str(tmp_path / "p"), "--rack-depth", "0.8", *common]) == 0
    folder = LayoutFolder(tmp_path / "p")
    rows = depth_rows(folder.spec, 0.8)
    for i in folder.indices():
        top = folder.read(i).top
        filled = (top > 0).any(2)  # (R, D): rows with any footprint, per slot
        for r in range(top.shape[0]):
            if filled[r].any():
                assert np.array_equal(filled[r], rows)
    assert main(["run", str(seq), "--out", str(tmp_path / "r"), "--rack-depth", "0.8", "--no-rrd", *common]) == 0
    top = LayoutFolder(tmp_path / "r" / "layouts").read(0).top
    assert WarehouseMap.load(tmp_path / "r" / "warehouse.json").meta["rack_depth"] == 0.8
    assert all(np.array_equal((t > 0).any(1), rows) for t in top if t.any())
    capsys.readouterr()
    for cmd in ("predict", "run"):
        assert main([cmd, str(seq), "--out", str(tmp_path / "x"), "--rack-depth", "-1", *common]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and "--rack-depth" in err
    assert main(["predict", str(seq), "--out", str(tmp_path / "y"), "--rack-depth", "5", *common]) == 2
    assert "depth extent" in capsys.readouterr().err


def test_eval_reconstruction_takes_the_scene_depth(tiny_checkpoint, tiny_dataset, tmp_path, capsys):
    seq = sorted(p for p in tiny_dataset.iterdir() if p.name.startswith("seq_"))[0]
    ckpt = ["--checkpoint", str(tiny_checkpoint), "--threads", "1", "--quiet", "--json"]
    assert main(["eval-reconstruction", str(seq), "--rack-depth", "scene", *ckpt]) == 0
    assert "summary" in capsys.readouterr().out
    assert main(["eval-reconstruction", str(seq), "--rack-depth", "scene", "--quiet"]) == 2
    assert "needs --checkpoint" in capsys.readouterr().err
    assert main(["eval-reconstruction", str(seq), "--rack-depth", "deep", *ckpt]) == 2
    assert "metres or 'scene'" in capsys.readouterr().err
