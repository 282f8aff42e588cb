"""Each predicted box's depth in the top view: its parts, and its back redrawn at a given depth.

A top-view box is a connected component of box cells in one slot; per layout column it spans from
a front to a back depth behind the rack front (the top view is centred on the rack's mid-depth, so
the rack ``depth`` places its rows, `layouts.spec`). `box_parts` lists the boxes a slot's top and
front views agree on; `redraw` moves a box's back per column; `impose_box_backs` gives every box of a
frame one back from per-column back depths read elsewhere (`network.heads.boxdepth`), boxes that touch side
by side told apart by their heights in the front view (`layouts.steps`).
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
from scipy.ndimage import find_objects
from skimage.measure import label

from layouts.classes import BOX, SHELF
from layouts.spec import LayoutSpec
from layouts.steps import MIN_BOX_WIDTH, SPLIT_STEP, pieces


def cell_z(spec: LayoutSpec, depth: float) -> np.ndarray:
    """``(D,)`` metres behind the rack front of the top view's row centres, the rack ``depth`` deep."""
    return spec.row_to_a("top", np.arange(spec.size) + 0.5) + depth / 2


def box_parts(
    top: np.ndarray, front: np.ndarray, spec: LayoutSpec, depth: float
) -> Iterator[tuple[np.ndarray, np.ndarray, np.ndarray, float]]:
    """Each box of a slot's top view ``(D, D)`` that the front view also shows (box cells in its columns):
    its columns, per-column front and back Z (metres behind the rack front) and its top height (metres)."""
    zc = cell_z(spec, depth)
    half = spec.z_extent / spec.size / 2
    lab = label(top == BOX, connectivity=1)
    front_box = front == BOX
    for k, (rs, cs) in enumerate(find_objects(lab), start=1):
        comp = lab[rs, cs] == k
        cols = np.arange(cs.start, cs.stop)  # a connected component has a cell in every column it spans
        fb = front_box[:, cs]
        shown = fb.any(0)
        if not shown.any():
            continue
        tops = fb.argmax(0)[shown]
        first = comp.argmax(0) + rs.start
        last = rs.stop - 1 - comp[::-1].argmax(0)
        yield cols, zc[last] - half, zc[first] + half, float(spec.row_to_a("front", np.median(tops)))


def redraw(
    top: np.ndarray, cols: np.ndarray, z_front: np.ndarray, z_back: np.ndarray, spec: LayoutSpec, depth: float
) -> None:
    """In place: the box cells of ``cols`` set from ``z_front`` to ``z_back`` (per column; NaN leaves a
    column) inside the rack footprint; the box's old cells there become shelf."""
    z_back = np.asarray(z_back, dtype=np.float64)
    ok = np.isfinite(z_back)
    cols = np.asarray(cols)[ok]
    zc = cell_z(spec, depth)[:, None]
    sub = top[:, cols]
    foot = sub > 0
    sub[sub == BOX] = SHELF
    sub[foot & (zc >= np.asarray(z_front, dtype=np.float64)[ok]) & (zc <= z_back[ok])] = BOX
    top[:, cols] = sub


def impose_box_backs(
    top: np.ndarray,
    front: np.ndarray,
    spec: LayoutSpec,
    depth: float,
    backs: np.ndarray,
    split: bool = True,
    fronts: np.ndarray | None = None,
) -> np.ndarray:
    """Top views ``(R, D, D)`` with every box's back moved to ``backs`` ``(R, W)``: metres behind the rack
    front per column of a grid of ``W`` columns over the same X extent (NaN: unknown; a box with no
    known column is left). Fronts stay; each box gets one back, the median of its known columns (a box is a cuboid:
    per-column backs left ragged edges, and a column read shallower than its front split the box in
    two for the stitcher), at least its front cell deep. Boxes that touch side by side form one component;
    it is split where the front view's box height steps (`layouts.steps.pieces`, as the stitcher splits
    it), each piece with the median of its own known columns (of the whole component where it has none;
    ``split=False``: one back per component). ``fronts`` ``(R, W)``, as ``backs``: each column of a box with
    a known back also takes its front from there (NaN: its own front stays). A copy is returned."""
    top = np.asarray(top)
    backs = np.asarray(backs, dtype=np.float64)
    r, d = top.shape[0], spec.size
    if top.shape != (r, d, d) or np.shape(front) != top.shape:
        raise ValueError(f"top and front must both be (R, {d}, {d}) class ids, got {top.shape} and {np.shape(front)}")
    if backs.ndim != 2 or backs.shape[0] != r or backs.shape[1] < 1:
        raise ValueError(f"backs must be ({r}, W) back depths, got {backs.shape}")
    if fronts is not None and np.shape(fronts) != backs.shape:
        raise ValueError(f"fronts must have the shape of backs {backs.shape}, got {np.shape(fronts)}")
    if not np.isfinite(depth) or depth <= 0:
        raise ValueError(f"rack depth must be a positive number of metres, got {depth}")
    out = top.copy()
    w = backs.shape[1]
    cell = spec.z_extent / d
    dx, dh = spec.pixel_size("front")
    min_cols = max(1, int(round(MIN_BOX_WIDTH / dx)))
    for k in range(r):
        for cols, zf, _, _ in box_parts(top[k], front[k], spec, depth):
            zb = backs[k, cols * w // d]
            known = np.isfinite(zb)
            if not known.any():
                continue
            if fronts is not None:
                zf = np.where(np.isfinite(zn := fronts[k, cols * w // d]), zn, zf)
            whole = float(np.median(zb[known]))
            back = np.empty(len(cols))
            height = np.count_nonzero(front[k][:, cols] == BOX, axis=0) * dh
            for a, b in pieces(height, SPLIT_STEP, min_cols) if split else [(0, len(cols))]:
                part = zb[a:b][known[a:b]]
                back[a:b] = np.median(part) if part.size else whole
            redraw(out[k], cols, zf, np.maximum(back, zf + cell), spec, depth)
    return out
