"""Table I evaluation: run a model over sequences and score layouts against ground truth.

Predictions are scored at the ground truth's resolution (logits resized bilinearly when the
model's D differs), over all cells and over the columns in view (per-frame ``visible``), with
`layouts.metrics.LayoutMetrics` (reference-style averaged mIoU / "mAP" and pooled figures). With
``reference`` the authors' own metric and loop is computed beside it (`layouts.metrics.ReferenceMetrics`:
all cells, each sequence's frames weighted as MVRackLay's windows target them, f0 twice and the last never).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import torch
from tqdm import tqdm

from layouts import VIEWS
from layouts.metrics import METRIC_CLASSES, FrameScorer, ReferenceMetrics, reference_weights
from network.data import SequenceLike, board_rows, check_spec_compatible
from network.inference.predictor import Predictor, rack_depth_source, sequence_camera
from network.model.net import MVRackLay
from network.preprocess import sequence_angles


def evaluate_sequences(
    model: MVRackLay,
    sequences: list[SequenceLike],
    *,
    mode: str = "window",
    max_frames: int | None = None,
    progress: bool = True,
    true_anchors: bool = False,
    flip: bool = False,
    read_depth: bool = True,
    whole_sequence: bool = False,
    fuse_tau: float = 0.0,
    roll: float | str | None = None,
    pitch: float | str | None = None,
    yaw: float | str | None = None,
    reference: bool = False,
) -> dict[str, Any]:
    """``{"all": table, "visible": table, "frames": n, "mode": mode, ...}`` over the given sequences.

    ``true_anchors`` places the shelf slots at the ground truth's boards instead of the row head's:
    what the decoders score when the boards are found perfectly (an analysis, not a result).
    ``flip`` averages each frame with its mirror image (`network.inference.predictor.Predictor`); ``read_depth``
    False keeps the top views' rack depth as decoded when the model could read it from back edges;
    ``whole_sequence`` reads the depths from every frame of a sequence (`network.inference.predictor.Predictor`);
    ``fuse_tau`` fuses each frame's layouts with its neighbours' (`network.inference.fusion`; 0 = off);
    ``roll`` levels a rolled camera (degrees or ``"auto"``, `network.inference.roll`; None: each sequence's
    recorded roll, 0 for a level camera), ``pitch`` / ``yaw`` a tilt (degrees, up > 0) / turn (degrees,
    right > 0), the same. ``reference`` adds ``"reference"``: the authors' metric and loop
    (`layouts.metrics.ReferenceMetrics`, over the first ``max_frames`` frames as their sequence).
    """
    scorer = FrameScorer()
    ref = ReferenceMetrics() if reference else None
    slots_right = 0
    total = sum(s.num_frames if max_frames is None else min(s.num_frames, max_frames) for s in sequences)
    bar = tqdm(total=total, desc=f"evaluate ({mode})", unit="frame", disable=not progress, leave=False)
    frames = 0
    rolls: list[float] = []
    pitches: list[float] = []
    yaws: list[float] = []
    options = dict(
        flip=flip,
        read_depth=read_depth,
        whole_sequence=whole_sequence,
        fuse_tau=fuse_tau,
        roll=roll,
        pitch=pitch,
        yaw=yaw,
    )
    for seq in sequences:
        check_spec_compatible(model.cfg.spec, seq.spec, str(getattr(seq, "root", seq.name)))
        n = seq.num_frames if max_frames is None else min(seq.num_frames, max_frames)
        scored, right, leveller = _score_sequence(model, seq, n, mode, (scorer, ref), bar, true_anchors, options)
        frames += scored
        slots_right += right
        if leveller is not None:
            rolls.extend(leveller.rolls)
            pitches.extend(leveller.pitches)
            yaws.extend(leveller.yaws)
    bar.close()
    extra = {} if ref is None else {"reference": ref.result(), "reference_windows": ref.frames["top"]}
    return {
        **scorer.result(),
        **extra,
        "frames": frames,
        "mode": mode,
        "flip_average": flip,
        "rack_depth": rack_depth_source(model) if read_depth else "as decoded",
        "box_depth": box_depth_source(model) if read_depth else "as decoded",
        "depths_from": "the whole sequence" if whole_sequence else "the frames so far",
        "fuse_frames": fuse_tau,
        # as asked: degrees, "auto", or None for each sequence's recorded angle
        "roll": roll,
        "pitch": pitch,
        "yaw": yaw,
        # the sequences' recorded camera rotations (degrees), in order
        "recorded_angles": [list(sequence_angles(seq)) for seq in sequences],
        # the angles levelled in each frame (degrees); [] when every camera was taken as level
        "rolls": rolls,
        "pitches": pitches,
        "yaws": yaws,
        "anchors": "truth" if true_anchors else "row head",
        "slot_count_accuracy": slots_right / max(frames, 1),
    }


def _score_sequence(
    model: MVRackLay,
    seq: SequenceLike,
    n: int,
    mode: str,
    scorers: tuple[FrameScorer, ReferenceMetrics | None],
    bar: tqdm,
    true_anchors: bool,
    options: dict[str, Any],
) -> tuple[int, int, Any]:
    """Score the first ``n`` frames of ``seq`` into ``scorers`` (ours, and the reference metric or None;
    ``options``: `Predictor`'s keywords).

    Returns the frames scored, how many of them the row head found the ground truth's number of shelf
    slots in, and the predictor's leveller (None when every camera was taken as level).
    """
    anchors = (lambda i, s=seq: board_rows(s, i, model.cfg.view, model.cfg.spec.num_slots)[0]) if true_anchors else None
    # angles None: the sequence's recorded ones (`network.inference.predictor.SequenceCamera`)
    pred = Predictor(model, sequence_camera(seq), anchors, **options)
    scorer, ref = scorers
    weights = reference_weights(n)
    frames = slots_right = 0
    for i, out in enumerate(pred.predict((seq.rgb(i) for i in range(n)), mode)):
        gt = seq.layouts(i)
        lay = out.layouts(seq.spec)
        scorer.update(lay, gt)
        if ref is not None:
            for view in VIEWS:
                ref.update(lay[view], getattr(gt, view), view, weights[i])
        found = int(torch.isfinite(out.anchors).sum())
        slots_right += int(found == int((gt.top.reshape(gt.top.shape[0], -1) > 0).any(1).sum()))
        frames += 1
        bar.update(1)
    return frames, slots_right, pred.leveller


def box_depth_source(model: MVRackLay) -> str:
    """Where a model reading depths takes its boxes' depths from (the record's ``"box_depth"``)."""
    if model.box_depth is None:
        return "as decoded"
    return "carried from the box-depth head" + (", fronts too" if model.cfg.box_front else "")


def score(result: dict[str, Any], part: str = "visible") -> float:
    """One number for choosing the best checkpoint: mean mIoU over views x classes (NaN -> 0)."""
    vals = [result[part][v][c]["miou"] for v in VIEWS for c in METRIC_CLASSES]
    return float(np.mean([0.0 if math.isnan(x) else x for x in vals]))


def table_title(
    variant: str | None,
    data: str,
    mode: str,
    model: MVRackLay,
    res: dict[str, Any],
    sequences: int,
    settings: Any,
    true_anchors: bool = False,
) -> str:
    """The tables' title: model, data, frames and every setting (``settings``: flip, depth reading, whole
    sequence, fusion, the angles as checked, e.g. `mvracklay.settings.InferenceSettings`) that changes what
    `evaluate_sequences` scored."""
    from network.inference.roll import ANGLES
    from network.model.frozen import trunk_precision

    angles = (settings.roll, settings.pitch, settings.yaw)
    title = f"{variant} on {data}, {res['frames']} frames of {sequences} sequences, {mode} mode"
    if settings.flip:
        title += ", flip-averaged"
    if trunk_precision(model) != "fp32":
        title += f", the trunk in {trunk_precision(model)}"
    if model.back is not None or model.uprights is not None:
        title += f", rack depth {res['rack_depth']}"
    if model.box_depth is not None:
        title += f", box depths {res['box_depth']}"
    heads = (model.back, model.uprights, model.box_depth) != (None,) * 3
    if settings.whole_sequence and settings.read_depth and heads:
        title += ", depths from the whole sequence"
    if settings.fuse_tau > 0:
        title += f", neighbouring frames fused (tau {settings.fuse_tau:g})"
    recorded = np.asarray(res["recorded_angles"], float).reshape(-1, 3)
    for k, (what, given) in enumerate(zip(ANGLES, angles)):
        if given is None and recorded[:, k].any():
            lo, hi = recorded[:, k].min(), recorded[:, k].max()
            span = f"{lo:g}" if lo == hi else f"{lo:g} to {hi:g}"
            title += f", camera {what} levelled as recorded ({span} deg)"
        elif given == 0 and recorded[:, k].any():
            title += f", camera {what} taken as level (recorded {np.abs(recorded[:, k]).max():g} deg)"
        elif given not in (None, 0):
            title += f", camera {what} " + ("read from the frames" if given == "auto" else f"{given:g} deg levelled")
    if true_anchors:
        title += ", ground-truth shelf boards"
    return title
