"""Long-window training (`--prefix-frames`): warm-up frames feed the slot memory without encoder gradients."""

from __future__ import annotations

import json

import pytest
import torch
from test_network_model import ANCHORS, tiny
from test_network_train import seqs

from layouts import InputError, LayoutSpec
from network.data import WindowDataset
from network.model.net import MVRackLay
from network.training.toy import ToySequence
from network.training.trainer import TrainConfig, Trainer

SPEC = LayoutSpec(num_slots=2, size=16)


def _memory_model(seed: int = 3) -> MVRackLay:
    torch.manual_seed(seed)
    model = MVRackLay(tiny())
    torch.nn.init.normal_(model.memory.out.weight, std=0.5)  # the correction starts at zero; make it count
    return model


def test_warm_up_frames_change_the_outputs_but_get_no_encoder_gradient():
    model = _memory_model().eval()
    x = torch.rand(1, 6, 3, 64, 64)
    anchors = ANCHORS.expand(1, 6, 2)
    with torch.no_grad():
        full = model(x, anchors)
        last = model(x, anchors, grad_frames=2)
    for v in ("top", "front", "rows", "anchors"):
        assert last[v].shape[1] == 2
        torch.testing.assert_close(last[v], full[v][:, 4:])  # the memory ran over all six frames
    x = x.clone().requires_grad_(True)
    out = model(x, anchors, grad_frames=2)
    out["top"].square().sum().backward()
    g = x.grad.abs().sum((0, 2, 3, 4))
    assert (g[:4] == 0).all() and (g[4:] > 0).all()
    # ... but the memory's weights see them: other warm-up frames give other memory gradients
    grads = []
    for warm in (x.detach()[:, :4], torch.rand(1, 4, 3, 64, 64)):
        model.zero_grad()
        y = torch.cat([warm, x.detach()[:, 4:]], 1)
        model(y, anchors, grad_frames=2)["top"].square().sum().backward()
        grads.append(model.memory.lstm.cells[0].gates.weight.grad.clone())
    assert not torch.allclose(grads[0], grads[1])


def test_grad_frames_outside_the_window_is_refused():
    model = MVRackLay(tiny()).eval()
    for bad in (0, 5):
        with pytest.raises(InputError, match="grad_frames must be in 1..4"):
            model(torch.rand(1, 4, 3, 64, 64), ANCHORS.expand(1, 4, 2), grad_frames=bad)


def test_a_prefixed_window_repeats_no_frame_where_the_sequence_is_long_enough():
    short = ToySequence(SPEC, num_frames=12, step_cols=1, seed=0)
    long = ToySequence(SPEC, num_frames=40, step_cols=1, seed=1)
    ds = WindowDataset([short, long], seq_len=4, input_size=(64, 64), spec=SPEC, augment=True, max_stride=3, prefix=8)
    assert ds.frame_ids(11) == list(range(12))
    for idx in range(12):  # the 12-frame sequence: every window is the whole sequence, stride 1
        item = ds[idx]
        assert item["images"].shape == (12, 3, 64, 64) and item["top"].shape == (12, 2, 16, 16)
        steps = item["cam_x"].diff().abs()
        assert torch.allclose(steps, steps[0]) and steps[0] > 0
    strides = set()
    for idx in range(12, 52):  # the 40-frame one keeps strides up to 3 and never repeats a frame
        steps = ds[idx]["cam_x"].diff().abs()
        assert (steps > 0).all() and torch.allclose(steps, steps[0])
        strides.add(round(float(steps[0]), 4))
    assert len(strides) > 1
    with pytest.raises(InputError, match="prefix must be an integer >= 0"):
        WindowDataset([short], seq_len=4, input_size=(64, 64), spec=SPEC, prefix=-1)


def test_training_with_warm_up_frames_learns_and_is_recorded(tmp_path):
    data = seqs(2, 10)
    tcfg = TrainConfig(
        frames_per_step=8, steps_per_epoch=12, epochs=2, lr=1e-2, dice_weight=0.0, augment=False, threads=1,
        prefix_frames=4,
    )  # fmt: skip
    trainer = Trainer(tiny("mvracklay-4"), tcfg, data, data, tmp_path / "run", progress=False)
    assert trainer.batch == 2 and trainer.train_ds[9]["images"].shape[0] == 8
    trainer.fit()
    hist = [json.loads(s) for s in (tmp_path / "run" / "metrics.jsonl").read_text().splitlines()]
    assert hist[-1]["loss"]["sup"] < 0.8 * hist[0]["loss"]["sup"]
    assert json.loads((tmp_path / "run" / "last.json").read_text())["train_config"]["prefix_frames"] == 4


def test_warm_up_frames_need_a_memory_and_a_count_of_at_least_zero(tmp_path):
    with pytest.raises(InputError, match="--prefix-frames needs a sequence variant"):
        Trainer(tiny("racklay"), TrainConfig(prefix_frames=2, threads=1), seqs(), seqs(), tmp_path / "r")
    with pytest.raises(InputError, match="--prefix-frames must be >= 0"):
        TrainConfig(prefix_frames=-1).validate()
