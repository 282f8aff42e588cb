"""Losses and data: consistency under the known camera motion, resampling, consistent flips."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from layouts import BOX, SHELF, InputError, LayoutSpec
from network.data import WindowDataset, resample_columns, resample_layout
from network.training.losses import column_shifts, consistency_loss, lsgan_discriminator_loss, supervised_loss
from network.training.toy import ToySequence

SPEC = LayoutSpec(num_slots=2, size=16)


def _perfect_logits(batch, view):
    onehot = torch.nn.functional.one_hot(batch[view], 3).movedim(-1, -3).float()
    return onehot * 20.0


def _window(step_cols: int, augment: bool, idx: int = 5):
    seq = ToySequence(SPEC, num_frames=8, step_cols=step_cols, seed=3)
    ds = WindowDataset([seq], seq_len=4, input_size=(64, 64), spec=SPEC, augment=augment, seed=0)
    item = ds[idx]
    return {k: (v[None] if isinstance(v, torch.Tensor) else v) for k, v in item.items()}


def test_consistency_is_zero_for_ground_truth_and_catches_a_wrong_shift():
    for step in (2, -3):
        b = _window(step, augment=False)
        assert column_shifts(b["cam_x"], SPEC, 0, 1).item() == step
        for view in ("top", "front"):
            logits = _perfect_logits(b, view)
            for long_range in (False, True):
                assert consistency_loss(logits, b["cam_x"], b["visible"], SPEC, long_range=long_range) < 1e-6
            wrong = consistency_loss(logits, -b["cam_x"], b["visible"], SPEC, long_range=False)
            assert wrong > 0.01


def test_flip_augmentation_keeps_images_layouts_and_motion_consistent():
    flipped_seen = False
    for idx in range(4, 8):
        b = _window(2, augment=True, idx=idx)
        flipped_seen |= bool(b["flipped"])
        logits = _perfect_logits(b, "top")
        assert consistency_loss(logits, b["cam_x"], b["visible"], SPEC, long_range=True) < 1e-6
    assert flipped_seen
    # The flip mirrors image and layout together: the image's left edge shows the layout's column 0.
    seq = ToySequence(SPEC, num_frames=8, step_cols=2, seed=3)
    ds = WindowDataset([seq], seq_len=1, input_size=(64, 64), spec=SPEC, augment=False)
    item = ds[0]
    assert item["images"].shape == (1, 3, 64, 64)
    assert item["top"].shape == (1, 2, 16, 16) and item["visible"].shape == (1, 16)


def test_window_repeats_the_first_frame_at_the_start():
    seq = ToySequence(SPEC, num_frames=8)
    ds = WindowDataset([seq], seq_len=4, input_size=(64, 64), spec=SPEC)
    assert ds.frame_ids(0) == [0, 0, 0, 0]
    assert ds.frame_ids(2) == [0, 0, 1, 2]
    assert ds.frame_ids(7) == [4, 5, 6, 7]
    assert ds.frame_ids(7, stride=2) == [1, 3, 5, 7]
    assert ds.frame_ids(3, stride=3) == [0, 0, 0, 3]


def test_strided_training_windows_draw_strides_up_to_the_maximum():
    seq = ToySequence(SPEC, num_frames=30, step_cols=1)
    ds = WindowDataset([seq], seq_len=3, input_size=(64, 64), spec=SPEC, augment=True, max_stride=3)
    px = SPEC.x_extent / SPEC.size
    strides = set()
    for idx in range(12, 30):
        steps = np.abs(np.diff(ds[idx]["cam_x"].numpy())) / px  # the toy camera moves one column per frame
        assert np.allclose(steps, steps[0], atol=1e-3)
        strides.add(round(float(steps[0])))
    assert strides == {1, 2, 3}
    plain = WindowDataset([seq], seq_len=3, input_size=(64, 64), spec=SPEC, augment=False, max_stride=3)
    assert np.allclose(np.abs(np.diff(plain[20]["cam_x"].numpy())) / px, 1.0)  # evaluation keeps consecutive frames
    with pytest.raises(InputError, match="max_stride"):
        WindowDataset([seq], seq_len=3, input_size=(64, 64), spec=SPEC, max_stride=0)


def test_resample_layout_takes_the_majority_class_and_prefers_boxes_on_ties():
    a = np.zeros((1, 4, 4), np.uint8)
    a[0, :2, :2] = [[BOX, BOX], [BOX, SHELF]]
    a[0, :2, 2:] = [[SHELF, SHELF], [BOX, BOX]]
    out = resample_layout(a, 2)
    assert out.tolist() == [[[BOX, BOX], [0, 0]]]
    up = resample_layout(out, 4)
    assert up.shape == (1, 4, 4) and up[0, 0, 3] == BOX
    assert resample_columns(np.array([True, True, False, True]), 2).tolist() == [True, False]
    assert resample_columns(np.array([True, False]), 4).tolist() == [True, True, False, False]


def test_supervised_and_lsgan_losses_behave():
    target = torch.randint(0, 3, (1, 2, 2, 8, 8))
    good = torch.nn.functional.one_hot(target, 3).movedim(-1, -3).float() * 10
    bad = torch.zeros_like(good)
    assert supervised_loss(good, target, dice_weight=0.5) < supervised_loss(bad, target, dice_weight=0.5)
    w = torch.tensor([1.0, 1.0, 3.0])
    assert torch.isfinite(supervised_loss(bad, target, w, 0.5))
    assert lsgan_discriminator_loss(torch.ones(3), torch.zeros(3)) == 0
