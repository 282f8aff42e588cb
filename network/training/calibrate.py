"""Decision calibration: one box-logit offset per view, and the rack-depth reader's offset, chosen on data
the model never trained on.

Training weights the rare box class (``--class-weights``, box x2 by default), which moves the
argmax toward "box": a weighted cross entropy is minimised by probabilities in which box counts
double, so boxes come out deeper and wider than they are (measured: predicted box depth 0.55 m
against a true 0.47 m on the held-out set). Subtracting an offset from the box logit before the
argmax undoes that prior shift (``log 2 = 0.69`` would undo it exactly for a perfectly fitted
model); `fit_box_offsets` picks the offset per view that maximises that view's mean rack and box
mIoU over a grid, on a tuning set (never the held-out set one reports on). The offsets live in the
checkpoint's record (``box_logit_offset``) and `network.inference.predictor.Predictor` applies them
(`network.inference.decision`), so every
consumer of predictions (evaluate, predict, run) gets the calibrated decision.

The rack depth read from the uprights and back edges (`network.heads.backedge.DepthReader`) is biased too, on
scenes its heads were not fitted on: shallow by a centimetre or so (docs/network.md). `fit_rack_depth_offset` measures that bias on a tuning set with
known rack depths (the median of read minus true over the frames with a reading) and returns its negative,
which the record carries as ``rack_depth_offset`` (metres) and the reader adds to every reading.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from typing import Any

import numpy as np
from tqdm import tqdm

from layouts import VIEWS
from layouts.errors import InputError
from layouts.metrics import METRIC_CLASSES, LayoutMetrics
from network.inference.decision import LIMIT, apply_box_offset, check_depth_offset
from network.inference.predictor import Predictor, sequence_camera
from network.inference.result import FramePrediction, logits_to_layout, resize_logits
from network.model.net import MVRackLay
from network.training.fit_back_edges import rack_row

#: offsets tried by `fit_box_offsets` (logit units)
GRID: tuple[float, ...] = tuple(round(0.25 * k, 2) for k in range(11))  # 0 .. 2.5


def _tuning_outputs(
    model: MVRackLay, sequences: list[Any], every: int, mode: str, flip: bool, progress: bool, desc: str
) -> Iterator[tuple[int, int, FramePrediction]]:
    """``(sequence index, frame index, outputs)`` of every ``every``-th frame of ``sequences``, each run whole by
    `network.inference.predictor.Predictor` (``mode``, flip-averaged with ``flip``, no fusion), with a progress bar."""
    if not sequences:
        raise InputError("calibration needs at least one sequence with ground truth")
    bar = tqdm(total=sum(s.num_frames for s in sequences), desc=desc, unit="frame", disable=not progress, leave=False)
    try:
        for k, seq in enumerate(sequences):
            pred = Predictor(model, sequence_camera(seq), flip=flip, fuse_tau=0)
            for i, out in enumerate(pred.run((seq.rgb(j) for j in range(seq.num_frames)), mode)):
                bar.update(1)
                if i % every == 0:
                    yield k, i, out
    finally:
        bar.close()


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
    scores flip-averaged logits (`network.inference.predictor.Predictor`).
    """
    if not grid or any(not math.isfinite(g) or abs(g) > LIMIT for g in grid):
        raise InputError(f"offset grid must hold numbers in [-{LIMIT}, {LIMIT}], got {grid}")
    saved = dict(model.box_logit_offset)
    model.box_logit_offset = {v: 0.0 for v in VIEWS}  # score the raw logits
    scorers = {g: LayoutMetrics() for g in grid}  # each view scored on its own, columns in view
    frames = 0
    try:
        for k, i, out in _tuning_outputs(model, sequences, every, mode, flip, progress, "calibrate"):
            d = sequences[k].spec.size
            gt = sequences[k].layouts(i)
            vis = gt.visible if gt.visible is not None else np.ones(d, bool)
            for v in VIEWS:
                logits = resize_logits(getattr(out, v).float(), d)  # offsets commute with the bilinear resize
                for g in grid:
                    pred = logits_to_layout(apply_box_offset(logits, g))
                    scorers[g].update(pred, getattr(gt, v), v, valid=vis)
            frames += 1
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


def fit_rack_depth_offset(
    model: MVRackLay,
    sequences: list[Any],
    *,
    every: int = 2,
    mode: str = "stream",
    flip: bool = False,
    progress: bool = True,
) -> dict[str, Any]:
    """The offset that centres ``model``'s rack-depth reading on ``sequences``' true rack depths.

    Streams each generated sequence as `network.inference.predictor.Predictor` does (the depth from the frames so far,
    every frame run, every ``every``-th one counted) with the offset at 0, and returns
    ``{"rack_depth_offset": -median(read - true), "frames", "error_before", "error_after", "mode",
    "flip_average", "every"}`` (errors: mean absolute, metres, over the counted frames with a reading; a
    model that reads no depth there gets offset 0, 0 frames and NaN errors).
    """
    if model.back is None and model.uprights is None:
        raise InputError("the model reads no rack depth (it has neither the back-edge nor the upright head)")
    truths = [rack_row(seq, "the rack-depth offset")[0] for seq in sequences]  # all checked before streaming
    saved = model.rack_depth_offset
    model.rack_depth_offset = 0.0
    errors: list[float] = []
    try:
        for k, _, out in _tuning_outputs(model, sequences, every, mode, flip, progress, "rack depth"):
            read = out.rack_depth
            if math.isfinite(read):
                errors.append(read - truths[k])
    finally:
        model.rack_depth_offset = saved
    if not errors:  # nothing to centre: the offset stays 0 (the stage says so; a recipe goes on)
        return {"rack_depth_offset": 0.0, "frames": 0, "error_before": float("nan"), "error_after": float("nan"),
                "mode": mode, "flip_average": flip, "every": every}  # fmt: skip
    err = np.asarray(errors)
    offset = -float(np.median(err))
    check_depth_offset(offset, "the measured rack-depth bias")
    return {
        "rack_depth_offset": offset,
        "frames": len(errors),
        "error_before": float(np.abs(err).mean()),
        "error_after": float(np.abs(err + offset).mean()),
        "mode": mode,
        "flip_average": flip,
        "every": every,
    }
