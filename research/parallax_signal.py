#!/usr/bin/env python3
"""How much depth the plane sweep of `network.heads.parallax` finds in two frames, with no learning at all.

    .venv/bin/python research/parallax_signal.py data/heldout128 [--sequences 12] [--gap 1] [--true-motion]

For frame pairs ``gap`` frames apart (every 2nd frame), both frames are warped into the model's
canonical view, the camera step is read from the images (`network.model.motion`; ``--true-motion``: from
the poses), and `network.heads.parallax.plane_sweep` scores every swept plane. Each pixel's best plane
(winner takes all) is compared with its true ``rho = d / Z`` (camera-to-rack distance over the
pixel's depth from the generator's depth image), on the 30 % of pixels whose cost varies most over
the planes (the textured ones). Prints the correlation and the mean best plane per band of true
rho: what a per-pixel reading finds before any network aggregates it.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from layouts.canonical import CanonicalView  # noqa: E402
from network.heads.parallax import RATIOS, plane_sweep  # noqa: E402
from network.model.motion import camera_shift, motion_signature  # noqa: E402
from network.preprocess import canonical_image, frame_camera, to_tensor  # noqa: E402
from waresynth.dataset import open_dataset  # noqa: E402

BANDS = ((0.6, 0.75), (0.75, 0.85), (0.85, 0.95), (0.95, 1.1))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("data", type=Path, help="a generated dataset folder (with depth images and camera poses)")
    ap.add_argument("--sequences", type=int, default=12, help="how many sequences to read (manifest order)")
    ap.add_argument("--gap", type=int, default=1, help="frames between the two of a pair")
    ap.add_argument("--size", type=int, default=128, help="canonical image size (square)")
    ap.add_argument("--true-motion", action="store_true", help="camera steps from the poses, not the images")
    ap.add_argument("--threads", type=int, default=1)
    args = ap.parse_args()
    torch.set_num_threads(max(1, args.threads))
    if args.gap < 1 or args.sequences < 1:
        ap.error("--gap and --sequences must be >= 1")
    ds = open_dataset(args.data)
    view = CanonicalView(args.size, args.size, ds.spec.x_extent)
    rho = np.asarray(RATIOS)
    true_all, best_all, motion_err = [], [], []
    for seq in ds.sequences()[: args.sequences]:
        pos = np.asarray(seq.camera_positions(), dtype=np.float64)
        for t in range(args.gap, seq.num_frames, 2):
            ims = []
            for i in (t - args.gap, t):
                intr, dist = frame_camera(seq, i)
                ims.append(to_tensor(canonical_image(seq.rgb(i), view, intr, dist))[None])
            true_dx = float(pos[t, 0] - pos[t - args.gap, 0])
            dx = camera_shift(motion_signature(ims[0]), motion_signature(ims[1]), view)
            motion_err.append(abs(float(dx) - true_dx))
            if args.true_motion:
                dx = torch.tensor([true_dx])
            cost = plane_sweep(ims[1], ims[0], dx, view)[0].numpy()  # (K, H, W)
            depth = seq.depth(t)  # (intr, dist): frame t's, from the loop above
            u, v = view.source_coords(intr, dist)  # nearest source pixel of each canonical pixel
            ui = np.clip(np.floor(u).astype(int), 0, depth.shape[1] - 1)
            vi = np.clip(np.floor(v).astype(int), 0, depth.shape[0] - 1)
            z = depth[vi[:, None], ui[None, :]]
            spread = cost.max(0) - cost.min(0)
            keep = (spread > np.quantile(spread, 0.7)) & (z > 0.3)
            true_all.append(dist / z[keep])
            best_all.append(rho[cost.argmin(0)][keep])
    tr, best = np.concatenate(true_all), np.concatenate(best_all)
    src = "poses" if args.true_motion else "images"
    print(
        f"{args.data}: {len(motion_err)} pairs {args.gap} frame(s) apart, camera step from the {src} "
        f"(image estimate off by {100 * np.median(motion_err):.1f} cm median)"
    )
    print(f"textured pixels {tr.size}: corr(true rho, best plane) {np.corrcoef(tr, best)[0, 1]:.3f}")
    for lo, hi in BANDS:
        m = (tr >= lo) & (tr < hi)
        if m.any():
            print(f"  true rho {lo:.2f}-{hi:.2f}: {int(m.sum()):8d} px, best plane {best[m].mean():.3f} mean")


if __name__ == "__main__":
    main()
