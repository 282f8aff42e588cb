"""Decision calibration: one box-logit offset per view, chosen on data the model never trained on.

Training weights the rare box class (``--class-weights``, box x2 by default), which moves the
argmax toward "box": a weighted cross entropy is minimised by probabilities in which box counts
double, so boxes come out deeper and wider than they are (measured: predicted box depth 0.55 m
against a true 0.47 m on the held-out set). Subtracting an offset from the box logit before the
argmax undoes that prior shift (``log 2 = 0.69`` would undo it exactly for a perfectly fitted
model); `fit_box_offsets` picks the offset per view that maximises that view's mean rack and box
mIoU over a grid, on a tuning set (never the held-out set one reports on). The offsets live in the
checkpoint's record (``box_logit_offset``) and `network.infer.Predictor` applies them, so every
consumer of predictions (evaluate, predict, run) gets the calibrated decision.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import torch
from tqdm import tqdm

from layouts import BOX, VIEWS
from layouts.errors import InputError
from layouts.metrics import METRIC_CLASSES, LayoutMetrics
from network.model import MVRackLay

#: offsets tried by `fit_box_offsets` (logit units)
GRID: tuple[float, ...] = tuple(round(0.25 * k, 2) for k in range(11))  # 0 .. 2.5
#: offsets outside this range are refused (they would erase or flood the box class)
LIMIT = 5.0


def check_offsets(value: Any, source: str) -> dict[str, float]:
    """``{"top": float, "front": float}`` from a record value (None = no calibration: zeros)."""
    if value is None:
        return {v: 0.0 for v in VIEWS}
    if not isinstance(value, dict) or set(value) != set(VIEWS):
        raise InputError(f"{source}: box_logit_offset must be an object with keys {list(VIEWS)}, got {value!r}")
    out = {}
    for v in VIEWS:
        x = value[v]
        if isinstance(x, bool) or not isinstance(x, (int, float)) or not math.isfinite(x) or abs(x) > LIMIT:
            raise InputError(f"{source}: box_logit_offset[{v!r}] must be a number in [-{LIMIT}, {LIMIT}], got {x!r}")
        out[v] = float(x)
    return out


def apply_box_offset(logits: torch.Tensor, offset: float) -> torch.Tensor:
    """``(..., 3, D, D)`` logits with ``offset`` subtracted from the box class (a new tensor)."""
    if offset == 0.0:
        return logits
    shift = torch.zeros(logits.shape[-3], dtype=logits.dtype, device=logits.device)
    shift[BOX] = offset
    return logits - shift.view(-1, 1, 1)


def fit_box_offsets(
    model: MVRackLay,
    sequences: list[Any],
    *,
    grid: tuple[float, ...] = GRID,
    every: int = 2,
    mode: str = "stream",
    flip: bool = False,
    progress: bool = True,
) -> dict[str, Any]:
    """Score every grid offset per view on ``sequences`` (every ``every``-th frame, columns in view).

    Returns ``{"box_logit_offset": {view: best}, "scores": {view: {offset: {"rack", "box"}}}, "frames"}``;
    best = the largest mean of the view's rack and box mIoU (ties: the smaller offset). ``flip``
    scores flip-averaged logits (`network.infer.Predictor`).
    """
    from network.infer import Predictor, logits_to_layout, resize_logits, sequence_camera  # infer imports this module

    if not sequences:
        raise InputError("calibration needs at least one sequence with ground truth")
    if not grid or any(not math.isfinite(g) or abs(g) > LIMIT for g in grid):
        raise InputError(f"offset grid must hold numbers in [-{LIMIT}, {LIMIT}], got {grid}")
    saved = dict(model.box_logit_offset)
    model.box_logit_offset = {v: 0.0 for v in VIEWS}  # score the raw logits
    scorers = {g: LayoutMetrics() for g in grid}  # each view scored on its own, columns in view
    total = sum(s.num_frames for s in sequences)
    frames = 0
    try:
        bar = tqdm(total=total, desc="calibrate", unit="frame", disable=not progress, leave=False)
        for seq in sequences:
            d = seq.spec.size
            for i, out in enumerate(
                Predictor(model, sequence_camera(seq), flip=flip, fuse_tau=0).run(
                    (seq.rgb(k) for k in range(seq.num_frames)), mode
                )
            ):
                bar.update(1)
                if i % every:
                    continue
                gt = seq.layouts(i)
                vis = gt.visible if gt.visible is not None else np.ones(d, bool)
                for v in VIEWS:
                    logits = resize_logits(out[v].float(), d)  # offsets commute with the bilinear resize
                    for g in grid:
                        pred = logits_to_layout(apply_box_offset(logits, g))
                        scorers[g].update(pred, getattr(gt, v), v, valid=vis)
                frames += 1
        bar.close()
    finally:
        model.box_logit_offset = saved
    scores: dict[str, dict[str, dict[str, float]]] = {v: {} for v in VIEWS}
    best: dict[str, float] = {}
    for v in VIEWS:
        top_score = -1.0
        for g in grid:
            res = scorers[g].result()[v]
            cell = {c: res[c]["miou"] for c in METRIC_CLASSES}
            scores[v][f"{g:g}"] = cell
            s = float(np.nanmean([cell[c] for c in METRIC_CLASSES]))
            if s > top_score + 1e-12:
                top_score, best[v] = s, float(g)
    return {
        "box_logit_offset": best,
        "scores": scores,
        "frames": frames,
        "mode": mode,
        "flip_average": flip,
        "every": every,
    }
