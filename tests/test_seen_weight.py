"""Loss weighting toward the stacks whose depth a window has shown (`--seen-weight`)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from layouts import BOX, InputError, LayoutSpec
from network.data import WindowDataset
from network.training.losses import supervised_loss
from network.training.toy import ToySequence
from waresynth.dataset import open_dataset
from waresynth.visibility import scene_stacks, seen_stacks, stack_columns

SPEC16 = LayoutSpec(size=16)


def test_column_weights_of_one_give_the_plain_loss_and_weights_move_the_gradient():
    torch.manual_seed(0)
    logits = torch.randn(2, 3, 2, 3, 8, 8, requires_grad=True)
    target = torch.randint(0, 3, (2, 3, 2, 8, 8))
    valid = torch.ones(2, 3, 2, dtype=torch.bool)
    valid[1, 2, 1] = False
    cw = torch.tensor([1.0, 1.0, 2.0])
    plain = supervised_loss(logits, target, cw, 0.5, valid)
    ones = supervised_loss(logits, target, cw, 0.5, valid, torch.ones(2, 3, 2, 8))
    assert torch.allclose(plain, ones, atol=1e-6)
    w = torch.ones(2, 3, 2, 8)
    w[..., :4] = 0.0  # only the right half of every layout counts
    (g,) = torch.autograd.grad(supervised_loss(logits, target, cw, 0.0, valid, w), logits)
    assert g[..., :4].abs().max() == 0 and g[..., 4:].abs().max() > 0
    half = supervised_loss(logits[..., 4:], target[..., 4:], cw, 0.0, valid)
    assert torch.allclose(supervised_loss(logits, target, cw, 0.0, valid, w), half, atol=1e-6)


def test_a_stack_counts_as_seen_only_when_its_pixels_reach_its_back():
    scene = {
        "racks": [
            {
                "shelves": [
                    {
                        "boxes": [
                            {
                                "stack_id": "a",
                                "center": [0.2, 1.0, 0.5],
                                "yaw": 0.0,
                                "size": [0.4, 0.3, 0.6],
                                "instance_id": 5,
                            },
                            {
                                "stack_id": "a",
                                "center": [0.2, 1.3, 0.5],
                                "yaw": 0.0,
                                "size": [0.4, 0.3, 0.6],
                                "instance_id": 6,
                            },
                        ]
                    }
                ]
            }  # fmt: skip
        ]
    }
    (st,) = scene_stacks(scene)
    assert st["level"] == 0 and st["ids"].tolist() == [5, 6]
    assert st["hx"] == pytest.approx(0.2) and st["hz"] == pytest.approx(0.3)
    cam_z = -2.0  # front face at z = 0.2: 2.2 m away, back face at 2.8 m
    instance = np.zeros((4, 4), np.int32)
    instance[1:3, 1:3] = 6
    depth = np.full((4, 4), 2.2, np.float32)
    assert seen_stacks([st], depth, instance, cam_z) == set()  # only its front face shows
    depth[1, 1] = 2.75  # a top or side face reaching 92 % of the way back
    assert seen_stacks([st], depth, instance, cam_z) == {0}
    assert seen_stacks([st], depth, instance, cam_z, candidates=[]) == set()
    spec = LayoutSpec(size=30)  # 10 cm columns over 3 m: the stack covers x = 0.0..0.4 -> columns 15..18
    assert stack_columns(st, spec, cam_x=0.0) == (15, 19)
    assert stack_columns(st, spec, cam_x=0.2) == (13, 17)
    assert stack_columns(st, spec, cam_x=5.0) == (0, 0)


def _dataset(root: Path, **kw) -> WindowDataset:
    seqs = open_dataset(root).sequences()
    return WindowDataset(seqs, seq_len=4, input_size=(64, 64), spec=SPEC16, augment=True, max_stride=2, **kw)


def test_windows_weight_the_box_columns_whose_depth_was_seen_so_far(tiny_dataset: Path):
    ds = _dataset(tiny_dataset, seen_weight=3.0)
    assert "top_weight" not in _dataset(tiny_dataset)[0]
    weighted = flips = 0
    for idx in range(len(ds)):
        item = ds[idx]
        w = item["top_weight"]
        assert w.shape == (4, SPEC16.num_slots, SPEC16.size) and set(w.unique().tolist()) <= {1.0, 4.0}
        heavy = (w > 1).numpy()
        box_cols = (item["top"].numpy() == BOX).any(-2)
        # weighted columns hold a box of that slot in that frame, flipped or not
        assert not (heavy & ~box_cols).any(), idx
        weighted += int(heavy.sum())
        flips += bool(item["flipped"])
    assert weighted > 0 and 0 < flips < len(ds)
    # what an earlier frame of the window showed stays weighted: the window's columns contain the frame's own
    seq = ds.sequences[0]
    for t in range(3, seq.num_frames):
        ids = ds.frame_ids(t)
        assert (ds._seen_columns(0, ids)[-1] >= ds._seen_columns(0, [t])[0]).all()


def test_seen_weight_needs_the_generator_files_and_a_valid_value():
    toy = ToySequence(SPEC16, num_frames=6)
    ds = WindowDataset([toy], seq_len=2, input_size=(64, 64), spec=SPEC16, seen_weight=1.0)
    with pytest.raises(InputError, match="--seen-weight needs"):
        ds[3]
    for bad in (-1.0, float("nan")):
        with pytest.raises(InputError, match="seen_weight"):
            WindowDataset([toy], seq_len=2, input_size=(64, 64), spec=SPEC16, seen_weight=bad)


def test_train_cli_trains_with_seen_weight_and_records_it(tiny_dataset: Path, tmp_path: Path):
    from tiny_net import TINY_NET

    from mvracklay.cli import main
    from network.checkpoint import load_checkpoint

    out = tmp_path / "run"
    args = ["train", "--data", str(tiny_dataset), "--out", str(out), "--epochs", "1", "--steps-per-epoch", "2"]
    assert main([*args, "--frames-per-step", "4", "--seen-weight", "2", *TINY_NET]) == 0
    _, record = load_checkpoint(out / "last.pt")
    assert record["train_config"]["seen_weight"] == 2.0
    assert main([*args, "--seen-weight", "-1", *TINY_NET]) == 2
