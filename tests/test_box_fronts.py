"""A box-depth head that also reads each box's front: the logits' layout, the fronts imposed on the
top view, carried along the row, fitted, and round-tripped through the `fit-box-depth` stage's `--front`."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from test_box_depth import slot_with_box

from layouts import BOX
from layouts.boxdepth import box_parts, impose_box_backs
from layouts.errors import InputError
from layouts.spec import LayoutSpec
from mvracklay.training.stages import run_stage
from network.checkpoint import load_checkpoint, load_model
from network.heads.boxdepth import BINS, FRONT_BINS, BoxDepthHead, BoxDepthReader, front_reading, reading, split_logits
from network.inference.layout_eval import box_depth_source
from network.inference.predictor import Predictor
from network.inference.result import frame_layouts
from network.training.box_cache import Cache, cache_inputs
from network.training.fit_box_depth import FitConfig, train_head, with_box_head
from waresynth.dataset import open_dataset
from waresynth.visibility import SeenTracker

SPEC = LayoutSpec(size=16)


def peaked(values: np.ndarray, at: float) -> np.ndarray:
    """``(K,)`` log-probabilities of a sharp reading over ``values`` centred at ``at``."""
    lg = -0.5 * ((values - at) / 0.02) ** 2
    return lg - np.log(np.exp(lg).sum())


def test_the_logits_split_into_backs_shown_and_fronts():
    k, f = len(BINS), len(FRONT_BINS)
    plain = torch.randn(2, k + 1, 5)
    back, shown, front = split_logits(plain)
    assert back.shape == (2, k, 5) and shown.shape == (2, 5) and front is None
    assert front_reading(plain) is None
    logits = torch.randn(2, k + 1 + f, 5)
    back, shown, front = split_logits(logits)
    assert torch.equal(back, logits[:, :k]) and torch.equal(shown, logits[:, k]) and front.shape == (2, f, 5)
    assert np.allclose(np.exp(front_reading(logits)).sum(1), 1.0, atol=1e-5)
    # the backs and shown probabilities read the same with or without the fronts after them
    for a, b in zip(reading(logits), reading(logits[:, : k + 1])):
        np.testing.assert_array_equal(a, b)
    with pytest.raises(ValueError, match="channels"):
        split_logits(torch.randn(1, k + 3, 5))
    head = BoxDepthHead(4, 3, width=8, front=True)
    assert head(torch.randn(2, 4, 4, 5), torch.randn(2, 3, 5)).shape == (2, k + 1 + f, 5)


def test_fronts_move_each_box_front_and_leave_unknown_columns():
    top, front = slot_with_box(SPEC, slice(6, 15), slice(3, 7))  # rows 6-14: its front at row 14
    depth, cell = 1.0, SPEC.z_extent / SPEC.size
    ((_, zf0, _, _),) = box_parts(top[0], front[0], SPEC, depth)
    backs = np.full((1, SPEC.size), 0.7)
    fronts = np.full((1, SPEC.size), np.nan)
    fronts[0, 3:5] = zf0[0] + 2 * cell  # two columns set back by two cells; the other two keep their own
    out = impose_box_backs(top, front, SPEC, depth, backs, fronts=fronts)
    ((cols, zf, zb, _),) = box_parts(out[0], front[0], SPEC, depth)
    assert list(cols) == [3, 4, 5, 6]
    assert zf == pytest.approx([zf0[0] + 2 * cell] * 2 + [zf0[0]] * 2, abs=1e-9)
    assert np.allclose(zb, 0.7, atol=cell)  # the backs as before
    plain = impose_box_backs(top, front, SPEC, depth, backs)
    nan = impose_box_backs(top, front, SPEC, depth, backs, fronts=np.full((1, SPEC.size), np.nan))
    np.testing.assert_array_equal(nan, plain)
    deep = impose_box_backs(top, front, SPEC, depth, backs, fronts=np.full((1, SPEC.size), 0.9))  # behind the back
    ((_, zf, zb, _),) = box_parts(deep[0], front[0], SPEC, depth)
    assert np.all(zb > zf) and np.count_nonzero(deep[0] == BOX) == 4  # at least the front cell stays a box
    with pytest.raises(ValueError, match="fronts must have the shape"):
        impose_box_backs(top, front, SPEC, depth, backs, fronts=np.zeros((1, 3)))


def test_the_reader_carries_fronts_every_frame_counting_once():
    reader = BoxDepthReader(SPEC)
    k, d = len(BINS), SPEC.size
    log_q = np.full((1, k, d), -np.log(k))
    shown = np.zeros((1, d))  # the backs are never shown: fronts are read regardless
    valid = np.array([True])
    assert reader.fronts(0.0, valid) is None  # a head without fronts gives none
    reader.add(log_q, shown, valid, 0.0, peaked(FRONT_BINS, 0.04)[None, :, None].repeat(d, 2))
    step = SPEC.x_extent / SPEC.size  # one column along +X: the same shelf is one column left
    reader.add(log_q, shown, valid, step, peaked(FRONT_BINS, 0.08)[None, :, None].repeat(d, 2))
    got = reader.fronts(reader.camera_x, valid)
    assert got[0, 3] == pytest.approx(0.06, abs=0.005)  # two readings as sure: their product halfway
    assert got[0, -1] == pytest.approx(0.08, abs=0.005)  # only the second frame saw the last column
    assert np.isnan(reader.fronts(reader.camera_x, np.array([False]))).all()


def test_a_cache_without_fronts_reads_them_as_unknown_and_a_front_head_refuses_it():
    rng = np.random.default_rng(0)
    old = Cache(rng.random((4, 2, 3, 5)).astype(np.float16), rng.random((4, 3, 5)).astype(np.float16),
                np.full((4, 5), 0.4, np.float32), np.ones((4, 5), bool))  # fmt: skip
    assert old.front.shape == (4, 5) and np.isnan(old.front).all()
    head = BoxDepthHead(2, 3, width=4, front=True)
    with pytest.raises(InputError, match="no box fronts"):
        train_head(head, old, FitConfig(epochs=1, batch=2), progress=False)


def test_the_head_learns_fronts(tiny_checkpoint, tiny_dataset, tmp_path):
    model = with_box_head(load_model(tiny_checkpoint)[0], front=True)
    assert model.cfg.box_front and model.box_depth.front
    data = cache_inputs(model, open_dataset(tiny_dataset).sequences(), SeenTracker, tmp_path, progress=False)
    known = np.isfinite(data.front)
    assert known.any() and np.array_equal(known, np.isfinite(data.back))  # a front wherever a box has a back
    assert np.all((data.front[known] >= 0) & (data.front[known] < data.back[known]))
    torch.manual_seed(0)
    head = BoxDepthHead(data.win.shape[1], data.extra.shape[1], front=True)
    cfg = FitConfig(epochs=12, batch=8, lr=3e-3)
    losses = train_head(head, data, cfg, progress=False)
    torch.manual_seed(0)
    plain = train_head(BoxDepthHead(data.win.shape[1], data.extra.shape[1]), data, cfg, progress=False)
    assert losses[-1] < 0.7 * losses[0] and losses[0] > plain[0]  # the front term is part of the loss
    with torch.no_grad():
        logits = head(torch.from_numpy(data.win).float(), torch.from_numpy(data.extra).float())
    q = np.exp(front_reading(logits))
    expected = (q * FRONT_BINS[None, :, None]).sum(1)
    err = np.abs(expected - data.front)[known].mean()
    assert err < np.abs(data.front[known] - FRONT_BINS.mean()).mean()  # better than the bins' middle


def test_fit_box_depth_front_round_trips_and_moves_the_fronts(tiny_checkpoint, tiny_dataset, tmp_path, capsys):
    out = tmp_path / "front.pt"
    args = ["--checkpoint", str(tiny_checkpoint), "--data", str(tiny_dataset), "--front"]
    assert run_stage("fit-box-depth", [*args, "--epochs", "1", "--out", str(out), "--threads", "1", "--quiet"]) == 0
    payload, record = load_checkpoint(out)
    assert record["model_config"]["box_front"] is True and record["box_depth"]["front"] is True
    model = load_model(out)[0]
    assert model.cfg.box_front
    plain = load_model(tiny_checkpoint)[0]
    assert box_depth_source(model) == "carried from the box-depth head, fronts too"  # what evaluate's table says
    assert box_depth_source(with_box_head(plain)) == "carried from the box-depth head"
    assert box_depth_source(plain) == "as decoded"
    seq = open_dataset(tiny_dataset).sequences()[0]
    frames = [seq.rgb(i) for i in range(seq.num_frames)]
    for whole in (False, True):
        outs = list(Predictor(model, rack_depth=0.8, whole_sequence=whole).run(frames))
        assert all(o.box_front.shape == o.box_back.shape for o in outs)
    assert next(iter(Predictor(load_model(tiny_checkpoint)[0], rack_depth=0.8).run(frames))).box_front is None
    with torch.no_grad():  # a head sure of every front at 0.10 m: every box's front is moved there
        model.box_depth.out.weight.zero_()
        model.box_depth.out.bias.fill_(-20.0)
        model.box_depth.out.bias[len(BINS)] = 20.0  # shown
        model.box_depth.out.bias[int(np.argmin(np.abs(BINS - 0.5)))] = 20.0
        model.box_depth.out.bias[len(BINS) + 1 + int(np.argmin(np.abs(FRONT_BINS - 0.10)))] = 20.0
    last = list(Predictor(model, rack_depth=0.8).run(frames))[-1]
    valid = np.isfinite(last.anchors.numpy())
    assert np.allclose(last.box_front[valid], 0.10, atol=1e-3)
    # frame_layouts moves the fronts of a frame's boxes there (here: a drawn box, its logits one-hot)
    top, front = (np.repeat(v, SPEC.num_slots, 0) for v in slot_with_box(SPEC, slice(6, 15), slice(3, 7)))
    hot = {v: 10.0 * torch.nn.functional.one_hot(torch.from_numpy(a).long(), 3).permute(0, 3, 1, 2).float()
           for v, a in (("top", top), ("front", front))}  # fmt: skip
    full = np.full((SPEC.num_slots, SPEC.size), 0.5)
    frame = {**hot, "rack_depth": torch.tensor(1.0), "box_back": torch.from_numpy(full)}
    lay = frame_layouts({**frame, "box_front": torch.from_numpy(full * 0 + 0.25)}, SPEC)
    ((_, zf, zb, _),) = box_parts(lay["top"][1], front[1], SPEC, 1.0)
    assert np.allclose(zf, 0.25, atol=SPEC.z_extent / SPEC.size) and np.allclose(
        zb, 0.5, atol=SPEC.z_extent / SPEC.size
    )
    ((_, zf_own, _, _),) = box_parts(frame_layouts(frame, SPEC)["top"][1], front[1], SPEC, 1.0)
    assert np.all(zf_own < 0.1)  # without fronts the drawn front stays
