"""Upright frames along a row: per-frame upright columns fused into a 1D vote along X, and a face's bays cut there.

A frame marks the layout columns that show a front upright (the network's upright head, or the ground truth);
`UprightStrip` places them in map X by the frame's offset and counts, per bin of the shelf strip's width, the
frames that marked it against those that had it in view. `UprightStrip.peaks` gives each upright frame once:
its X (the centre of a run of bins marked in at least half the frames that saw them) and its support (that
share). `fuse_uprights` joins the uprights of several passes along a face; `bay_cuts` picks the ones that cut
a stretch of racking into bays, with the repetition of bay widths along the face as a prior.
"""

from __future__ import annotations

import math
import statistics
from dataclasses import dataclass

import numpy as np

from layouts.errors import InputError

MIN_SHARE = 0.5  #: a bin is an upright's where at least this share of the frames that saw it marked it
MIN_FRAMES = 2  #: ... and at least this many frames saw it
SAME_UPRIGHT = 0.15  #: metres: two passes' uprights closer than this are one frame
END_MARGIN = 0.3  #: metres: an upright this close to a stretch's end is that end's, not a cut
CERTAIN_SUPPORT = 0.7  #: a boundary is certain with at least this support and a bay width the face repeats
WIDTH_PRIOR = (0.75, 1.33)  #: bay widths within this share of the face's typical width agree with the prior


@dataclass(frozen=True)
class Upright:
    x: float  #: centre line X (map or face frame, metres)
    support: float  #: share of the frames (passes: their mean) that marked it where they saw it


class UprightStrip:
    """Votes of upright columns along X in bins of ``dx`` metres (global bin index = ``g0`` + position)."""

    def __init__(self, dx: float):
        if not (math.isfinite(dx) and dx > 0):
            raise InputError(f"upright strip bin width must be a positive number of metres, got {dx!r}")
        self.dx = dx
        self.g0 = 0
        self.marked = np.zeros(0, np.int32)
        self.seen = np.zeros(0, np.int32)

    def add(self, columns: np.ndarray, x_first: float, lo: int, hi: int) -> None:
        """One frame: ``columns`` (bool, one per layout column) marks its uprights; columns ``lo:hi`` were in
        view; ``x_first`` is the map X of column ``lo``'s centre."""
        cols = np.asarray(columns)
        if cols.ndim != 1 or not 0 <= lo <= hi <= cols.shape[0]:
            raise InputError(f"upright columns must be one flag per layout column, got shape {cols.shape}")
        n = hi - lo
        if n <= 0:
            return
        g = int(math.floor(x_first / self.dx))
        self._grow(g, g + n)
        a = g - self.g0
        self.seen[a : a + n] += 1
        self.marked[a : a + n] += cols[lo:hi].astype(bool)

    def _grow(self, g_lo: int, g_hi: int) -> None:
        if self.seen.size == 0:
            self.g0 = g_lo
        new_lo, new_hi = min(self.g0, g_lo), max(self.g0 + self.seen.size, g_hi)
        if new_lo == self.g0 and new_hi == self.g0 + self.seen.size:
            return
        marked, seen = np.zeros(new_hi - new_lo, np.int32), np.zeros(new_hi - new_lo, np.int32)
        a = self.g0 - new_lo
        marked[a : a + self.seen.size], seen[a : a + self.seen.size] = self.marked, self.seen
        self.g0, self.marked, self.seen = new_lo, marked, seen

    def peaks(self) -> list[Upright]:
        """Each upright once: runs of bins marked by >= `MIN_SHARE` of >= `MIN_FRAMES` frames that saw them."""
        with np.errstate(invalid="ignore", divide="ignore"):
            share = np.where(self.seen > 0, self.marked / np.maximum(self.seen, 1), 0.0)
        on = (share >= MIN_SHARE) & (self.seen >= MIN_FRAMES)
        out, i = [], 0
        while i < on.size:
            if not on[i]:
                i += 1
                continue
            j = i
            while j < on.size and on[j]:
                j += 1
            w = share[i:j]
            centre = float(np.sum((np.arange(i, j) + 0.5) * w) / np.sum(w))
            out.append(Upright(round((self.g0 + centre) * self.dx, 6), round(float(w.mean()), 4)))
            i = j
        return out


def fuse_uprights(per_pass: list[list[Upright]]) -> list[Upright]:
    """The uprights of several passes along one face (face frame), each once: those within `SAME_UPRIGHT` of
    each other are one frame at their support-weighted X; its support is the mean over the passes that saw it."""
    flat = sorted((u for us in per_pass for u in us), key=lambda u: u.x)
    groups: list[list[Upright]] = []
    for u in flat:
        if groups and u.x - groups[-1][-1].x <= SAME_UPRIGHT:
            groups[-1].append(u)
        else:
            groups.append([u])
    out = []
    for g in groups:
        w = sum(u.support for u in g) or 1.0
        out.append(Upright(sum(u.x * u.support for u in g) / w, statistics.mean(u.support for u in g)))
    return out


def bay_cuts(lo: float, hi: float, uprights: list[Upright], typical: float | None) -> list[tuple[float, bool]]:
    """Where the stretch of racking ``lo``..``hi`` (found as one rack) is cut into bays: at each upright inside it
    (more than `END_MARGIN` from its ends), as ``(x, certain)``. With the face's ``typical`` bay width, a cut
    that would leave a bay under half of it beside another cut is dropped (the weaker of the two), and a cut is
    certain where its support is at least `CERTAIN_SUPPORT` and the bays on both sides agree with the prior."""
    inside = [u for u in uprights if lo + END_MARGIN < u.x < hi - END_MARGIN]
    if typical and typical > 0:
        changed = True
        while changed and inside:
            changed = False
            edges = [lo, *(u.x for u in inside), hi]
            for k in range(len(inside)):
                left, right = edges[k + 1] - edges[k], edges[k + 2] - edges[k + 1]
                if min(left, right) < 0.5 * typical and left + right < WIDTH_PRIOR[1] * typical:
                    del inside[k]  # two half bays: one bay and a false upright
                    changed = True
                    break
    edges = [lo, *(u.x for u in inside), hi]
    out = []
    for k, u in enumerate(inside):
        ok = u.support >= CERTAIN_SUPPORT
        if typical and typical > 0:
            for w in (edges[k + 1] - edges[k], edges[k + 2] - edges[k + 1]):
                ok = ok and WIDTH_PRIOR[0] * typical <= w <= WIDTH_PRIOR[1] * typical
        out.append((u.x, ok))
    return out
