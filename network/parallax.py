"""Depth behind the rack front from the parallax between two frames of the row (a plane sweep).

The camera moves along the row (X) at a constant height, so two canonical images
(`layouts.canonical.CanonicalView`) form a rectified stereo pair: a point ``z`` metres behind the
rack front plane, seen from a camera ``d`` metres in front of it, moves by ``rho * dx`` (rho =
``d / (d + z)``) when the camera moves by ``dx``, while everything on the front plane moves by the
full ``dx`` (whatever the camera, since canonical pixels have a fixed size on that plane). So the
frame before, shifted by ``rho * dx`` for a few ratios rho, matches the current frame where the
scene lies at the matching depth: a box's side face and top running back, the back uprights and
board edges, the back wall. `plane_sweep` returns those matching costs (a cost volume, one map per
ratio); `ParallaxNet` turns them into features for the top view's depth rows
(`network.model.SlotHeads`), the one thing a single frame shows only through faces a few pixels tall.

``dx`` comes from `network.motion.camera_shift` (the images alone) or from the caller (odometry).
A frame without a predecessor (a sequence start) has ``dx = 0``: every ratio matches equally and
the cost volume is zero, so the features carry nothing, as for a camera that does not move.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from layouts.canonical import CanonicalView

#: ``d / (d + z)`` of the swept planes: at d = 2.5 m, z from 1.35 m behind the front to 0.5 m in front; ratios
#: above 1 also take up an error of the image motion estimate (`network.motion`)
RATIOS = (1.25, 1.2, 1.15, 1.1, 1.05, 1.0, 0.95, 0.9, 0.85, 0.8, 0.75, 0.7, 0.65)


def plane_sweep(cur: torch.Tensor, prev: torch.Tensor, dx: torch.Tensor, view: CanonicalView) -> torch.Tensor:
    """Matching cost ``(N, K, H, W)`` of frames ``cur`` against ``prev`` (``(N, 3, H, W)``) per swept plane.

    ``dx`` ``(N,)``: the camera's step from ``prev`` to ``cur`` (metres, + = toward +X). Cost is
    the mean absolute colour difference after shifting ``prev`` by ``rho * dx``, averaged over 3x3.
    """
    n, c, h, w = cur.shape
    k = len(RATIOS)
    rho = torch.tensor(RATIOS, device=cur.device, dtype=torch.float32)
    shift = (dx.float()[:, None] * rho[None, :] / view.metres_per_pixel).reshape(-1)  # (N*K,) pixels
    theta = torch.zeros(n * k, 2, 3, device=cur.device, dtype=torch.float32)
    theta[:, 0, 0] = 1.0
    theta[:, 1, 1] = 1.0
    theta[:, 0, 2] = 2.0 * shift / w  # sample prev at x + shift: a point on that plane lands there
    grid = F.affine_grid(theta, [n * k, c, h, w], align_corners=False).to(prev.dtype)
    src = prev.repeat_interleave(k, 0)
    warped = F.grid_sample(src, grid, mode="bilinear", padding_mode="border", align_corners=False)
    cost = (warped.view(n, k, c, h, w) - cur[:, None]).abs().mean(2)
    return F.avg_pool2d(cost, 3, 1, 1, count_include_pad=False)


def relative_costs(cost: torch.Tensor) -> torch.Tensor:
    """``(N, K, H, W)`` costs -> ``(N, K + 1, H, W)``: each plane's cost relative to the mean over the
    planes (which plane matches best) and that mean (how much texture there is to match), x10 (unit scale)."""
    mean = cost.mean(1, keepdim=True)
    return torch.cat([cost - mean, mean], 1) * 10.0


class ParallaxNet(nn.Module):
    """Cost volume -> ``channels`` feature maps at half the image's resolution (the 1/2 map's grid).

    Input: `relative_costs` of the volume (which plane matches best, and how much texture there is
    to match), scaled for the first batch norm.
    """

    def __init__(self, channels: int = 16) -> None:
        super().__init__()
        k = len(RATIOS)
        self.channels = channels
        self.net = nn.Sequential(
            nn.Conv2d(k + 1, channels, 3, padding=1, bias=False),
            nn.BatchNorm2d(channels),
            nn.ReLU(True),
            nn.Conv2d(channels, channels, 3, stride=2, padding=1, bias=False),
            nn.BatchNorm2d(channels),
            nn.ReLU(True),
            nn.Conv2d(channels, channels, 3, padding=1, bias=False),
            nn.BatchNorm2d(channels),
            nn.ReLU(True),
        )

    def forward(self, cost: torch.Tensor) -> torch.Tensor:
        return self.net(relative_costs(cost))
