"""Shift: where a frame sits along the row relative to what is already mapped.

Two estimators, the second a fallback:

* `vote_offset`: box edges of the new frame vs. box edges already in the map (which holds the
  previous frames fused). Every pair of like edges (same slot, left/left or right/right, similar
  depth, height and, when both are whole, width) proposes an offset; the offset with the most
  distinct supporting frame edges within ``tol`` wins (a 1D consensus, so mismatched pairs are
  outliers that cannot pull it), ties go to the hypothesis nearest the prediction, and the
  answer is the mean of the supporters (pixel-quantised edges average out). Matching against the
  fused map rather than only the previous frame keeps the error from accumulating frame by frame.
* `correlate_shift`: correlation of the previous and current top-view layouts' per-column
  profiles (box and shelf fraction per slot; parabolic sub-pixel peak), used when too few edges
  agree.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from layouts.classes import BOX
from layouts.errors import LayoutError
from layouts.spec import LayoutSpec


@dataclass(frozen=True)
class ShiftConfig:
    max_step: float = 0.45  #: metres; largest |offset - previous offset| considered
    tol_px: float = 1.05  #: layout columns; supporters of a hypothesis lie this close to it (edges are
    #: quantised to whole columns, so the two neighbouring quantisation levels must both count)
    size_tol: float = 0.06  #: metres; like edges must agree this well in depth/height/width
    min_support: int = 2  #: distinct agreeing frame edges needed to trust the box vote
    min_corr_conf: float = 0.5  #: profile correlation below this is not used
    max_speed_change: float = 0.3  #: metres; largest |step - previous step| (a camera does not jump back
    #: at once: a reversal takes several frames); keeps a wrong consensus of a few edges out

    def __post_init__(self) -> None:
        for name in ("max_step", "tol_px", "size_tol", "min_corr_conf", "max_speed_change"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0:
                raise LayoutError(f"ShiftConfig.{name} must be a finite number >= 0, got {v!r}")
        m = self.min_support
        if isinstance(m, bool) or not isinstance(m, int) or m < 0:
            raise LayoutError(f"ShiftConfig.min_support must be an integer >= 0, got {m!r}")

    def allows(self, step: float | np.ndarray, velocity: float | None = None) -> bool | np.ndarray:
        """Whether a camera step (metres; a float or an array) is plausible: within ``max_step`` and,
        given the previous step ``velocity``, within ``max_speed_change`` of it. The one motion prior
        the box vote and the correlation fallback share."""
        ok = np.abs(step) <= self.max_step
        if velocity is not None:
            ok = ok & (np.abs(step - velocity) <= self.max_speed_change)
        return ok


@dataclass
class Edges:
    """Box edges as parallel arrays: slot, side (0 left, 1 right), x, width (nan if cut), depth, z, height, count."""

    slot: np.ndarray
    side: np.ndarray
    x: np.ndarray
    w: np.ndarray
    d: np.ndarray
    z: np.ndarray
    h: np.ndarray
    n: np.ndarray  #: observations behind each edge (its weight in the refinement)

    @classmethod
    def empty(cls) -> Edges:
        e = np.zeros(0)
        return cls(e.astype(int), e.astype(int), e, e, e, e, e, e)

    def __len__(self) -> int:
        return len(self.x)


def vote_offset(
    frame: Edges, mapped: Edges, predicted: float, cfg: ShiftConfig, dx: float, expected: float | None = None
) -> tuple[float, int, float]:
    """Consensus offset ``map_x - frame_x``: (offset, distinct supporting frame edges, confidence).

    ``dx`` is the layout's metres per column (the quantisation step of the edges). Hypotheses lie
    within ``max_step`` of ``predicted`` (the previous offset: the camera may reverse) and, when
    ``expected`` (constant velocity) is given, within ``max_speed_change`` of it; ties go to the one
    nearest ``expected`` (default ``predicted``).
    """
    tol = cfg.tol_px * dx
    if len(frame) == 0 or len(mapped) == 0:
        return predicted, 0, 0.0
    off = mapped.x[None, :] - frame.x[:, None]
    ok = (frame.slot[:, None] == mapped.slot[None, :]) & (frame.side[:, None] == mapped.side[None, :])
    ok &= cfg.allows(off - predicted, None if expected is None else expected - predicted)
    ok &= np.abs(frame.d[:, None] - mapped.d[None, :]) <= cfg.size_tol
    ok &= np.abs(frame.h[:, None] - mapped.h[None, :]) <= cfg.size_tol
    ok &= np.abs(frame.z[:, None] - mapped.z[None, :]) <= cfg.size_tol
    dw = np.abs(frame.w[:, None] - mapped.w[None, :])
    ok &= ~(dw > cfg.size_tol)  # nan (a cut width) never rejects
    fi, mi = np.nonzero(ok)
    if fi.size == 0:
        return predicted, 0, 0.0
    hyp = off[fi, mi]
    close = np.abs(hyp[:, None] - hyp[None, :]) <= tol  # (H, H)
    # Distinct frame edges supporting each hypothesis.
    nf = len(frame)
    support = np.zeros((len(hyp), nf), bool)
    rows, cols = np.nonzero(close)
    support[rows, fi[cols]] = True
    count = support.sum(axis=1)
    best_count = count.max()
    cand = np.flatnonzero(count == best_count)
    best = cand[np.argmin(np.abs(hyp[cand] - (predicted if expected is None else expected)))]
    # Refine: mean of one supporter per frame edge (the pair nearest the centre) within tol, twice.
    centre = float(hyp[best])
    weight = np.sqrt(np.maximum(mapped.n[mi], 1.0))
    for _ in range(2):
        chosen: dict[int, tuple[float, float]] = {}
        sel = np.flatnonzero(np.abs(hyp - centre) <= tol)
        for k in sel.tolist():
            f, h = int(fi[k]), float(hyp[k])
            if f not in chosen or abs(h - centre) < abs(chosen[f][0] - centre):
                chosen[f] = (h, float(weight[k]))
        if not chosen:
            break
        hs, ws = np.array(list(chosen.values())).T
        centre = float(np.average(hs, weights=ws))
    offset = centre
    conf = float(min(1.0, best_count / max(4.0, 0.5 * nf)))
    return offset, int(best_count), conf


def _profiles(top: np.ndarray) -> np.ndarray:
    """Per slot, the fraction of rows that are box and that are not background, per column: (2R, D)."""
    rows = top.shape[1]
    box = np.count_nonzero(top == BOX, axis=1) / rows
    shelf = np.count_nonzero(top, axis=1) / rows
    return np.concatenate([box, shelf]).astype(np.float64)


def correlate_shift(
    prev_top: np.ndarray, cur_top: np.ndarray, spec: LayoutSpec, max_step: float = 0.45
) -> tuple[float, float]:
    """Camera shift (metres, + = camera moved to +X) between two top-view stacks, and a confidence.

    Correlates the per-column profiles (box fraction and shelf fraction of each slot; averaging
    over rows makes them robust to scattered pixel flips) over lags up to ``max_step``, with a
    parabolic sub-pixel peak. Content moves to -X when the camera moves to +X, so the current
    profile at column c matches the previous one at c + lag. Confidence: the Pearson
    correlation at the peak (0 when either layout is blank).
    """
    a, b = _profiles(prev_top), _profiles(cur_top)
    D = a.shape[1]
    if a.std() == 0 or b.std() == 0:
        return 0.0, 0.0
    dx = spec.x_extent / spec.size
    m = max(1, min(int(np.ceil(max_step / dx)), D // 2))
    lags = np.arange(-m, m + 1)
    score = np.full(len(lags), -np.inf)
    for k, lag in enumerate(lags):
        pa = a[:, max(lag, 0) : D + min(lag, 0)]
        pb = b[:, max(-lag, 0) : D + min(-lag, 0)]
        va, vb = pa - pa.mean(), pb - pb.mean()
        den = np.sqrt((va * va).sum() * (vb * vb).sum())
        if den > 0:
            score[k] = float((va * vb).sum() / den)
    k = int(np.argmax(score))
    if not np.isfinite(score[k]):
        return 0.0, 0.0
    lag = float(lags[k])
    if 0 < k < len(lags) - 1 and np.isfinite(score[k - 1]) and np.isfinite(score[k + 1]):
        l, c, r = score[k - 1], score[k], score[k + 1]
        den = l - 2 * c + r
        if den < 0:
            lag += float(np.clip(0.5 * (l - r) / den, -0.5, 0.5))
    return lag * dx, float(max(0.0, score[k]))
