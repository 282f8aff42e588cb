#!/usr/bin/env python3
"""What the layouts allow: Table I of two oracles built from the ground truth itself.

    .venv/bin/python research/layout_ceilings.py data/heldout128 [--size 64] [--every 5]

* **resampled to D**: the ground truth resampled to the model's layout size (class area) and back
  (nearest): the ceiling a model predicting at that D can reach.
* **mean box depth**: the ground truth with every box's depth (its extent along Z in the top view)
  replaced by the training distribution's mean, measured from the rack's front edge, X extents and
  the rack footprint kept exact. One frame cannot see how deep a box is unless its top or a side
  shows; this is what a perfect model that never sees it would score.
* **seen box depth (this frame / so far)**: the same, except that stacks whose depth the camera
  sees keep their true footprint: a stack counts as seen when its visible pixels (instance image)
  reach, by the depth image, at least `waresynth.visibility.SEEN` of the way from its front face to its back (a top
  face, a side face or the back edge in view). "This frame" is what a perfect single-frame reader
  could know; "so far" (seen in any frame up to this one) what a perfect sequence reader could.

Scores are `layouts.metrics.FrameScorer` tables (per-(frame, slot) averaged mIoU and "mAP", pooled
beside), over the columns in view, in percent.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from tqdm import tqdm

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from layouts import BOX, SHELF  # noqa: E402
from layouts.metrics import FrameScorer, format_table  # noqa: E402
from layouts.raster import fill_rect  # noqa: E402
from network.data import resample_layout  # noqa: E402
from waresynth.dataset import open_dataset  # noqa: E402
from waresynth.visibility import scene_stacks, seen_stacks  # noqa: E402

SETBACK = 0.04  #: metres: the middle of the generator's default box setback range (0-0.08)
MEAN_DEPTH = 0.475  #: metres: the middle of the generator's default box depth range (0.25-0.7)


def resampled(stack: np.ndarray, size: int) -> np.ndarray:
    d = stack.shape[-1]
    small = resample_layout(stack, size)
    return np.repeat(np.repeat(small, d // size, axis=1), d // size, axis=2) if d % size == 0 else small


def mean_depth(top: np.ndarray, z_extent: float) -> np.ndarray:
    """Each slot's boxes redrawn with the mean depth from the rack's front edge (columns kept)."""
    out = top.copy()
    d = top.shape[-1]
    row_m = z_extent / d
    for r in range(top.shape[0]):
        foot = top[r] > 0
        if not foot.any():
            continue
        near = int(np.max(np.nonzero(foot.any(1))[0]))  # nearest rack row (row 0 = far side)
        cols = (top[r] == BOX).any(0)
        out[r][top[r] == BOX] = SHELF
        lo = near - int(round((SETBACK + MEAN_DEPTH) / row_m)) + 1
        hi = near - int(round(SETBACK / row_m)) + 1
        block = out[r, max(lo, 0) : hi]
        block[:, cols & foot[max(lo, 0) : hi].any(0)] = BOX
    return out


def seen_depth(
    mean: np.ndarray, spec, stacks: list[dict], keep: set[int], levels: list[int], cam_x: float, mid_z: float
) -> np.ndarray:
    """The `mean_depth` oracle ``mean``, except that the stacks in ``keep`` get their true footprints back."""
    out = mean.copy()
    for k in keep:
        st = stacks[k]
        if st["level"] not in levels:
            continue
        r = levels.index(st["level"])
        mask = np.zeros(mean.shape[1:], np.uint8)
        fill_rect(mask, spec, "top", (st["x"] - cam_x, st["z"] - mid_z), (st["w"], st["d"]), 1, yaw=st["yaw"])
        cols = (mask > 0).any(0)
        out[r][:, cols] = np.where(out[r][:, cols] == BOX, SHELF, out[r][:, cols])
        out[r][mask > 0] = BOX
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("data", type=Path, help="a WareSynth dataset (e.g. the held-out set)")
    ap.add_argument("--size", type=int, default=64, help="the model's layout size D")
    ap.add_argument("--every", type=int, default=5, help="score every N-th frame")
    args = ap.parse_args()
    seqs = open_dataset(args.data).sequences()
    res, depth, single, multi = FrameScorer(), FrameScorer(), FrameScorer(), FrameScorer()
    frames = seen_now = seen_sofar = in_view = 0
    for seq in tqdm(seqs, desc="sequences", leave=False):
        stacks = scene_stacks(seq.scene())
        sofar: set[int] = set()
        for i in range(seq.num_frames):
            rec = seq.frame(i)
            cam_x, cam_z = float(rec["camera_position"][0]), float(rec["camera_position"][2])
            now = seen_stacks(stacks, seq.level_depth(i), seq.instance(i), cam_z)
            sofar |= now
            if i % args.every:
                continue
            gt = seq.layouts(i)
            res.update({"top": resampled(gt.top, args.size), "front": resampled(gt.front, args.size)}, gt)
            mean = mean_depth(gt.top, seq.spec.z_extent)
            depth.update({"top": mean, "front": gt.front}, gt)
            levels = [int(sl["level"]) for sl in rec["slots"]]
            mid_z = float(rec["rack_mid_z"])
            for scorer, keep in ((single, now), (multi, sofar)):
                top = seen_depth(mean, seq.spec, stacks, keep, levels, cam_x, mid_z)
                scorer.update({"top": top, "front": gt.front}, gt)
            half = seq.spec.x_extent / 2
            view = [k for k, st in enumerate(stacks) if st["level"] in levels and abs(st["x"] - cam_x) < half]
            in_view += len(view)
            seen_now += sum(k in now for k in view)
            seen_sofar += sum(k in sofar for k in view)
            frames += 1
    name = f"{args.data}: {frames} frames of {len(seqs)} sequences, columns in view"
    print(format_table(res.result()["visible"], f"ground truth resampled to D={args.size} and back -- {name}"))
    print()
    print(format_table(depth.result()["visible"], f"ground truth with mean box depth (top view) -- {name}"))
    print()
    print(
        f"stacks in the layouts' X extent whose depth is seen: {seen_now / max(in_view, 1):.1%} in the frame, "
        f"{seen_sofar / max(in_view, 1):.1%} in this or an earlier frame ({in_view} stack views)"
    )
    for scorer, what in ((single, "in this frame"), (multi, "in this or an earlier frame")):
        print()
        print(format_table(scorer.result()["visible"], f"true depth for stacks seen {what}, mean otherwise -- {name}"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
