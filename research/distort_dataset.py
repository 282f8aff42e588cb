#!/usr/bin/env python3
"""A copy of a generated dataset as a camera with lens distortion would have filmed it: every RGB frame distorted.

    .venv/bin/python research/distort_dataset.py data/heldout128-ss2 data/heldout128-ss2-k010 --k1 -0.10
    mvracklay evaluate --checkpoint mvracklay/models/mvracklay-disc-4.pt --data data/heldout128-ss2-k010 --split all
    .venv/bin/python research/distort_dataset.py data/heldout128-ss2 data/heldout128-ss2-k010u --k1 -0.10 --undistort

Every ``SEQ/rgb/*.png`` (a pinhole render) is resampled to what a lens with the sequence's intrinsics and
the given Brown-Conrady coefficients (OpenCV's k1, k2, p1, p2, k3; `layouts.lens`) shows; the parts of
the lens's view the render does not cover (the corners, for a barrel lens: k1 < 0) take the canonical
fill colour, unless the focal lengths are zoomed so that none is left: each sequence's meta.json
records the zoomed intrinsics (`layouts.lens.covering_intrinsics`, the pinhole image's centre
cropped) with the lens's coefficients beside them. ``--undistort`` then resamples the distorted frame
back to the pinhole image, as ``mvracklay run --camera`` does when the camera file gives the lens: what is left is the cost of the two
resamplings and the lost corners. Everything else is hard-linked, unchanged. ``DISTORTED.json`` at the
root says what was done. Refuses to write into a folder that exists. ``mvracklay evaluate`` scores the
frames as stored (the copy measures what the distortion costs); ``run`` and ``predict`` undistort them
through the lens meta.json records. ``--zoom-only`` writes the baseline: the same zoomed view through a
pinhole (no distortion), so that what the lens does is told apart from what the narrower view does. The
ground truth stays the source's, the unzoomed camera's (its shelf slots): compare the copies of one lens
with each other, not with the source (a narrower camera's own cost wants renders, ``camera.hfov_deg``).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from rgb_copy import write_rgb_copy  # noqa: E402  (this script's folder is on the path)

from layouts.canonical import FILL_RGB  # noqa: E402
from layouts.errors import LayoutError  # noqa: E402
from layouts.fileio import atomic_write_json, load_json  # noqa: E402
from layouts.lens import LENS_KEYS, Lens, covering_intrinsics, distort_image, undistort_image  # noqa: E402
from waresynth.dataset import open_dataset  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("src", type=Path, help="a generated dataset folder")
    ap.add_argument("dst", type=Path, help="the folder to write (must not exist)")
    for k in LENS_KEYS:
        ap.add_argument(f"--{k}", type=float, default=0.0, help=f"the lens's {k} (OpenCV convention)")
    ap.add_argument("--undistort", action="store_true", help="resample each distorted frame back to the pinhole image")
    ap.add_argument(
        "--zoom-only",
        action="store_true",
        help="only crop to the view the lens's zoomed intrinsics give, with no distortion (the baseline)",
    )
    args = ap.parse_args()
    if args.undistort and args.zoom_only:
        ap.error("--undistort and --zoom-only exclude each other")
    try:
        lens = Lens(**{k: getattr(args, k) for k in LENS_KEYS})
    except LayoutError as e:
        ap.error(str(e))
    if lens.is_pinhole:
        ap.error("give --k1, --k2, --p1, --p2 or --k3: a copy through a pinhole lens is the source")
    if args.dst.exists():
        ap.error(f"{args.dst}: exists; give a new folder")
    seqs = open_dataset(args.src).sequences()  # validates the source

    lens_intr = {seq.root: covering_intrinsics(seq.intrinsics, lens) for seq in seqs}

    def change(rgb: np.ndarray, seq) -> np.ndarray:
        out = distort_image(rgb, seq.intrinsics, Lens() if args.zoom_only else lens, FILL_RGB, out=lens_intr[seq.root])
        return undistort_image(out, lens_intr[seq.root], lens, FILL_RGB) if args.undistort else out

    recorded_lens = {} if args.undistort or args.zoom_only else lens.to_dict()  # what the stored frames show

    def finish(root: Path) -> None:
        for seq in seqs:
            meta_path = root / seq.root.relative_to(args.src) / "meta.json"
            meta = load_json(meta_path)
            meta["intrinsics"] = {**lens_intr[seq.root].to_dict(), **recorded_lens}
            meta_path.unlink()  # a hard link: never write through it into the source
            atomic_write_json(meta_path, meta)

    zoom = sorted({round(lens_intr[s.root].fx / s.intrinsics.fx, 4) for s in seqs})
    said = {"source": str(args.src), "lens": lens.to_dict(), "focal_zoom": zoom}
    said |= {"undistorted": args.undistort, "zoom_only": args.zoom_only}
    frames = write_rgb_copy(args.src, args.dst, seqs, change, "distort", ("DISTORTED.json", said), finish)
    print(f"wrote {args.dst}: {len(seqs)} sequences, {frames} frames, lens {lens.to_dict()}, focal zoom {zoom}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
