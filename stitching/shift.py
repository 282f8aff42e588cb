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

`MotionPrior` is the robust motion model both answer to: the median of the camera's last few
trusted steps (a constant-velocity prior that one bad step cannot pull) and a gate from their
spread (MAD). A step outside the gate is believed only with strong support or a second estimator
agreeing; otherwise the step is predicted from the prior and marked untrusted, so one stretch of
bad layouts (dim, noisy, blurred frames) leaves a flagged gap in the path instead of a bend.
"""

from __future__ import annotations

import math
from collections import deque
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
    max_speed_change: float = 0.6  #: metres; largest |step - previous step|: a hand-held camera stops, doubles
    #: its step or steps back from one frame to the next (the motion prior and a second estimator judge such steps)
    prior_steps: int = 10  #: trusted frames the robust line is fitted to (< 3: no motion prior)
    prior_gate: float = 0.04  #: metres; the least gate around the robust velocity (it widens to 3 MADs)
    override_support: int = 6  #: edges (and twice the gated vote's) a step outside the gate needs to be proposed
    relock: int = 4  #: strong votes in a row at one new speed that restart the prior (a real change of speed)
    speedup: float = 2.5  #: a step that breaks the prior may be up to this many times its speed (a hand's jerk)
    backstep: float = 1.5  #: ... or back by up to this many times it (a step back)
    motion_gain: float = 0.0  #: how far an agreeing image step pulls the vote (x its confidence share; 0: not)

    def __post_init__(self) -> None:
        for name in (
            "max_step",
            "tol_px",
            "size_tol",
            "min_corr_conf",
            "max_speed_change",
            "prior_gate",
            "speedup",
            "backstep",
            "motion_gain",
        ):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0:
                raise LayoutError(f"ShiftConfig.{name} must be a finite number >= 0, got {v!r}")
        for name in ("min_support", "prior_steps", "override_support", "relock"):
            m = getattr(self, name)
            if isinstance(m, bool) or not isinstance(m, int) or m < 0:
                raise LayoutError(f"ShiftConfig.{name} must be an integer >= 0, got {m!r}")

    def allows(self, step: float | np.ndarray, velocity: float | None = None) -> bool | np.ndarray:
        """Whether a camera step (metres; a float or an array) is plausible: within ``max_step`` and,
        given the previous step ``velocity``, within ``max_speed_change`` of it. The one motion prior
        the box vote and the correlation fallback share."""
        ok = np.abs(step) <= self.max_step
        if velocity is not None:
            ok = ok & (np.abs(step - velocity) <= self.max_speed_change)
        return ok


class MotionPrior:
    """Robust constant-velocity model of the camera along the row, updated one frame at a time.

    Keeps the offsets of the last ``prior_steps`` trusted frames and fits a line to them by
    Theil-Sen (median of pairwise slopes, median intercept): one bad offset cannot pull it, and the
    prediction for a frame after a stretch of untrusted ones is extrapolated from trusted anchors,
    not from accumulated guesses. ``gate``: how far an offset may lie from the line and still agree
    (``prior_gate`` or three scaled MADs of the residuals, widened by half for every ``relock``
    untrusted frames in a row; at most ``max_speed_change``). A real change of speed is taken up
    by `propose`. Ready with three trusted frames; O(``prior_steps``^2) per frame.
    """

    MIN_STEPS = 3

    def __init__(self, cfg: ShiftConfig):
        self.cfg = cfg
        self.points: deque[tuple[int, float]] = deque(maxlen=max(cfg.prior_steps, 1))
        self.misses = 0
        self.rejected: deque[tuple[int, float]] = deque(maxlen=max(cfg.relock, 1))  # strong votes it broke
        self._line = (0.0, 0.0, 0.0)  # slope, intercept, residual spread
        self.expected = 0.0  #: the step `predict` expects for the current frame
        self.speeds: deque[float] = deque(maxlen=4 * max(cfg.prior_steps, 1))  #: trusted steps per frame

    @property
    def ready(self) -> bool:
        return self.cfg.prior_steps >= self.MIN_STEPS and len(self.points) >= self.MIN_STEPS

    def _fit(self) -> None:
        k, y = np.array(self.points, dtype=np.float64).T
        i, j = np.triu_indices(len(k), 1)
        slope = float(np.median((y[j] - y[i]) / (k[j] - k[i])))
        icpt = float(np.median(y - slope * k))
        res = y - (icpt + slope * k)
        self._line = (slope, icpt, 1.4826 * float(np.median(np.abs(res - np.median(res)))))

    def predict(self, frame: int, offset: float, fallback: float) -> float:
        """The step expected from ``offset`` (the previous frame's) to ``frame``: the line's, else ``fallback``."""
        if self.ready:
            slope, icpt, _ = self._line
            self.expected = icpt + slope * frame - offset
        else:
            self.expected = fallback
        return self.expected

    def gate(self) -> float:
        base = max(self.cfg.prior_gate, 3.0 * self._line[2])
        widen = 1.0 + 0.5 * (self.misses // max(self.cfg.relock, 1)) if self.cfg.relock else 1.0
        return float(min(base * widen, self.cfg.max_speed_change))

    def agreement(self, step: float) -> float:
        """1 at the expected step, 0.5 at the gate, falling off beyond it (1 while not ready)."""
        if not self.ready:
            return 1.0
        return float(1.0 / (1.0 + (abs(step - self.expected) / max(self.gate(), 1e-9)) ** 2))

    def agrees(self, step: float) -> bool:
        return not self.ready or abs(step - self.expected) <= self.gate()

    def plausible(self, step: float) -> bool:
        """Whether a step that breaks the line is one a camera carried by hand or robot makes: a stop, up to
        ``speedup`` times the line's speed, or back by up to ``backstep`` times it (plus the gate), in the
        direction of travel. Always True while the prior is not ready."""
        if not self.ready or len(self.speeds) < self.MIN_STEPS:
            return True
        sp = np.asarray(self.speeds)
        moving = np.abs(sp)[np.abs(sp) > 0.25 * self.cfg.prior_gate]
        if moving.size < self.MIN_STEPS:
            return True
        v, g = float(np.median(moving)), self.gate()  # the usual speed while moving
        s = step if sp.sum() >= 0 else -step  # in the direction of travel
        return -self.cfg.backstep * v - g <= s <= self.cfg.speedup * v + g

    def propose(self, frame: int, offset: float) -> bool:
        """A strongly supported offset that breaks the prior: True (and the prior restarts from them) once
        the last ``relock`` such offsets are of consecutive frames and lie on one line within the gate:
        the camera really changed speed. Scattered wrong votes (bad layouts) never line up."""
        self.rejected.append((frame, float(offset)))
        r = list(self.rejected)
        if not self.cfg.relock or len(r) < max(self.cfg.relock, 2) or r[-1][0] - r[0][0] != len(r) - 1:
            return False
        k, y = np.array(r).T
        slope = float(np.median(np.diff(y) / np.diff(k)))
        res = y - slope * k
        if float(np.max(np.abs(res - np.median(res)))) > self.gate():
            return False
        self.points.clear()
        self.points.extend(r[:-1])
        self.rejected.clear()
        return True

    def restart(self, frame: int, offset: float) -> None:
        """Forget the line (a change of speed another estimator confirmed): start again from one point."""
        self.points.clear()
        self.rejected.clear()
        self.points.append((frame, float(offset)))

    def update(self, frame: int, offset: float, trusted: bool) -> None:
        if trusted:
            if self.points and frame > self.points[-1][0]:
                f0, o0 = self.points[-1]
                self.speeds.append((offset - o0) / (frame - f0))
            self.points.append((frame, float(offset)))
            self.misses = 0
            if self.rejected and self.rejected[-1][0] != frame:
                self.rejected.clear()
            if len(self.points) >= 2:
                self._fit()
        else:
            self.misses += 1


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

    @classmethod
    def from_rows(cls, rows: list[tuple]) -> Edges:
        """Edges from ``(slot, side, x, w, d, z, h[, n])`` rows (``n`` 1 when left out)."""
        if not rows:
            return cls.empty()
        a = np.array([r if len(r) == 8 else (*r, 1) for r in rows], dtype=float)
        return cls(a[:, 0].astype(int), a[:, 1].astype(int), a[:, 2], a[:, 3], a[:, 4], a[:, 5], a[:, 6], a[:, 7])

    @classmethod
    def concat(cls, a: Edges, b: Edges) -> Edges:
        return cls(
            *(np.concatenate([getattr(a, f), getattr(b, f)]) for f in ("slot", "side", "x", "w", "d", "z", "h", "n"))
        )


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
