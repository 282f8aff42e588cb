"""A known rack depth imposed on predicted top views.

The top view's rows are centred on the rack's mid-depth (`layouts.spec`), so the rack front, and
every box standing at it, lies half the rack depth in front of the centre row. A model that reads
the rack depth a few centimetres wrong draws the footprint too shallow or too deep and moves the
boxes with its front edge. Racking depth is usually known (a spec sheet, one tape measure), so
`impose_rack_depth` redraws each slot's footprint rows from it and moves the predicted boxes by the
same amount as the front edge, keeping the predicted columns (where the shelf and boxes are along X)
and the boxes' own depths.
"""

from __future__ import annotations

import math

import numpy as np

from layouts.classes import BOX, SHELF
from layouts.errors import InputError
from layouts.raster import fill_rect
from layouts.spec import LayoutSpec


def check_rack_depth(depth: float, spec: LayoutSpec | None = None, name: str = "--rack-depth") -> float:
    """``depth`` as a float if it is a positive number of metres (and, given ``spec``, fits its top view),
    else a one-line `InputError`."""
    if isinstance(depth, bool) or not isinstance(depth, (int, float)) or not math.isfinite(depth) or depth <= 0:
        raise InputError(f"{name} must be a positive number of metres, got {depth!r}")
    if spec is not None and depth > spec.z_extent:
        raise InputError(f"{name} {depth} m exceeds the top view's {spec.z_extent} m depth extent")
    return float(depth)


def front_rows(mask: np.ndarray) -> np.ndarray:
    """Per column of a ``(D, D)`` mask with any cell set: its last row (the top view's front, nearest the camera)."""
    rows = np.arange(mask.shape[0])[:, None]
    return np.where(mask, rows, -1).max(0)[mask.any(0)]


def shift_rows(slot: np.ndarray, shift: int) -> np.ndarray:
    """``slot`` moved ``shift`` rows toward the last row (negative: toward row 0), zeros shifted in."""
    out = np.zeros_like(slot)
    d = slot.shape[0]
    src = slot[max(-shift, 0) : d - max(shift, 0)]
    out[max(shift, 0) : max(shift, 0) + src.shape[0]] = src
    return out


def depth_rows(spec: LayoutSpec, depth: float) -> np.ndarray:
    """Boolean ``(D,)``: the top-view rows a rack ``depth`` metres deep covers (the rasteriser's rule)."""
    band = np.zeros((spec.size, spec.size), np.uint8)
    fill_rect(band, spec, "top", (0.0, 0.0), (2 * spec.x_extent, depth), 1)
    return band.any(1)


def impose_rack_depth(top: np.ndarray, spec: LayoutSpec, depth: float) -> np.ndarray:
    """``top`` ``(R, D, D)`` class ids with each slot's footprint redrawn ``depth`` metres deep.

    Per slot with any footprint: the footprint's columns are kept and its rows become those of the
    known depth; the box cells move along the rows by the shift between the predicted front edge
    (median last footprint row over columns) and the known one, and are clipped to the footprint.
    """
    check_rack_depth(depth, spec, "rack depth")
    top = np.asarray(top)
    if top.ndim != 3 or top.shape[1:] != (spec.size, spec.size):
        raise InputError(f"top view must have shape (R, {spec.size}, {spec.size}), got {top.shape}")
    rows = depth_rows(spec, depth)
    near = int(np.nonzero(rows)[0].max())
    out = top.copy()
    for r in range(top.shape[0]):
        foot = top[r] > 0
        cols = foot.any(0)
        if not cols.any():
            continue
        boxes = shift_rows(top[r] == BOX, near - int(round(float(np.median(front_rows(foot))))))
        band = rows[:, None] & cols[None, :]
        out[r] = np.where(band, SHELF, 0).astype(top.dtype)
        out[r][band & boxes] = BOX
    return out
