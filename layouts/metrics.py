"""Table I metrics of RackLay / MVRackLay, per view x class, reference-style and pooled.

For each view (top, front) and class (``rack`` = class 1 shelf, ``box`` = class 2), binary masks
``pred == c`` and ``gt == c`` are compared **per shelf slot per frame**:

* ``miou``  mean over (frame, slot) pairs of IoU = TP / (TP + FP + FN).
  A pair where both masks are empty is skipped (nothing to find, nothing claimed).
* ``map``   what RackLay / MVRackLay call "mAP": the mean over (frame, slot) pairs of the pixel
  *precision* TP / (TP + FP). A pair with no predicted pixel of the class is skipped
  (precision undefined); a pair with predictions but no ground truth scores 0.
* ``pooled_iou`` / ``pooled_precision``: TP, FP, FN summed over every pixel of the dataset
  first, then one ratio. Large shelves weigh more; empty slots weigh nothing.
* ``pairs_iou`` / ``pairs_precision``: how many (frame, slot) pairs entered each mean.

An optional ``valid`` mask restricts scoring to some cells (e.g. the columns in view);
cells outside it count for nothing. Means over zero pairs are reported as NaN.

`ReferenceMetrics` is the authors' own evaluation (MVRackLay ``utils.py`` ``mean_IU`` /
``mean_precision`` as ``eval_vracklay.py`` sums them), offered so figures beside the paper's are
on equal terms: every cell is scored; a (frame, slot) pair with both masks empty scores IoU 1;
precision is taken only over the classes present in the ground truth, so on a slot without the
class it is the precision of "not the class" (1, or 0 when the prediction claims every cell), and
a prediction with no pixel of a present class scores 0; the sums are divided by frames x slots.
"""

from __future__ import annotations

import math

import numpy as np

from layouts.classes import BOX, SHELF
from layouts.errors import LayoutError
from layouts.spec import VIEWS, check_view

METRIC_CLASSES: dict[str, int] = {"rack": SHELF, "box": BOX}


