"""`network.fastops`: the torch ops' values bit for bit, and their gradients."""

from __future__ import annotations

import pytest
import torch
import torch.nn.functional as F

from network.fastops import avg_pool2, mean_row_pairs, up2


@pytest.mark.parametrize("shape", [(3, 32, 32, 32), (2, 5, 33, 17), (1, 1, 2, 2), (1, 13, 64, 64)])
def test_the_same_values_as_the_torch_ops(shape):
    x = torch.randn(*shape, generator=torch.Generator().manual_seed(sum(shape))) * 7
    assert torch.equal(up2(x), F.interpolate(x, scale_factor=2.0, mode="nearest"))
    assert torch.equal(avg_pool2(x), F.avg_pool2d(x, 2))
    even = x[..., : shape[2] // 2 * 2, :]
    assert torch.equal(mean_row_pairs(even), F.adaptive_avg_pool2d(even, (shape[2] // 2, shape[3])))


def test_the_same_gradients_as_the_torch_ops():
    x = torch.randn(2, 3, 9, 8, requires_grad=True)
    pairs = [
        (up2, lambda t: F.interpolate(t, scale_factor=2.0, mode="nearest")),
        (avg_pool2, lambda t: F.avg_pool2d(t, 2)),
        (lambda t: mean_row_pairs(t[..., :8, :]), lambda t: F.adaptive_avg_pool2d(t[..., :8, :], (4, 8))),
    ]
    for ours, theirs in pairs:
        w = torch.randn(theirs(x).shape)  # a loss that weighs every output differently
        a = torch.autograd.grad((ours(x) * w).sum(), x)[0]
        b = torch.autograd.grad((theirs(x) * w).sum(), x)[0]
        torch.testing.assert_close(a, b)
