#!/usr/bin/env python3
"""How well `network.model.motion` reads the camera's motion along the row from consecutive frames.

    .venv/bin/python research/motion_estimate.py data/heldout128 [--sequences 24] [--size 128]

Each frame is warped into the canonical view (as the model sees it), the motion between
consecutive frames is estimated from the images alone and compared with the ground-truth camera
positions. Prints the absolute error (median, mean, 90th percentile, max, share above 10 cm),
the bias (estimate minus truth), the per-sequence bias and the mean true motion, in metres per
frame, and the share of the camera's path the estimate reads over each sequence.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from layouts.canonical import CanonicalView  # noqa: E402
from network.model.motion import camera_shift, motion_signature  # noqa: E402
from network.preprocess import canonical_image, frame_camera, to_tensor  # noqa: E402
from waresynth.dataset import open_dataset  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("data", type=Path, help="a generated dataset folder (with camera poses)")
    ap.add_argument("--sequences", type=int, default=24, help="how many sequences to read (manifest order)")
    ap.add_argument("--size", type=int, default=128, help="canonical image size (square)")
    args = ap.parse_args()
    ds = open_dataset(args.data)
    view = CanonicalView(args.size, args.size, ds.spec.x_extent)
    errors, truth, ratio = [], [], []
    for seq in ds.sequences()[: args.sequences]:
        pos = np.asarray(seq.camera_positions(), dtype=np.float64)
        imgs = torch.cat(
            [to_tensor(canonical_image(seq.rgb(i), view, *frame_camera(seq, i)))[None] for i in range(seq.num_frames)]
        )
        sig = motion_signature(imgs)
        est = camera_shift(sig[:-1], sig[1:], view).double().numpy()
        true = np.diff(pos[:, 0])
        errors.append(est - true)
        truth.append(true)
        ratio.append(est.sum() / true.sum())  # the share of the camera's path the estimate reads
    ratio = np.array(ratio)
    bias = np.abs([np.mean(x) for x in errors])  # per sequence: how much of the error is a steady bias
    e, t = np.concatenate(errors), np.concatenate(truth)
    a = np.abs(e)
    print(
        f"{args.data}: {len(e)} frame pairs of {min(args.sequences, len(ds.sequences()))} sequences, canonical {view.width}x{view.height}"
    )
    print(f"  true motion per frame: mean |dx| {np.abs(t).mean():.3f} m")
    print(
        f"  abs error: median {np.median(a):.3f} m, mean {a.mean():.3f}, p90 {np.percentile(a, 90):.3f}, "
        f"max {a.max():.3f}; above 0.10 m: {100 * (a > 0.1).mean():.1f} %; bias {e.mean():+.4f} m"
    )
    print(
        f"  per-sequence |mean error|: median {np.median(bias):.3f} m, max {bias.max():.3f} "
        f"(a steady per-scene bias is parallax: floor and far background move unlike the rack front)"
    )
    print(
        f"  path read / path travelled per sequence: median {np.median(ratio):.3f}, "
        f"range {ratio.min():.2f} to {ratio.max():.2f}"
    )


if __name__ == "__main__":
    main()