class LayoutMetrics:
    """Accumulates Table I metrics over frames; call `update` per frame (or batch)."""

    def __init__(self) -> None:
        self._iou: dict[tuple[str, str], list[float]] = {}
        self._prec: dict[tuple[str, str], list[float]] = {}
        self._pool: dict[tuple[str, str], np.ndarray] = {}
        for v in VIEWS:
            for c in METRIC_CLASSES:
                self._iou[v, c] = []
                self._prec[v, c] = []
                self._pool[v, c] = np.zeros(3, np.int64)  # tp, fp, fn

    def update(self, pred: np.ndarray, gt: np.ndarray, view: str, valid: np.ndarray | None = None) -> None:
        """Add one frame ``(R, D, D)`` or a batch ``(N, R, D, D)`` of predictions and truth.

        ``valid`` broadcasts against the stacks: ``(D,)`` columns, ``(D, D)``, ``(R, D, D)``,
        ``(N, D)`` per-frame columns for a batch, or the full shape.
        """
        check_view(view)
        pred = np.asarray(pred)
        gt = np.asarray(gt)
        if pred.shape != gt.shape:
            raise LayoutError(f"prediction shape {pred.shape} differs from ground truth {gt.shape}")
        if pred.ndim == 3:
            pred, gt = pred[None], gt[None]
            if valid is not None and np.ndim(valid) == 1:
                valid = np.asarray(valid)[None]
        if pred.ndim != 4:
            raise LayoutError(f"layouts must be (R, D, D) or (N, R, D, D), got {pred.shape}")
        n, r, d, _ = pred.shape
        if valid is None:
            vmask = np.ones((1, 1, 1, 1), bool)
        else:
            valid = np.asarray(valid, bool)
            if valid.ndim == 2 and valid.shape == (n, d):
                vmask = valid[:, None, None, :]
            elif valid.ndim == 1:
                vmask = valid[None, None, None, :]
            else:
                vmask = valid.reshape((1,) * (4 - valid.ndim) + valid.shape)
            try:
                np.broadcast_shapes(vmask.shape, pred.shape)
            except ValueError:
                raise LayoutError(f"valid mask shape {valid.shape} does not fit layouts {pred.shape}") from None
        for cname, cid in METRIC_CLASSES.items():
            p = (pred == cid) & vmask
            g = (gt == cid) & vmask
            tp = (p & g).sum(axis=(2, 3))
            fp = (p & ~g).sum(axis=(2, 3))
            fn = (~p & g).sum(axis=(2, 3))
            self._pool[view, cname] += [int(tp.sum()), int(fp.sum()), int(fn.sum())]
            union = tp + fp + fn
            has = union > 0
            self._iou[view, cname].extend((tp[has] / union[has]).tolist())
            npred = tp + fp
            hp = npred > 0
            self._prec[view, cname].extend((tp[hp] / npred[hp]).tolist())

    def result(self) -> dict[str, dict[str, dict[str, float]]]:
        """``{view: {class: {miou, map, pooled_iou, pooled_precision, pairs_iou, pairs_precision}}}``."""
        out: dict[str, dict[str, dict[str, float]]] = {}
        for v in VIEWS:
            out[v] = {}
            for c in METRIC_CLASSES:
                tp, fp, fn = (int(x) for x in self._pool[v, c])
                ious, precs = self._iou[v, c], self._prec[v, c]
                out[v][c] = {
                    "miou": float(np.mean(ious)) if ious else math.nan,
                    "map": float(np.mean(precs)) if precs else math.nan,
                    "pooled_iou": tp / (tp + fp + fn) if tp + fp + fn else math.nan,
                    "pooled_precision": tp / (tp + fp) if tp + fp else math.nan,
                    "pairs_iou": len(ious),
                    "pairs_precision": len(precs),
                }
        return out


class FrameScorer:
    """Table I over all cells and over the columns in view, fed one frame at a time."""

    def __init__(self) -> None:
        self.all = LayoutMetrics()
        self.visible = LayoutMetrics()

    def update(self, pred: dict[str, np.ndarray], gt) -> None:
        """``pred`` maps view -> ``(R, D, D)``; ``gt`` has ``top``, ``front`` and ``visible`` (None = all)."""
        for view in VIEWS:
            g = getattr(gt, view)
            self.all.update(pred[view], g, view)
            vis = gt.visible if gt.visible is not None else np.ones(g.shape[-1], bool)
            self.visible.update(pred[view], g, view, valid=vis)

    def result(self) -> dict[str, dict]:
        return {"all": self.all.result(), "visible": self.visible.result()}


def format_table(result: dict, title: str = "") -> str:
    """Table I as text: rows view x class, columns mIoU / mAP (per-slot averaged) and pooled."""
    lines = []
    if title:
        lines.append(title)
    lines.append(f"{'view':<6} {'class':<5} {'mIoU':>7} {'mAP':>7} {'pooled IoU':>11} {'pooled prec':>12}")
    for v in VIEWS:
        for c in METRIC_CLASSES:
            m = result[v][c]
            lines.append(
                f"{v:<6} {c:<5} {100 * m['miou']:7.2f} {100 * m['map']:7.2f} "
                f"{100 * m['pooled_iou']:11.2f} {100 * m['pooled_precision']:12.2f}"
            )
    lines.append("mIoU/mAP: mean over (frame, shelf slot) pairs (mAP = mean pixel precision, as in RackLay);")
    lines.append("pooled: one ratio over all pixels' TP/FP/FN. Figures in percent.")
    return "\n".join(lines)


def reference_iou(pred: np.ndarray, gt: np.ndarray) -> float:
    """Foreground IoU of two binary masks as MVRackLay's ``mean_IU(...)[1]``: 1 when both are empty."""
    p, g = np.asarray(pred, bool), np.asarray(gt, bool)
    union = int((p | g).sum())
    return 1.0 if union == 0 else int((p & g).sum()) / union


