"""Neighbouring frames' layouts fused along the row: each frame's logits averaged with its neighbours'.

A stretch of shelf is seen from several viewpoints as the camera passes, and each view errs a little
differently. Each frame's decided logits (both views, every slot) are averaged with those of the
frames before it (and, over a recorded sequence, after it), each shifted by the camera's motion
along the row into the frame's own columns (`network.model.memory.shift_columns`: the layout frame moves
with the camera) and weighted by ``exp(-|frames apart| / tau)`` over the columns each frame saw. A
short ``tau`` (1 frame, `FUSE_TAU`: weights 1, 0.37, 0.14, ...) keeps what this frame shows in charge
and the camera motion read from the images (`network.model.motion`) precise enough: that reading drifts
by a few millimetres a frame, and a long window smears the layouts (docs/network.md, *Neighbouring
frames fused*).
It is off unless asked for (``--fuse-frames``): the layouts gain, but the maps stitched from them lose
(at tau = 1 0.01-0.03 box precision and recall held out: the stitcher finds fewer boxes at 3D IoU 0.5).

Averaging logits (not probabilities) keeps their scale, so the checkpoint's box offsets still hold. What leaves the
layouts' X extent is dropped from the running sums (a camera that turns back starts over there).
"""

from __future__ import annotations

import copy
import math
from collections.abc import Sequence

import torch
import torch.nn.functional as F

from layouts import VIEWS
from layouts.errors import InputError
from network.model.memory import shift_columns

#: frames; each neighbour's weight is exp(-frames apart / tau); chosen on the tuning sets (what a bare
#: ``--fuse-frames`` gives; off by default: the stitched maps lose by it, docs/network.md)
FUSE_TAU = 1.0


def check_tau(tau: float, name: str = "fuse_tau") -> float:
    """``tau`` as a float, or an InputError naming ``name`` (the argument or option)."""
    if isinstance(tau, bool) or not isinstance(tau, (int, float)) or not math.isfinite(tau) or tau < 0:
        raise InputError(f"{name} must be a number of frames >= 0 (0 = no fusion), got {tau!r}")
    return float(tau)


def seen_columns(signature: torch.Tensor, size: int) -> torch.Tensor:
    """``(size,)`` float 0/1: the layout columns whose canonical pixels are mostly inside the source image.

    ``signature``: one frame's `network.model.motion.motion_signature` ``(1, 2, H, W)``; the canonical image
    spans the layouts' X extent, so its columns map onto the layout columns.
    """
    cols = signature[0, 1].amax(0)  # (W,) 1 where the column holds source pixels
    return (F.adaptive_avg_pool1d(cols[None, None].float(), size)[0, 0] > 0.5).float()


def _decay(tau: float) -> float:
    """Each frame's weight relative to the next one's, ``exp(-1 / tau)``; ``tau`` must be > 0."""
    if check_tau(tau) == 0:
        raise InputError("fusion needs fuse_tau > 0 (0 means no fusion: skip it)")
    return math.exp(-1.0 / tau)


class _Sums:
    """Decayed sums of weighted logits and of weights, in the current frame's columns."""

    def __init__(self, decay: float, x_extent: float) -> None:
        self.decay, self.x_extent = decay, x_extent
        self.logits: dict[str, torch.Tensor] | None = None
        self.weight: torch.Tensor | None = None

    def move(self, step: float) -> None:
        """The camera moved ``step`` metres along X: the sums follow into the new frame's columns, decayed."""
        if self.logits is None or self.weight is None:
            return
        dx = torch.tensor([step], dtype=torch.float32)
        self.logits = {
            v: self.decay * shift_columns(x, dx.to(x.device), self.x_extent, x.shape[0]) for v, x in self.logits.items()
        }
        w = self.weight[None, None, None]  # (1, 1, 1, D)
        self.weight = self.decay * shift_columns(w, dx.to(w.device), self.x_extent, 1)[0, 0, 0]

    def add(self, logits: dict[str, torch.Tensor], seen: torch.Tensor) -> None:
        terms = {v: logits[v].float() * seen for v in VIEWS}
        if self.logits is None or self.weight is None:
            self.logits, self.weight = terms, seen.clone()
            return
        self.logits = {v: self.logits[v] + terms[v] for v in VIEWS}
        self.weight = self.weight + seen


def _average(own: dict[str, torch.Tensor], parts: Sequence[_Sums], eps: float = 1e-3) -> dict[str, torch.Tensor]:
    """The weighted mean of ``parts`` per column; ``own`` where no frame saw the column."""
    weight = sum(p.weight for p in parts if p.weight is not None)
    out = {}
    for v in VIEWS:
        total = sum(p.logits[v] for p in parts if p.logits is not None)
        mean = total / torch.clamp(weight, min=eps)
        out[v] = torch.where(weight > eps, mean, own[v].float()).to(own[v].dtype)
    return out


class LayoutFusion:
    """Streaming fusion over the frames so far: ``add`` each frame's logits, get them fused.

    ``tau``: frames (> 0); ``x_extent``: metres of row across the layout columns.
    """

    def __init__(self, tau: float, x_extent: float) -> None:
        self._sums = _Sums(_decay(tau), x_extent)

    def add(self, logits: dict[str, torch.Tensor], step: float, seen: torch.Tensor) -> dict[str, torch.Tensor]:
        """``logits``: ``{view: (R, 3, D, D)}``; ``step``: camera motion along X since the previous frame
        (metres); ``seen``: ``(D,)`` 0/1 columns in view. Returns the fused ``{view: (R, 3, D, D)}``."""
        self._sums.move(step)
        self._sums.add(logits, seen)
        return _average(logits, [self._sums])


def fuse_sequence(
    logits: Sequence[dict[str, torch.Tensor]],
    steps: Sequence[float],
    seen: Sequence[torch.Tensor],
    tau: float,
    x_extent: float,
) -> list[dict[str, torch.Tensor]]:
    """Every frame fused with the frames before and after it (a recorded sequence).

    ``steps[i]``: the camera motion from frame i-1 to frame i (``steps[0]`` unused). One pass forward
    (`LayoutFusion`) and one backward (the later frames, moved back by their steps).
    """
    n = len(logits)
    if not (len(steps) == len(seen) == n):
        raise InputError(f"fuse_sequence: {n} frames of logits, {len(steps)} steps, {len(seen)} seen masks")
    decay = _decay(tau)
    ahead = _Sums(decay, x_extent)  # frames after i, in frame i's columns
    later: list[_Sums] = [None] * n  # type: ignore[list-item]
    for i in range(n - 1, -1, -1):
        later[i] = copy.copy(ahead)  # the sums are replaced, never changed in place: a shallow copy holds
        ahead.add(logits[i], seen[i])
        ahead.move(-float(steps[i]))  # into frame i-1's columns, one more frame away
    before = _Sums(decay, x_extent)  # frames up to i, in frame i's columns
    out = []
    for i in range(n):
        before.move(float(steps[i]) if i else 0.0)
        before.add(logits[i], seen[i])
        out.append(_average(logits[i], [before, later[i]]))
    return out
