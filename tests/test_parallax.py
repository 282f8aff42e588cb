"""The plane sweep (depth from the parallax between two frames), which the box-depth head reads."""

from __future__ import annotations

import pytest
import torch
from tiny_net import tiny_config

from layouts import InputError, LayoutSpec
from layouts.canonical import CanonicalView
from network.heads.parallax import RATIOS, box_mean3, plane_sweep, relative_costs, shifted_costs
from network.model.config import RETIRED_FLAGS, ModelConfig

VIEW = CanonicalView(64, 32, 3.0)


def _texture(w: int = 96, seed: int = 0) -> torch.Tensor:
    """A random vertical-stripe texture ``(1, 3, 32, w)``: every column differs, rows repeat."""
    g = torch.Generator().manual_seed(seed)
    cols = torch.rand(1, 3, 1, w, generator=g)
    return cols.expand(1, 3, 32, w).contiguous()


def test_the_sweep_finds_each_region_at_its_depth():
    """Left half on the front plane (rho 1), right half 0.5 m behind it at d = 2 m (rho 0.8): a camera
    step of 5 pixels moves the first by 5 pixels and the second by 4, and the sweep says so."""
    m = VIEW.metres_per_pixel
    prev = _texture()
    near = torch.roll(prev, -5, dims=-1)[..., 16:80]  # cur(x) = prev(x + 5)
    far = torch.roll(prev, -4, dims=-1)[..., 16:80]  # cur(x) = prev(x + 4)
    cur = torch.cat([near[..., :32], far[..., 32:]], -1)
    cost = plane_sweep(cur, prev[..., 16:80], torch.tensor([5 * m]), VIEW)[0]  # (K, H, W)
    best = torch.tensor(RATIOS)[cost.argmin(0)]  # (H, W)
    assert cost.shape == (len(RATIOS), 32, 64)
    assert (best[:, 4:28] == 1.0).float().mean() > 0.95
    assert (best[:, 36:60] == 0.8).float().mean() > 0.95
    # the opposite motion finds neither
    rev = plane_sweep(cur, prev[..., 16:80], torch.tensor([-5 * m]), VIEW)[0]
    assert (torch.tensor(RATIOS)[rev.argmin(0)][:, 4:28] == 1.0).float().mean() < 0.5


def test_a_camera_that_does_not_move_gives_no_information():
    cur = _texture()[..., :64]
    cost = plane_sweep(cur, cur, torch.zeros(1), VIEW)
    assert float(cost.abs().max()) < 1e-5  # bilinear resampling at the pixel centres, up to rounding
    rel = relative_costs(cost)  # what the head reads: every plane matches as well as any other
    assert rel.shape == (1, len(RATIOS) + 1, 32, 64) and float(rel.abs().max()) < 1e-4


def test_the_fast_shift_and_box_mean_equal_grid_sample_and_avg_pool():
    """`shifted_costs` samples at x + shift bilinearly with the border clamped (what `grid_sample` does
    with a pure X translation), whole and fractional shifts, in range and past either edge; `box_mean3` is a
    3x3 average that counts only the cells inside, down to a single row or column."""
    g = torch.Generator().manual_seed(1)
    src = torch.rand(2, 3, 5, 11, generator=g)
    shift = torch.tensor([[0.0, 2.5, -3.25, 14.0], [-0.75, 1.0, 9.6, -20.0]])
    theta = torch.zeros(8, 2, 3)
    theta[:, 0, 0] = theta[:, 1, 1] = 1.0
    theta[:, 0, 2] = 2.0 * shift.reshape(-1) / 11
    grid = torch.nn.functional.affine_grid(theta, [8, 3, 5, 11], align_corners=False)
    ref = torch.nn.functional.grid_sample(
        src.repeat_interleave(4, 0), grid, mode="bilinear", padding_mode="border", align_corners=False
    )
    cur = torch.rand(2, 3, 5, 11, generator=g)
    want = (ref.view(2, 4, 3, 5, 11) - cur[:, None]).abs().mean(2)
    torch.testing.assert_close(shifted_costs(cur, src, shift), want, atol=1e-5, rtol=0)
    for shape in ((2, 3, 5, 11), (1, 1, 1, 7), (1, 2, 6, 1), (1, 1, 1, 1)):
        x = torch.rand(*shape, generator=g)
        want = torch.nn.functional.avg_pool2d(x, 3, 1, 1, count_include_pad=False)
        torch.testing.assert_close(box_mean3(x), want)


@pytest.mark.parametrize("name", RETIRED_FLAGS)
def test_a_record_naming_a_retired_option_loads_when_it_is_off_and_is_refused_when_on(name):
    """Records of earlier versions carry ``"parallax": false`` (and the other retired options): they load as
    before; one with the option on describes a model this version cannot build."""
    cfg = tiny_config(LayoutSpec(num_slots=2, size=16))
    assert ModelConfig.from_dict({**cfg.to_dict(), name: False}) == cfg
    with pytest.raises(InputError, match=f"'{name}' is on, an option this version no longer has"):
        ModelConfig.from_dict({**cfg.to_dict(), name: True}, "old.json")


@pytest.mark.parametrize("h, w", [(32, 64), (6, 10), (4, 4), (5, 8), (2, 6)])
def test_the_pooled_sweep_equals_the_sweep_then_avg_pool(h, w):
    """`pooled_sweep` (the 3x3 mean and the 2x2 pooling as one filter at half resolution) gives what the two
    steps give, edges included; odd or tiny sizes take the two steps."""
    from network.fastops import avg_pool2
    from network.heads.parallax import pooled_sweep

    g = torch.Generator().manual_seed(h * w)
    cur, prev = torch.rand(2, 1, 3, h, w, generator=g)
    m = VIEW.metres_per_pixel
    for dx in (0.0, 2.3 * m, -4.6 * m, 40 * m):
        want = avg_pool2(plane_sweep(cur, prev, torch.tensor([dx]), VIEW))
        got = pooled_sweep(cur, prev, torch.tensor([dx]), VIEW)
        assert got.shape == want.shape == (1, len(RATIOS), h // 2, w // 2)
        torch.testing.assert_close(got, want, atol=1e-6, rtol=1e-5)
