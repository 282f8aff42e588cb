"""Depths read from the whole sequence (``whole_sequence``): every frame gets what all the frames showed."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from tiny_net import fixed_steps, tiny_config

from layouts.spec import LayoutSpec
from network.data import row_target
from network.heads.backedge import DEPTH_STEP, back_edge_rows
from network.heads.boxdepth import BINS
from network.inference.predictor import HEAD_INPUTS, Predictor
from network.model.net import MVRackLay
from network.preprocess import DEFAULT_DISTANCE
from network.training.fit_box_depth import with_box_head

SPEC = LayoutSpec(size=16)
FRAMES = 5
STEP = SPEC.x_extent / SPEC.size  #: the camera's (patched) motion per frame: one layout column


def _heads_shown_last(monkeypatch) -> MVRackLay:
    """A tiny model with both depth heads whose readings only the last frame carries: its back edges put
    the rack 1.05 m deep and its box head shows a 0.3 m back in every column; the frames before show
    nothing. The camera moves one column per frame."""
    plain = MVRackLay(tiny_config(SPEC, back_edges=True)).eval()
    model = with_box_head(plain)
    view = model.cfg.view
    h0, m = view.height / 2, view.metres_per_pixel
    fronts = [h0 + 0.9 / m, h0 - 1.0 / m]
    back = back_edge_rows(fronts, view, DEFAULT_DISTANCE, 1.05)[0]
    prob = 0.02 + 0.96 * row_target([float(r) for r in back], view.height)
    edges = torch.from_numpy(np.log(prob / (1 - prob))).float()
    calls = {"back": 0, "box": 0}

    def back_forward(pooled: torch.Tensor) -> torch.Tensor:
        last = calls["back"] == FRAMES - 1
        calls["back"] += pooled.shape[0]
        return (edges if last else torch.zeros_like(edges)).expand(pooled.shape[0], -1)

    def box_forward(win: torch.Tensor, extra: torch.Tensor) -> torch.Tensor:
        last = calls["box"] == FRAMES - 1
        calls["box"] += 1
        out = torch.full((win.shape[0], len(BINS) + 1, SPEC.size), -20.0)
        out[:, int(np.argmin(np.abs(BINS - 0.3)))] = 20.0
        out[:, -1] = 20.0 if last else -20.0
        return out

    monkeypatch.setattr("network.inference.predictor.board_peaks", lambda p, v: fronts)
    monkeypatch.setattr("network.inference.predictor.StepReader", fixed_steps(STEP))
    monkeypatch.setattr(model.back, "forward", back_forward)
    monkeypatch.setattr(model.box_depth, "forward", box_forward)
    model.frozen_graphs = False  # the patched forwards count their calls in Python: a traced graph would not
    torch.nn.init.constant_(model.rows.net[-1].bias, 2.0)
    model.calls = calls
    return model


@pytest.mark.parametrize("mode", ["stream", "window"])
def test_every_frame_gets_what_the_last_frame_showed(mode, monkeypatch):
    frames = [np.random.default_rng(i).integers(0, 255, (96, 128, 3), np.uint8) for i in range(FRAMES)]
    model = _heads_shown_last(monkeypatch)
    causal = list(Predictor(model, fuse_tau=0).run(frames, mode))  # the depths alone (network.inference.fusion aside)
    model.calls.update(back=0, box=0)
    whole = list(Predictor(model, whole_sequence=True, fuse_tau=0).run(frames, mode))
    assert len(whole) == FRAMES
    # so far: only the last frame knows the depths
    last = causal[-1].rack_depth
    assert last == pytest.approx(1.05, abs=0.1)  # a 64-pixel-high canonical view reads it to a few centimetres
    # before it the depth is unknown (NaN: flat scores peak on the hypotheses' edge) or far from it
    assert all(not abs(o.rack_depth - last) <= 10 * DEPTH_STEP for o in causal[:-1])
    assert all(np.isnan(o.box_back[0]).all() for o in causal[:-1])
    # whole sequence: every frame has the last frame's rack depth, and its box backs where the last frame's view
    # overlaps its own (frame i sees the last frame's column j at its column j + (FRAMES - 1 - i))
    assert [o.rack_depth for o in whole] == [causal[-1].rack_depth] * FRAMES
    valid = torch.isfinite(whole[0].anchors).numpy()
    assert valid.any()
    for i, o in enumerate(whole):
        backs = o.box_back
        lag = FRAMES - 1 - i
        for r in np.nonzero(valid)[0]:
            assert np.isnan(backs[r, :lag]).all()
            assert backs[r, lag:] == pytest.approx(BINS[int(np.argmin(np.abs(BINS - 0.3)))], abs=1e-3)
        assert torch.equal(o.top, causal[i].top) and torch.equal(o.front, causal[i].front)
        assert not set(HEAD_INPUTS) & set(o.maps)  # the heads' inputs are not held
    lay = whole[0].layouts(SPEC)["top"]
    assert lay.shape == (SPEC.num_slots, SPEC.size, SPEC.size)


def test_a_given_depth_or_no_reading_is_kept_whole(monkeypatch):
    frames = [np.random.default_rng(i).integers(0, 255, (96, 128, 3), np.uint8) for i in range(FRAMES)]
    model = _heads_shown_last(monkeypatch)
    given = list(Predictor(model, rack_depth=0.9, whole_sequence=True).run(frames))
    assert [o.rack_depth for o in given] == [0.9] * FRAMES
    assert all(o.box_back is not None for o in given)
    off = list(Predictor(model, read_depth=False, whole_sequence=True).run(frames))
    assert all(math.isnan(o.rack_depth) and o.box_back is None for o in off)
