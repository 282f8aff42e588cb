"""Rasterise metric rectangles into a layout slot (used to make ground truth).

Coverage rule: a pixel takes the value when its *centre* lies inside the rectangle, with the
rectangle treated as half-open (``lo <= p < hi`` in its own axes). So two rectangles that share
an edge never both claim a pixel, a rectangle narrower than a pixel may claim none, and the
painted area converges to the true area as D grows. Later calls paint over earlier ones.
"""

from __future__ import annotations

import math

import numpy as np

from layouts.errors import LayoutError
from layouts.spec import LayoutSpec, check_view


def fill_rect(
    slot: np.ndarray,
    spec: LayoutSpec,
    view: str,
    centre: tuple[float, float],
    size: tuple[float, float],
    value: int,
    yaw: float = 0.0,
) -> int:
    """Paint ``value`` into ``slot`` (D, D) where pixel centres fall inside a metric rectangle.

    ``centre`` is ``(x, a)`` and ``size`` is ``(extent along x, extent along a)`` in metres, where
    ``a`` is Z for the top view and the height above the board for the front view. ``yaw``
    (radians) turns the rectangle about its centre: its width axis is ``(cos yaw, sin yaw)``
    in ``(x, a)`` coordinates. Returns the number of pixels painted.
    """
    check_view(view)
    if slot.shape != (spec.size, spec.size):
        raise LayoutError(f"slot must have shape {(spec.size, spec.size)}, got {slot.shape}")
    w, l = float(size[0]), float(size[1])
    if not (math.isfinite(w) and math.isfinite(l)) or w < 0 or l < 0:
        raise LayoutError(f"rectangle size must be finite and >= 0, got {size}")
    cx, ca = float(centre[0]), float(centre[1])
    c, s = math.cos(yaw), math.sin(yaw)
    # Metric half-extents of the rotated rectangle's bounding box.
    hx = 0.5 * (abs(c) * w + abs(s) * l)
    ha = 0.5 * (abs(s) * w + abs(c) * l)
    u0, u1 = spec.x_to_col(cx - hx), spec.x_to_col(cx + hx)
    # Row axis runs opposite to the metric axis (row 0 = max a).
    v0, v1 = spec.a_to_row(view, ca + ha), spec.a_to_row(view, ca - ha)
    c0, c1 = max(int(math.floor(u0 - 0.5)), 0), min(int(math.ceil(u1 + 0.5)), spec.size)
    r0, r1 = max(int(math.floor(v0 - 0.5)), 0), min(int(math.ceil(v1 + 0.5)), spec.size)
    if c0 >= c1 or r0 >= r1:
        return 0
    xs = spec.col_to_x(np.arange(c0, c1) + 0.5) - cx
    as_ = spec.row_to_a(view, np.arange(r0, r1) + 0.5) - ca
    if yaw == 0.0:
        inx = (xs >= -w / 2) & (xs < w / 2)
        ina = (as_ >= -l / 2) & (as_ < l / 2)
        mask = ina[:, None] & inx[None, :]
    else:
        X = xs[None, :]
        A = as_[:, None]
        p = c * X + s * A  # coordinate along the rectangle's width axis
        q = -s * X + c * A  # coordinate along its length axis
        mask = (p >= -w / 2) & (p < w / 2) & (q >= -l / 2) & (q < l / 2)
    slot[r0:r1, c0:c1][mask] = value
    return int(mask.sum())


def rect_area_pixels(spec: LayoutSpec, view: str, size: tuple[float, float]) -> float:
    """Expected pixel count of a rectangle of metric ``size`` (for sanity checks and tests)."""
    px, pa = spec.pixel_size(view)
    return size[0] * size[1] / (px * pa)
