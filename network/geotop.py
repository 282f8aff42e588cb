"""Geometric top view: image features lifted onto the top view's cells by projecting 3D points.

The top view's column transform (`network.model.ColumnTransform`) maps each canonical column's
band of rows to depth rows and never mixes columns. A side face of a box, seen off the optical
axis, and the back edges of a rack lie in *other* image columns than the front face above them:
a point ``Z`` metres behind the rack front at lateral ``X`` lands at ``X * rho`` with
``rho = d / (d + Z)`` (d: camera to rack front). This branch samples, for every top-view cell
(X, Z) of a slot and a few heights h above its board, the feature at the canonical pixel where the
3D point (X, board + h, Z) projects, as an orthographic feature transform does, so that the
top view's convolutions see what lies over each cell wherever the perspective put it.

Canonical geometry (`layouts.canonical`): square pixels of ``m`` metres on the rack front plane,
centred on the optical axis, so a point at lateral X and height ``y`` above the camera, ``Z``
behind the front plane, projects at column ``W/2 + X rho / m`` and row ``H/2 - y rho / m``. The
slot's anchor row ``a`` (its board's front edge, on the front plane) gives the board's height over
the camera, ``(H/2 - a) m``. The model is not told d or the rack depth: the nominal values below
place the samples (the generator draws d in 2.3-2.9 m and racks 0.8-1.2 m deep; 0.3 m of error in
d moves a sample by ~1 % of its offset from the axis), and the convolutions that follow absorb the
rest.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import nn

from layouts.canonical import CanonicalView
from layouts.spec import LayoutSpec

#: camera-to-rack-front distance (metres) and rack depth the samples assume
NOMINAL_DISTANCE = 2.6
NOMINAL_RACK_DEPTH = 1.0
#: heights above the board sampled per cell, as fractions of the front window (`LayoutSpec.h_extent`)
HEIGHT_FRACTIONS = (0.02, 0.1, 0.2, 0.3, 0.42, 0.56, 0.72)


def top_view_grid(
    anchors: torch.Tensor,
    view: CanonicalView,
    spec: LayoutSpec,
    cells: int,
    heights: torch.Tensor,
    distance: float = NOMINAL_DISTANCE,
    rack_depth: float = NOMINAL_RACK_DEPTH,
) -> torch.Tensor:
    """``grid_sample`` coordinates ``(N, R * K, cells * cells, 2)`` of every slot's ``cells x cells``
    top-view cells (row 0 = far side, as the layouts) at the ``K`` heights (metres above the board).

    ``anchors`` ``(N, R)``: the slots' board rows in canonical pixels (finite). Row-major cells;
    the K heights of slot r are the block ``r*K .. r*K + K - 1``.
    """
    n, r = anchors.shape
    dev, dt = anchors.device, anchors.dtype
    centres = (np.arange(cells) + 0.5) * (spec.size / cells)  # coarse cell centres in layout pixels
    x = torch.as_tensor(spec.col_to_x(centres), device=dev, dtype=dt)  # (cells,) lateral, column 0 at -X
    z = torch.as_tensor(spec.row_to_a("top", centres), device=dev, dtype=dt)  # about mid-depth, row 0 far
    behind = (z + rack_depth / 2).clamp(min=-0.5 * distance)  # metres behind the front plane
    rho = distance / (distance + behind)  # (cells,) per depth row
    m = view.metres_per_pixel
    h0, w0 = view.height / 2, view.width / 2
    col = w0 + x[None, :] * rho[:, None] / m  # (rows, cols)
    # height over the camera of the point: board height over the camera plus h
    over = (h0 - anchors)[:, :, None] * m + heights.to(dev, dt)[None, None, :]  # (N, R, K)
    row = h0 - over[..., None] * rho[None, None, None, :] / m  # (N, R, K, rows)
    gx = (col * (2.0 / view.width) - 1.0).expand(n, r, heights.numel(), cells, cells)
    gy = (row * (2.0 / view.height) - 1.0)[..., None].expand(n, r, heights.numel(), cells, cells)
    return torch.stack([gx, gy], -1).reshape(n, r * heights.numel(), cells * cells, 2)


class GeometricTop(nn.Module):
    """Top-view features from projected samples of a feature map; zero-initialised output, so a
    model warm-started without the branch computes what its source did."""

    def __init__(self, channels: int, out: int, view: CanonicalView, spec: LayoutSpec, cells: int) -> None:
        super().__init__()
        self.view, self.spec, self.cells = view, spec, cells
        self.register_buffer(
            "heights", torch.tensor(HEIGHT_FRACTIONS, dtype=torch.float32) * spec.h_extent, persistent=False
        )
        k = len(HEIGHT_FRACTIONS)
        self.mix = nn.Sequential(
            nn.Conv2d(channels * k, out, 1, bias=False),
            nn.BatchNorm2d(out),
            nn.ReLU(True),
            nn.Conv2d(out, out, 3, padding=1, bias=False),
            nn.BatchNorm2d(out),
            nn.ReLU(True),
        )
        self.out = nn.Conv2d(out, out, 1)
        nn.init.zeros_(self.out.weight)
        nn.init.zeros_(self.out.bias)

    def forward(self, fmap: torch.Tensor, anchors: torch.Tensor) -> torch.Tensor:
        """``fmap`` ``(N, C, h, w)``, anchors ``(N, R)`` (finite) -> ``(N*R, out, cells, cells)``."""
        n, r = anchors.shape
        c, s, k = fmap.shape[1], self.cells, self.heights.numel()
        grid = top_view_grid(anchors, self.view, self.spec, s, self.heights)
        v = nn.functional.grid_sample(
            fmap, grid.to(fmap.dtype), mode="bilinear", padding_mode="zeros", align_corners=False
        )
        # (N, C, R*K, s*s) -> (N*R, K*C, s, s)
        v = v.view(n, c, r, k, s, s).permute(0, 2, 3, 1, 4, 5).reshape(n * r, k * c, s, s)
        return self.out(self.mix(v))
