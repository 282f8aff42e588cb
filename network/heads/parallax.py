"""Depth behind the rack front from the parallax between two frames of the row (a plane sweep).

The camera moves along the row (X) at a constant height, so two canonical images
(`layouts.canonical.CanonicalView`) form a rectified stereo pair: a point ``z`` metres behind the
rack front plane, seen from a camera ``d`` metres in front of it, moves by ``rho * dx`` (rho =
``d / (d + z)``) when the camera moves by ``dx``, while everything on the front plane moves by the
full ``dx`` (whatever the camera, since canonical pixels have a fixed size on that plane). So the
frame before, shifted by ``rho * dx`` for a few ratios rho, matches the current frame where the
scene lies at the matching depth: a box's side face and top running back, the back uprights and
board edges, the back wall. `plane_sweep` returns those matching costs (a cost volume, one map per
ratio), which the box-depth head reads (`network.heads.boxdepth.ParallaxHistory`, option ``box_parallax``):
a box's depth, which a single frame shows only through faces a few pixels tall.

``dx`` comes from `network.model.motion.camera_shift` (the images alone) or from the caller (odometry).
A frame without a predecessor (a sequence start) has ``dx = 0``: every ratio matches equally and
the cost volume is zero, so the features carry nothing, as for a camera that does not move.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from layouts.canonical import CanonicalView
from network.fastops import avg_pool2

#: ``d / (d + z)`` of the swept planes: at d = 2.5 m, z from 1.35 m behind the front to 0.5 m in front; ratios
#: above 1 also take up an error of the image motion estimate (`network.model.motion`)
RATIOS = (1.25, 1.2, 1.15, 1.1, 1.05, 1.0, 0.95, 0.9, 0.85, 0.8, 0.75, 0.7, 0.65)


def plane_sweep(cur: torch.Tensor, prev: torch.Tensor, dx: torch.Tensor, view: CanonicalView) -> torch.Tensor:
    """Matching cost ``(N, K, H, W)`` of frames ``cur`` against ``prev`` (``(N, 3, H, W)``) per swept plane.

    ``dx`` ``(N,)``: the camera's step from ``prev`` to ``cur`` (metres, + = toward +X). Cost is
    the mean absolute colour difference after shifting ``prev`` by ``rho * dx``, averaged over 3x3.
    """
    return box_mean3(shifted_costs(cur, prev, _plane_shifts(dx, view, cur.device)))


def _plane_shifts(dx: torch.Tensor, view: CanonicalView, device: torch.device) -> torch.Tensor:
    """``(N, K)`` pixels each swept plane moves by for camera steps ``dx`` ``(N,)`` (metres): ``rho * dx``."""
    rho = torch.tensor(RATIOS, device=device, dtype=torch.float32)
    return dx.float().to(device)[:, None] * rho[None, :] / view.metres_per_pixel


def shifted_costs(cur: torch.Tensor, prev: torch.Tensor, shift: torch.Tensor) -> torch.Tensor:
    """Mean absolute colour difference ``(N, K, H, W)`` between ``cur`` and ``prev`` (``(N, C, H, W)``)
    sampled at ``x + shift`` for each of ``shift`` ``(N, K)`` (pixels): linear between the two nearest
    columns, clamped at the edges.

    The same as `grid_sample` (bilinear, border padding) with a pure X translation, without its cost:
    one shift per plane, so each plane is two column-shifted views of ``prev`` padded at its edges
    (a shift past the image's width samples the edge column everywhere, as a width's shift does)."""
    return _summed_costs(cur, prev, shift) / prev.shape[1]


def _summed_costs(cur: torch.Tensor, prev: torch.Tensor, shift: torch.Tensor) -> torch.Tensor:
    """`shifted_costs` times the channels (the channels' sum, not their mean), each plane in one buffer."""
    n, c, h, w = prev.shape
    shift = shift.float().clamp(-w, w)
    whole = torch.floor(shift)
    frac, whole = (shift - whole).tolist(), whole.long().tolist()
    pad = max((abs(v) for row in whole for v in row), default=0) + 1
    padded = F.pad(prev, (pad, pad, 0, 0), mode="replicate")
    out = cur.new_empty(n, shift.shape[1], h, w)
    buf = cur.new_empty(c, h, w)
    for i in range(n):
        for k, (o, f) in enumerate(zip(whole[i], frac[i])):
            o += pad
            torch.lerp(padded[i, :, :, o : o + w], padded[i, :, :, o + 1 : o + 1 + w], f, out=buf)
            buf.sub_(cur[i]).abs_()
            acc = torch.sum(buf[:1], 0, out=out[i, k]) if c == 1 else torch.add(buf[0], buf[1], out=out[i, k])
            for j in range(2, c):
                acc.add_(buf[j])
    return out


def pooled_sweep(cur: torch.Tensor, prev: torch.Tensor, dx: torch.Tensor, view: CanonicalView) -> torch.Tensor:
    """`plane_sweep`'s costs averaged over 2x2 cells ``(N, K, H/2, W/2)`` (`network.fastops.avg_pool2`), what the
    box-depth head reads, about twice as fast: the 3x3 mean and the 2x2 pooling are one separable filter per
    axis applied at half resolution, and the channels' mean is folded into its scale. Equal to the two steps
    up to float rounding; images of odd or tiny sizes take them one after the other."""
    h, w = cur.shape[-2:]
    if h % 2 or w % 2 or h < 4 or w < 4:
        return avg_pool2(plane_sweep(cur, prev, dx, view))
    summed = _summed_costs(cur, prev, _plane_shifts(dx, view, cur.device))
    return _pooled_box3(_pooled_box3(summed, -2), -1) / (4.0 * prev.shape[1])


def _pooled_box3(x: torch.Tensor, dim: int) -> torch.Tensor:
    """Along ``dim`` (-1 or -2, an even length >= 4): the sum over each pair of cells of their 3-cell means (the
    2 cells inside at either end), i.e. ``box_mean3`` then twice ``avg_pool2`` along that axis. Inside, a pair
    (2i, 2i+1) weighs cells 2i-1..2i+2 by 1, 2, 2, 1 over 3; the end pairs add a sixth of their own sum."""
    ev, od = x.narrow(dim, 0, x.shape[dim] // 2 * 2).unflatten(dim, (-1, 2)).unbind(dim)
    pair = ev + od
    out = pair * 2.0
    n = pair.shape[dim]
    out.narrow(dim, 1, n - 1).add_(od.narrow(dim, 0, n - 1))
    out.narrow(dim, 0, n - 1).add_(ev.narrow(dim, 1, n - 1))
    out.div_(3.0)
    for end in (0, n - 1):
        out.narrow(dim, end, 1).add_(pair.narrow(dim, end, 1) / 6.0)
    return out


def box_mean3(x: torch.Tensor) -> torch.Tensor:
    """Mean over each cell's 3x3 neighbourhood (last two dims), at the edges over the cells inside:
    `avg_pool2d(x, 3, 1, 1, count_include_pad=False)`, as shifted sums (several times faster on CPUs)."""
    h, w = x.shape[-2:]
    s = x.clone()
    s[..., 1:] += x[..., :-1]
    s[..., :-1] += x[..., 1:]
    t = s.clone()
    t[..., 1:, :] += s[..., :-1, :]
    t[..., :-1, :] += s[..., 1:, :]
    return t / (_box_counts(h, x)[:, None] * _box_counts(w, x)[None, :])


def _box_counts(m: int, like: torch.Tensor) -> torch.Tensor:
    """Cells of a 3-wide window inside a line of ``m``: 3, and 2 at each end (1 for a single cell)."""
    counts = torch.full((m,), 3.0 if m > 1 else 1.0, dtype=like.dtype, device=like.device)
    if m > 1:
        counts[0] = counts[-1] = 2.0
    return counts


def relative_costs(cost: torch.Tensor) -> torch.Tensor:
    """``(N, K, H, W)`` costs -> ``(N, K + 1, H, W)``: each plane's cost relative to the mean over the
    planes (which plane matches best) and that mean (how much texture there is to match), x10 (unit scale)."""
    mean = cost.mean(1, keepdim=True)
    return torch.cat([cost - mean, mean], 1) * 10.0
