"""Geometric top view: image features lifted onto the top view's cells by projecting 3D points.

The top view's column transform (`network.model.net.ColumnTransform`) maps each canonical column's
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


def cell_projection(
    view: CanonicalView,
    spec: LayoutSpec,
    cells: int,
    distance: float = NOMINAL_DISTANCE,
    rack_depth: float = NOMINAL_RACK_DEPTH,
) -> tuple[torch.Tensor, torch.Tensor]:
    """The frame-independent part of the projection of ``cells x cells`` top-view cells (row 0 = far
    side, as the layouts): canonical columns ``(rows, cols)`` and the perspective ratio ``rho (rows,)``."""
    centres = (np.arange(cells) + 0.5) * (spec.size / cells)  # coarse cell centres in layout pixels
    x = torch.as_tensor(spec.col_to_x(centres))  # (cells,) lateral, column 0 at -X
    z = torch.as_tensor(spec.row_to_a("top", centres))  # about mid-depth, row 0 far
    behind = (z + rack_depth / 2).clamp(min=-0.5 * distance)  # metres behind the front plane
    rho = distance / (distance + behind)
    return view.width / 2 + x[None, :] * rho[:, None] / view.metres_per_pixel, rho


def grid_from_projection(
    anchors: torch.Tensor, view: CanonicalView, heights: torch.Tensor, col: torch.Tensor, rho: torch.Tensor
) -> torch.Tensor:
    """``grid_sample`` coordinates ``(N, R * K, rows * cols, 2)`` of the cells of `cell_projection`
    over each slot's board at the ``K`` heights (metres above it).

    ``anchors`` ``(N, R)``: the slots' board rows in canonical pixels (finite). Row-major cells;
    the K heights of slot r are the block ``r*K .. r*K + K - 1``.
    """
    n, r = anchors.shape
    k, (rows, cols) = heights.numel(), col.shape
    m, h0 = view.metres_per_pixel, view.height / 2
    # height over the camera of the point: board height over the camera plus h
    over = (h0 - anchors)[:, :, None] * m + heights.to(anchors)[None, None, :]  # (N, R, K)
    row = h0 - over[..., None] * rho.to(anchors)[None, None, None, :] / m  # (N, R, K, rows)
    gx = (col.to(anchors) * (2.0 / view.width) - 1.0).expand(n, r, k, rows, cols)
    gy = (row * (2.0 / view.height) - 1.0)[..., None].expand(n, r, k, rows, cols)
    return torch.stack([gx, gy], -1).reshape(n, r * k, rows * cols, 2)


def top_view_grid(
    anchors: torch.Tensor,
    view: CanonicalView,
    spec: LayoutSpec,
    cells: int,
    heights: torch.Tensor,
    distance: float = NOMINAL_DISTANCE,
    rack_depth: float = NOMINAL_RACK_DEPTH,
) -> torch.Tensor:
    """`grid_from_projection` of `cell_projection`: where every slot's cells at ``heights`` project."""
    col, rho = cell_projection(view, spec, cells, distance, rack_depth)
    return grid_from_projection(anchors, view, heights, col, rho)


class GeometricTop(nn.Module):
    """Top-view features from projected samples of a feature map; zero-initialised output, so a
    model warm-started without the branch computes what its source did."""

    def __init__(self, channels: int, out: int, view: CanonicalView, spec: LayoutSpec, cells: int) -> None:
        super().__init__()
        self.view, self.cells = view, cells
        self.register_buffer(
            "heights", torch.tensor(HEIGHT_FRACTIONS, dtype=torch.float32) * spec.h_extent, persistent=False
        )
        col, rho = cell_projection(view, spec, cells)  # fixed per model: computed once
        self.register_buffer("col", col.float(), persistent=False)
        self.register_buffer("rho", rho.float(), persistent=False)
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
        grid = grid_from_projection(anchors, self.view, self.heights, self.col, self.rho)
        v = nn.functional.grid_sample(
            fmap, grid.to(fmap.dtype), mode="bilinear", padding_mode="zeros", align_corners=False
        )
        # (N, C, R*K, s*s) -> (N*R, K*C, s, s)
        v = v.view(n, c, r, k, s, s).permute(0, 2, 3, 1, 4, 5).reshape(n * r, k * c, s, s)
        return self.out(self.mix(v))
