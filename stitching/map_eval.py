"""Evaluate a `WarehouseMap` against ground-truth cuboids (the generator's ``scene.json``).

Alignment uses only the first frame's record: the map origin is placed at (first camera X,
slot 0's ``board_top_y``, ``rack_mid_z``). No later ground truth is used, so the drift of the
estimated shifts shows in every figure.

Unit of evaluation: a ground-truth *stack* (boxes sharing ``stack_id``; their union is a cuboid),
since layouts cannot separate stacked boxes. Per shelf level, reconstructed cuboids and stacks
are matched one-to-one (Hungarian on exact 3D IoU, `stitching.geometry.iou_3d`); a match with
IoU >= ``iou_threshold`` is a true positive.

Which stacks count: those whose footprint lies wholly inside the X range some frame saw
(``covered``). Stacks only partly inside it are *ignored*: reconstructed boxes overlapping them,
or lying outside the covered range, are neither true nor false positives.

* precision = TP / (TP + FP), recall = TP / counted stacks, mean IoU over the true positives;
* box count: per shelf (rack x level) touching the covered range, counted stacks vs.
  reconstructed boxes whose centre lies in the rack's X range (ignored ones left out);
* free length: per such shelf, inside the covered part of the rack: rack length minus the union of
  the boxes' X extents, map vs. ground truth, mean absolute error;
* drift: |estimated camera offset - true camera X displacement| at the last frame (and the max).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import linear_sum_assignment

from layouts.errors import InputError
from stitching.geometry import Cuboid, footprint_intersection, iou_matrix, stacks_of
from stitching.warehouse_map import WarehouseMap, origin_from_record


@dataclass
class EvalResult:
    precision: float
    recall: float
    mean_iou: float
    tp: int
    fp: int
    fn: int
    ignored_gt: int
    shelves: int
    count_exact: int
    free_length_mae: float
    drift_end: float
    drift_max: float
    per_shelf: list[dict] = field(default_factory=list)

    @property
    def count_accuracy(self) -> float:
        return self.count_exact / self.shelves if self.shelves else 1.0

    def to_dict(self) -> dict:
        d = {k: getattr(self, k) for k in self.__dataclass_fields__ if k != "per_shelf"}
        d["count_accuracy"] = self.count_accuracy
        d["per_shelf"] = self.per_shelf
        return d


def _shift(c: Cuboid, o: tuple[float, float, float]) -> Cuboid:
    return Cuboid((c.center[0] - o[0], c.center[1] - o[1], c.center[2] - o[2]), c.size, c.yaw)


def _union_length(intervals: list[tuple[float, float]], lo: float, hi: float) -> float:
    iv = sorted((max(a, lo), min(b, hi)) for a, b in intervals if b > lo and a < hi)
    total, cur0, cur1 = 0.0, None, None
    for a, b in iv:
        if cur1 is None or a > cur1:
            if cur1 is not None:
                total += cur1 - cur0
            cur0, cur1 = a, b
        else:
            cur1 = max(cur1, b)
    if cur1 is not None:
        total += cur1 - cur0
    return total


def _level_stacks(
    scene: dict, level: int, origin: tuple[float, float, float], cov: tuple[float, float]
) -> tuple[list[Cuboid], list[int], list[bool], list[tuple[str, float, float, int]]]:
    """Ground-truth stacks of one shelf level in map coordinates: the cuboids, the index of each one's rack,
    whether each counts (wholly inside the covered range ``cov``), and the racks ``(id, x0, x1, index)``."""
    cov_lo, cov_hi = cov
    gt, gt_rack, gt_counted = [], [], []
    racks = []
    for rack in scene.get("racks", []):
        shelves = [s for s in rack.get("shelves", []) if int(s.get("level", -1)) == level]
        if not shelves:
            continue
        rx0, rx1 = float(rack["x_min"]) - origin[0], float(rack["x_max"]) - origin[0]
        racks.append((rack["id"], rx0, rx1, len(racks)))
        for c in stacks_of(shelves[0]):
            c = _shift(c, origin)
            x0, x1 = c.x_range()
            gt.append(c)
            gt_rack.append(len(racks) - 1)
            gt_counted.append(x0 >= cov_lo and x1 <= cov_hi)
    return gt, gt_rack, gt_counted, racks


def _match_level(
    pred: list[Cuboid], gt: list[Cuboid], gt_counted: list[bool], iou_threshold: float, cov: tuple[float, float]
) -> tuple[list[str], set[int], list[float]]:
    """One level's reconstructed boxes matched to its stacks: each box's status (tp, fp or ignored), the matched
    stacks and the IoUs of the true positives."""
    cov_lo, cov_hi = cov
    m = iou_matrix(pred, gt) if pred and gt else np.zeros((len(pred), len(gt)))
    status = ["fp"] * len(pred)
    matched_gt: set[int] = set()
    ious: list[float] = []
    if pred and gt:
        ri, ci = linear_sum_assignment(-m)
        for i, j in zip(ri, ci):
            if m[i, j] >= iou_threshold:
                matched_gt.add(int(j))
                status[i] = "tp" if gt_counted[j] else "ignored"
                if gt_counted[j]:
                    ious.append(float(m[i, j]))
    for i in range(len(pred)):
        if status[i] != "fp":
            continue
        x0, x1 = pred[i].x_range()
        near_ignored = any(not gt_counted[j] and footprint_intersection(pred[i], gt[j]) > 0 for j in range(len(gt)))
        if near_ignored or x1 <= cov_lo or x0 >= cov_hi or (x0 < cov_lo or x1 > cov_hi):
            status[i] = "ignored"
    return status, matched_gt, ious


def _drift(wmap: WarehouseMap, records: list[dict], origin: tuple[float, float, float]) -> list[float]:
    """|estimated camera offset - true camera X displacement| per scored frame."""
    true_dx = [float(r["camera_position"][0]) - origin[0] for r in records]
    if len(wmap.steps) == len(records):
        return [abs(s.offset - t) for s, t in zip(wmap.steps, true_dx)]
    # a bounded step history (MergeConfig.keep_steps): score the frames it kept, by frame index
    by_index = {int(r.get("index", i)): t for i, (r, t) in enumerate(zip(records, true_dx))}
    return [abs(s.offset - by_index[s.frame]) for s in wmap.steps if s.frame in by_index]


def evaluate_map(
    wmap: WarehouseMap,
    scene: dict,
    records: list[dict],
    covered: tuple[float, float],
    iou_threshold: float = 0.5,
) -> EvalResult:
    """Compare ``wmap`` with ``scene`` (world frame); ``covered`` is the world X range frames saw."""
    if not records:
        raise InputError("evaluation needs at least one frame record")
    origin = origin_from_record(records[0])
    slot_level = {r: int(s["level"]) for r, s in enumerate(records[0]["slots"])}
    cov_lo, cov_hi = covered[0] - origin[0], covered[1] - origin[0]
    tp = fp = fn = ignored_total = 0
    ious: list[float] = []
    per_shelf: list[dict] = []
    free_err: list[float] = []
    map_shelves = wmap.shelves()
    for slot, level in slot_level.items():
        pred = [b.cuboid for s in map_shelves if s.slot == slot for b in s.boxes]
        pred_x = [c.x_range() for c in pred]
        gt, gt_rack, gt_counted, racks = _level_stacks(scene, level, origin, (cov_lo, cov_hi))
        status, matched_gt, level_ious = _match_level(pred, gt, gt_counted, iou_threshold, (cov_lo, cov_hi))
        ious += level_ious
        tp += status.count("tp")
        fp += status.count("fp")
        fn += sum(1 for j in range(len(gt)) if gt_counted[j] and j not in matched_gt)
        ignored_total += sum(1 for j in range(len(gt)) if not gt_counted[j])
        for rid, rx0, rx1, k in racks:
            lo, hi = max(rx0, cov_lo), min(rx1, cov_hi)
            if hi <= lo:
                continue
            gt_n = sum(1 for j in range(len(gt)) if gt_rack[j] == k and gt_counted[j])
            pred_n = sum(1 for i in range(len(pred)) if status[i] != "ignored" and rx0 <= pred[i].center[0] <= rx1)
            gt_free = (hi - lo) - _union_length([gt[j].x_range() for j in range(len(gt)) if gt_rack[j] == k], lo, hi)
            pr_free = (hi - lo) - _union_length(
                [pred_x[i] for i in range(len(pred)) if rx0 - 0.2 <= pred[i].center[0] <= rx1 + 0.2], lo, hi
            )
            free_err.append(abs(gt_free - pr_free))
            per_shelf.append(
                {
                    "rack": rid,
                    "level": level,
                    "slot": slot,
                    "gt_boxes": gt_n,
                    "pred_boxes": pred_n,
                    "count_exact": gt_n == pred_n,
                    "gt_free_length": round(gt_free, 4),
                    "pred_free_length": round(pr_free, 4),
                }
            )
    errs = _drift(wmap, records, origin)
    return EvalResult(
        precision=tp / (tp + fp) if tp + fp else 1.0,
        recall=tp / (tp + fn) if tp + fn else 1.0,
        mean_iou=float(np.mean(ious)) if ious else 0.0,
        tp=tp,
        fp=fp,
        fn=fn,
        ignored_gt=ignored_total,
        shelves=len(per_shelf),
        count_exact=sum(1 for s in per_shelf if s["count_exact"]),
        free_length_mae=float(np.mean(free_err)) if free_err else 0.0,
        drift_end=errs[-1] if errs else 0.0,
        drift_max=max(errs) if errs else 0.0,
        per_shelf=per_shelf,
    )


def covered_range(records: list[dict], visible_x: list[tuple[float, float]]) -> tuple[float, float]:
    """World X range seen by any frame: camera X plus each frame's visible X range."""
    if len(records) != len(visible_x) or not records:
        raise InputError(f"need one visible range per frame record ({len(visible_x)} vs {len(records)})")
    xs = [float(r["camera_position"][0]) for r in records]
    return min(x + v[0] for x, v in zip(xs, visible_x)), max(x + v[1] for x, v in zip(xs, visible_x))
