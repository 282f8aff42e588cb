"""`supervised_loss`'s per-column weights, and which box stacks a frame has shown the depth of
(`waresynth.visibility`, what the box-depth head's shown targets come from)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from layouts import LayoutSpec
from network.training.losses import supervised_loss
from waresynth.visibility import scene_stacks, seen_stacks, stack_columns


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
