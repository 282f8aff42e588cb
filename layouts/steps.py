"""Where touching boxes part: steps in per-column profiles.

Boxes standing side by side on a shelf merge into one run of box columns in a layout. A box is a
cuboid, so inside such a run a step in a per-column profile (the front view's box height, the top
view's near or far edge) marks where one box ends and the next begins. The stitcher splits its
detections there (`stitching.detect`) and the box-depth reader gives each piece its own back
(`layouts.boxdepth.impose_box_backs`), both with the defaults below.
"""

from __future__ import annotations

import numpy as np

SPLIT_STEP = 0.045  #: metres; a step this large in a profile splits a run of box columns
MIN_BOX_WIDTH = 0.18  #: metres; no split leaves a piece narrower than this


def _med3(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Element-wise median of three arrays (no sorting)."""
    return np.maximum(np.minimum(a, b), np.minimum(np.maximum(a, b), c))


def profile_steps(profiles: np.ndarray) -> np.ndarray:
    """Per split position, the largest |median of the 3 values right - median of the 3 left| over profiles.

    ``profiles`` is ``(P, n)`` or ``(n,)``; the result has length ``n + 1`` (position j splits before
    column j) and is 0 within 3 columns of either end.
    """
    p = np.atleast_2d(profiles)
    n = p.shape[1]
    out = np.zeros(n + 1)
    if n < 6:
        return out
    med = _med3(p[:, :-2], p[:, 1:-1], p[:, 2:])  # med[:, i] = median of p[:, i:i+3]
    # Position j (3 <= j <= n-3): left window starts at j-3, right window at j.
    out[3 : n - 2] = np.abs(med[:, 3:] - med[:, : n - 5]).max(axis=0)
    # A plateau of equal scores surrounds a clean step: the raw jump picks the exact column.
    out[1:n] += 1e-3 * np.abs(np.diff(p, axis=1)).max(axis=0)
    return out


def split_positions(score: np.ndarray, thr: float, min_cols: int, n: int) -> list[int]:
    """Greedy strongest-first split positions in ``(0, n)`` above ``thr``, at least ``min_cols`` apart."""
    cand = np.flatnonzero(score > thr)
    cuts: list[int] = []
    for j in cand[np.argsort(-score[cand], kind="stable")]:
        if j < min_cols or n - j < min_cols:
            continue
        if all(abs(j - c) >= min_cols for c in cuts):
            cuts.append(int(j))
    return sorted(cuts)


def score_pieces(score: np.ndarray, thr: float, min_cols: int) -> list[tuple[int, int]]:
    """Half-open column ranges ``[a, b)`` of one run of ``len(score) - 1`` box columns, split where the step
    ``score`` (`profile_steps`, per split position) exceeds ``thr``: never at the run's ends, no piece under
    ``min_cols``."""
    n = len(score) - 1
    inner = np.array(score, dtype=np.float64)
    inner[0] = inner[-1] = 0.0
    edges = [0, *split_positions(inner, thr, min_cols, n), n]
    return list(zip(edges[:-1], edges[1:]))


def pieces(profile: np.ndarray, thr: float, min_cols: int) -> list[tuple[int, int]]:
    """`score_pieces` of one run of box columns where its ``profile`` steps by more than ``thr``."""
    return score_pieces(profile_steps(profile), thr, min_cols)
