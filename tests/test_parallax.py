"""The plane sweep (depth from the parallax between two frames) and the model's parallax branch."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from tiny_net import cached_and_naive_windows, tiny_config

from layouts import InputError, LayoutSpec
from layouts.canonical import CanonicalView
from network.heads.parallax import RATIOS, ParallaxNet, box_mean3, plane_sweep, shifted_costs
from network.model.net import ModelConfig, MVRackLay

SPEC = LayoutSpec(num_slots=2, size=16)
VIEW = CanonicalView(64, 32, 3.0)
ANCHORS = torch.tensor([52.0, 30.0])


def tiny(parallax: bool = True, variant: str = "mvracklay-disc-4") -> ModelConfig:
    return tiny_config(SPEC, variant, parallax=parallax)


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
    net = ParallaxNet(8).eval()
    other = plane_sweep(cur.flip(-1), cur.flip(-1), torch.zeros(1), VIEW)
    with torch.no_grad():
        torch.testing.assert_close(net(cost), net(other))


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


def test_parallax_needs_a_sequence_variant_and_round_trips():
    with pytest.raises(InputError, match="parallax needs a sequence variant"):
        tiny(variant="racklay")
    cfg = tiny()
    assert ModelConfig.from_dict(cfg.to_dict()) == cfg
    d = cfg.to_dict()
    del d["parallax"]  # written before the option: off
    assert ModelConfig.from_dict(d).parallax is False


def test_streaming_equals_the_window_and_a_fresh_branch_changes_nothing():
    torch.manual_seed(3)
    model = MVRackLay(tiny()).eval()
    plain = MVRackLay(tiny(parallax=False)).eval()
    missing, unexpected = model.load_state_dict(plain.state_dict(), strict=False)
    assert not unexpected and all(k.startswith(("parallax.", "slots.par_")) for k in missing)
    base = torch.rand(1, 3, 64, 96)
    x = torch.stack([base[..., 4 * t : 4 * t + 64] for t in range(5)], 1)  # a camera moving along the row
    a = ANCHORS.expand(1, 5, 2)
    with torch.no_grad():
        torch.testing.assert_close(model(x, a)["top"], plain(x, a)["top"])  # zero-initialised: the warm start
        torch.nn.init.normal_(model.slots.par_out.weight, std=5.0)  # make the (untrained) branch count
        full = model(x, a)
        assert not torch.allclose(full["top"][:, 1:], plain(x, a)["top"][:, 1:], atol=1e-4)
        torch.testing.assert_close(full["top"][:, 0], plain(x, a)["top"][:, 0])  # no frame before: nothing
        state = None
        for t in range(5):
            out, state = model.step(x[:, t], state, ANCHORS[None])
            torch.testing.assert_close(out["top"], full["top"][:, t], rtol=1e-4, atol=1e-5)
        # the first frame of a window sees the one before it when given
        later = model(x[:, 1:], a[:, 1:], before=x[:, 0])
        torch.testing.assert_close(later["top"][:, 0], full["top"][:, 1], rtol=1e-4, atol=1e-5)


def test_windowed_prediction_with_parallax_matches_the_naive_form():
    torch.manual_seed(4)
    model = MVRackLay(tiny()).eval()
    torch.nn.init.normal_(model.slots.par_out.weight, std=0.5)
    _, _, cached, naive = cached_and_naive_windows(model, SPEC)
    for t in range(6):
        torch.testing.assert_close(cached[t]["top"], naive[t]["top"], rtol=1e-4, atol=1e-5)
    assert np.isfinite(cached[5]["top"].numpy()).all()