def reference_precision(pred: np.ndarray, gt: np.ndarray) -> float:
    """Foreground precision as MVRackLay's ``mean_precision(...)[1]`` (classes of the ground truth only).

    Ground truth without the class: the precision of the background class (1, or 0 when ``pred``
    covers every cell); with it: TP / predicted, 0 when nothing is predicted (their NaN -> 0)."""
    p, g = np.asarray(pred, bool), np.asarray(gt, bool)
    if not g.any():
        return 1.0 if not p.all() else 0.0
    npred = int(p.sum())
    return int((p & g).sum()) / npred if npred else 0.0


class ReferenceMetrics:
    """The authors' Table I loop (``eval_vracklay.py``): per target frame and slot, `reference_iou` and
    `reference_precision` of each class summed, then divided by frames x slots. ``weight`` counts a
    frame several times (their windows make the first frame of a sequence the target twice)."""

    def __init__(self) -> None:
        self._sum: dict[tuple[str, str], np.ndarray] = {(v, c): np.zeros(2) for v in VIEWS for c in METRIC_CLASSES}
        self._pairs: dict[str, int] = {v: 0 for v in VIEWS}
        self.frames: dict[str, int] = {v: 0 for v in VIEWS}

    def update(self, pred: np.ndarray, gt: np.ndarray, view: str, weight: int = 1) -> None:
        """Add one frame's ``(R, D, D)`` prediction and truth of ``view``, counted ``weight`` times."""
        check_view(view)
        pred, gt = np.asarray(pred), np.asarray(gt)
        if pred.shape != gt.shape or pred.ndim != 3:
            raise LayoutError(f"reference metric needs (R, D, D) pairs of one shape, got {pred.shape} and {gt.shape}")
        if weight <= 0:
            return
        for cname, cid in METRIC_CLASSES.items():
            for p, g in zip(pred == cid, gt == cid):
                self._sum[view, cname] += weight * np.array([reference_iou(p, g), reference_precision(p, g)])
        self._pairs[view] += weight * pred.shape[0]
        self.frames[view] += weight

    def result(self) -> dict[str, dict[str, dict[str, float]]]:
        """``{view: {class: {miou, map, pairs}}}`` (NaN over zero pairs)."""
        out: dict[str, dict[str, dict[str, float]]] = {}
        for v in VIEWS:
            n = self._pairs[v]
            out[v] = {}
            for c in METRIC_CLASSES:
                iou, prec = (float(x / n) if n else math.nan for x in self._sum[v, c])
                out[v][c] = {"miou": iou, "map": prec, "pairs": n}
        return out


def reference_weights(num_frames: int) -> list[int]:
    """How often each frame of a sequence is a target in MVRackLay's ``temporal_readlines`` windows:
    the targets are f0, f0, f1, ..., f[N-2] (the first frame twice, the last never)."""
    w = [0] * num_frames
    for t in [0, *range(num_frames - 1)][:num_frames]:
        w[t] += 1
    return w


def format_reference_table(result: dict, title: str = "") -> str:
    """The reference metric's Table I as text: rows view x class, columns mIoU / mAP."""
    lines = [title] if title else []
    lines.append(f"{'view':<6} {'class':<5} {'mIoU':>7} {'mAP':>7}")
    for v in VIEWS:
        for c in METRIC_CLASSES:
            m = result[v][c]
            lines.append(f"{v:<6} {c:<5} {100 * m['miou']:7.2f} {100 * m['map']:7.2f}")
    lines.append(
        "reference metric (MVRackLay eval_vracklay.py): all cells, a pair with both masks empty scores 1, "
        "precision over the classes in the ground truth, sums / (frames x slots). Figures in percent."
    )
    return "\n".join(lines)
