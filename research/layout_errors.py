#!/usr/bin/env python3
"""Where a checkpoint's layout errors come from: its predictions with one part replaced by the truth.

    .venv/bin/python research/layout_errors.py runs/mvracklay-disc-4/best.pt data/heldout128 [--every 2]

Runs the model (streaming, row-head anchors) over every sequence and scores Table I
(`layouts.metrics.FrameScorer`, columns in view, mIoU in percent) of:

* **prediction** as it is;
* **true footprint**: inside the shelf's true footprint (shelf or box), predicted background
  becomes shelf; outside it, everything becomes background. What the shelf's extent costs.
* **true footprint depth**: in columns where both have a shelf, the footprint's rows are the
  truth's (boxes kept where predicted inside it). For the top view: what misjudging the rack's
  depth costs; for the front view: what misjudging the clear height costs.
* **true box depth**: in columns where both have a box, the box cells are the truth's (predicted
  box cells elsewhere in the column become shelf). What the boxes' extent along the rows (their
  depth in the top view, their height in the front view) costs once X is right.
* **both**: true footprint depth and true box depth together.
* **true box near edge**: in columns where both have a box, the predicted box cells keep their
  extent but are moved along the rows so that their last row (the top view's front face, the front
  view's bottom) is the truth's. Splits "true box depth" into where a box starts and how far it
  reaches.
* **shifted to the true near edge**: each slot's whole prediction moved along the rows by the
  difference between the truth's and the prediction's footprint near edge (median last row over
  columns). In the top view, whose rows are centred on the rack depth, a misjudged rack depth moves
  the rack front and every box on it; this is what that shift costs.

Then two numbers per frame and slot: the rack depth read off the predicted top view (median over
columns of the footprint's row extent) against the truth, and the same pooled per sequence
(median over its frames), which shows whether the errors average out over a sequence or are a
per-scene bias; and the depth of predicted boxes against the truth's in shared columns. Both are
broken down by where the shelf is seen from: the board's height relative to the camera (its top
face is visible only from above, the underside only from below) and, for boxes, how far the
column is from the optical axis (a box's side face shows only off-axis). ``--seen`` (generated
data only) also breaks box depth down by whether the stack's depth is seen (`waresynth.visibility`,
the test of `layout_ceilings.py`): in this frame, only in an earlier one, or never so far. Depth
read well where this frame sees it but not where only an earlier frame did points at the memory;
read badly in both, at the per-frame reading. ``--read-depth`` scores the layouts after the
checkpoint's depth heads redraw them (what `mvracklay evaluate` scores by default) instead of the
decoder's own; for a box-depth head that reads fronts (the `fit-box-depth` stage's `--front`) it adds a line with the
decoder's box fronts kept (the head's backs and rack depth still applied): what the head's fronts are worth.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from layouts import BOX, SHELF  # noqa: E402
from layouts.metrics import FrameScorer  # noqa: E402
from layouts.rackdepth import front_rows, shift_rows  # noqa: E402
from network.checkpoint import load_model  # noqa: E402
from network.inference.predictor import Predictor, sequence_camera  # noqa: E402
from network.training.train_data import open_data  # noqa: E402
from waresynth.visibility import SeenTracker  # noqa: E402

CASES = (
    "prediction",
    "true footprint",
    "true footprint depth",
    "true box depth",
    "both",
    "true box near edge",
    "shifted to the true near edge",
)


def true_footprint(p: np.ndarray, g: np.ndarray) -> np.ndarray:
    out = p.copy()
    out[(g > 0) & (out == 0)] = SHELF
    out[g == 0] = 0
    return out


def true_footprint_depth(p: np.ndarray, g: np.ndarray) -> np.ndarray:
    out = p.copy()
    both = ((p > 0).any(1) & (g > 0).any(1))[:, None, :]  # (R, 1, D) columns where both have a shelf
    out[both & (g > 0) & (out == 0)] = SHELF
    out[both & (g == 0)] = 0
    return out


def true_box_depth(p: np.ndarray, g: np.ndarray) -> np.ndarray:
    out = p.copy()
    both = ((p == BOX).any(1) & (g == BOX).any(1))[:, None, :]
    out[both & (p == BOX)] = SHELF
    out[both & (g == BOX)] = BOX
    return out


def both_depths(p: np.ndarray, g: np.ndarray) -> np.ndarray:
    return true_box_depth(true_footprint_depth(p, g), g)


def true_box_near_edge(p: np.ndarray, g: np.ndarray) -> np.ndarray:
    out = p.copy()
    rows = np.arange(p.shape[1])[:, None]
    for r in range(p.shape[0]):
        pb, gb = p[r] == BOX, g[r] == BOX
        for c in np.nonzero(pb.any(0) & gb.any(0))[0]:
            shift = int(rows[gb[:, c], 0].max() - rows[pb[:, c], 0].max())
            cells = np.nonzero(pb[:, c])[0] + shift
            out[r][pb[:, c], c] = SHELF
            out[r][cells[(cells >= 0) & (cells < p.shape[1])], c] = BOX
    return out


def shifted_to_true_near_edge(p: np.ndarray, g: np.ndarray) -> np.ndarray:
    out = p.copy()
    for r in range(p.shape[0]):
        pf, gf = p[r] > 0, g[r] > 0
        if not (pf.any() and gf.any()):
            continue
        out[r] = shift_rows(p[r], int(np.median(front_rows(gf)) - np.median(front_rows(pf))))
    return out


def extent_rows(mask: np.ndarray) -> np.ndarray:
    """Per column with any cell set: last row - first row + 1 (``(cols,)``)."""
    cols = np.nonzero(mask.any(0))[0]
    rows = np.arange(mask.shape[0])[:, None]
    m = mask[:, cols]
    hi = np.where(m, rows, -1).max(0)
    lo = np.where(m, rows, mask.shape[0]).min(0)
    return hi - lo + 1


#: the extra line of a head that reads box fronts: its layouts with the decoder's fronts instead
OWN_FRONTS = "decoder's box fronts"

FIXES = (
    None,
    true_footprint,
    true_footprint_depth,
    true_box_depth,
    both_depths,
    true_box_near_edge,
    shifted_to_true_near_edge,
)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("checkpoint", type=Path)
    ap.add_argument("data", type=Path, help="a dataset with ground truth (e.g. the held-out set)")
    ap.add_argument("--every", type=int, default=2, help="score every N-th frame (all frames are run)")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--seen", action="store_true", help="box depth by whether the stack's depth is seen (see above)")
    ap.add_argument(
        "--read-depth",
        action="store_true",
        help="score the layouts after the checkpoint's depth heads (rack depth, carried box backs) redraw them",
    )
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    model, record = load_model(args.checkpoint)
    model.eval()
    seqs = open_data(args.data).sequences()
    scorers = {c: FrameScorer() for c in (*CASES, OWN_FRONTS)}
    has_fronts = False
    rack = []  # (sequence, predicted depth m, true depth m, board metres below the camera) per frame and slot
    boxes = []  # (predicted, true, board metres below the camera, |X| m, seen) box depth per shared box column
    fronts = []  # (box front error, its slot's rack front error) in metres per shared box column, top view
    frames = 0
    bar = tqdm(total=sum(s.num_frames for s in seqs), desc="predict", unit="frame", leave=False)
    for q, seq in enumerate(seqs):
        row_m = seq.spec.z_extent / seq.spec.size
        # the decoder's own depths unless --read-depth (then the heads' redrawn layouts, as `evaluate`)
        pred = Predictor(model, sequence_camera(seq), read_depth=args.read_depth, fuse_tau=0)
        seen = SeenTracker(seq) if args.seen else None
        for i, out in enumerate(pred.run((seq.rgb(i) for i in range(seq.num_frames)), "stream")):
            bar.update(1)
            if seen is not None:
                seen.add(i)
            if i % args.every:
                continue
            gt = seq.layouts(i)
            p = out.layouts(seq.spec)
            if out.box_front is not None:
                has_fronts = True
                own = replace(out, box_front=None).layouts(seq.spec)
                scorers[OWN_FRONTS].update(own, gt)
            vis = gt.visible if gt.visible is not None else np.ones(seq.spec.size, bool)
            rec = seq.frame(i)
            cam_y = float(rec["camera_position"][1])
            below = [float(sl["board_top_y"]) - cam_y for sl in rec.get("slots", [])]
            col_x = np.abs(seq.spec.col_to_x(np.arange(seq.spec.size) + 0.5))[vis]
            labels = seen.labels(i) if seen is not None else np.full((gt.top.shape[0], seq.spec.size), -1)
            for case, fn in zip(CASES, FIXES):
                scorers[case].update(p if fn is None else {v: fn(p[v], getattr(gt, v)) for v in ("top", "front")}, gt)
            for r in range(gt.top.shape[0]):
                pt, g = p["top"][r][:, vis], gt.top[r][:, vis]
                elev = below[r] if r < len(below) else np.nan
                if (pt > 0).any() and (g > 0).any():
                    rack.append(
                        (q, np.median(extent_rows(pt > 0)) * row_m, np.median(extent_rows(g > 0)) * row_m, elev)
                    )
                shared = (pt == BOX).any(0) & (g == BOX).any(0)
                if shared.any():
                    pe = extent_rows((pt == BOX) & shared[None, :])
                    ge = extent_rows((g == BOX) & shared[None, :])
                    seen_cols = labels[r][vis][shared]
                    boxes.extend(zip(pe * row_m, ge * row_m, np.full(pe.size, elev), col_x[shared], seen_cols))
                    rack_front = np.median(front_rows(pt > 0)) - np.median(front_rows(g > 0))
                    box_front = front_rows((pt == BOX) & shared[None, :]) - front_rows((g == BOX) & shared[None, :])
                    fronts.extend(zip(box_front * row_m, np.full(box_front.size, rack_front * row_m)))
            frames += 1
    bar.close()
    print(f"{record.get('variant')} ({args.checkpoint}) on {args.data}: {frames} frames of {len(seqs)} sequences")
    print(f"{'mIoU, columns in view':28s} {'top rack':>9s} {'top box':>8s} {'front rack':>11s} {'front box':>10s}")
    for case in (*CASES, OWN_FRONTS):
        if case == OWN_FRONTS and not has_fronts:
            continue
        v = scorers[case].result()["visible"]
        cells = [v[view][c]["miou"] * 100 for view in ("top", "front") for c in ("rack", "box")]
        print(f"{case:28s} {cells[0]:9.1f} {cells[1]:8.1f} {cells[2]:11.1f} {cells[3]:10.1f}")
    if rack:
        q, pd, td, el = (np.array(x) for x in zip(*rack))
        pooled = np.array([np.median(pd[q == k]) for k in q])  # each frame's sequence median
        print(
            f"rack depth (top view footprint): true {td.mean():.2f} +- {td.std():.2f} m; per frame: error "
            f"{np.abs(pd - td).mean() * 100:.1f} cm mean abs, bias {(pd - td).mean() * 100:+.1f} cm, "
            f"corr {np.corrcoef(pd, td)[0, 1]:.2f}; sequence median: error {np.abs(pooled - td).mean() * 100:.1f} cm"
        )
        for name, sel in elevation_bins(el):
            if sel.sum() > 1:
                print(
                    f"  board {name:26s} {sel.sum():6d} slots: error {np.abs(pd - td)[sel].mean() * 100:5.1f} cm, "
                    f"corr {_corr(pd[sel], td[sel]):.2f}"
                )
    if boxes:
        pb, tb, el, ax, sn = (np.array(x) for x in zip(*boxes))
        print(
            f"box depth (shared box columns): true {tb.mean():.2f} +- {tb.std():.2f} m, predicted "
            f"{pb.mean():.2f} +- {pb.std():.2f} m; error {np.abs(pb - tb).mean() * 100:.1f} cm mean abs, "
            f"corr {np.corrcoef(pb, tb)[0, 1]:.2f}"
        )
        bf, rf = (np.array(x) for x in zip(*fronts))
        print(
            f"box front (shared box columns, + = nearer the camera): error {np.abs(bf).mean() * 100:.1f} cm mean abs, "
            f"bias {bf.mean() * 100:+.1f} cm; its slot's rack front: error {np.abs(rf).mean() * 100:.1f} cm, "
            f"corr between the two {_corr(bf, rf):.2f}"
        )
        lateral = [(f"|X| < {LATERAL[0]} m", ax < LATERAL[0])]
        lateral += [(f"|X| {a}-{b} m", (ax >= a) & (ax < b)) for a, b in zip(LATERAL, LATERAL[1:])]
        lateral += [(f"|X| >= {LATERAL[-1]} m", ax >= LATERAL[-1])]
        seen_bins = [(f"stack depth {n}", sn == k) for k, n in SEEN_LABELS.items()] if args.seen else []
        for name, sel in elevation_bins(el) + lateral + seen_bins:
            if sel.sum() > 1:
                print(
                    f"  {name:32s} {sel.sum():6d} columns: error {np.abs(pb - tb)[sel].mean() * 100:5.1f} cm, "
                    f"corr {_corr(pb[sel], tb[sel]):.2f}"
                )
    return 0


#: board height below the camera (metres; negative = above it) and lateral offset bins of the breakdowns
ELEVATION = (-0.4, 0.4)
LATERAL = (0.5, 1.0)
#: `waresynth.visibility.SeenTracker.labels` values
SEEN_LABELS = {2: "seen in this frame", 1: "seen only earlier", 0: "not seen yet"}


def elevation_bins(el: np.ndarray) -> list[tuple[str, np.ndarray]]:
    lo, hi = ELEVATION
    return [
        (f"> {-lo} m above the camera", el < lo),
        (f"within {hi} m of eye level", (el >= lo) & (el <= hi)),
        (f"> {hi} m below the camera", el > hi),
    ]


def _corr(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.corrcoef(a, b)[0, 1]) if a.std() > 0 and b.std() > 0 else float("nan")


if __name__ == "__main__":
    sys.exit(main())
