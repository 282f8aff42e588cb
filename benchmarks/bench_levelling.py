#!/usr/bin/env python3
"""What levelling a turned camera costs per frame: reading its angles and the canonical warp.

    .venv/bin/python benchmarks/bench_levelling.py data/heldout128 --sizes 128x128 256x256 1280x720

Frames of a generated dataset, resized to each size, are read for their roll alone
(`network.inference.angle_reading.estimate_roll`, what ``--roll auto`` does per frame) and for roll, pitch and yaw
(`network.inference.angle_reading.estimate_tilt`, ``--pitch auto --yaw auto``), each levelled by the sequence's angles so
far as the leveller does (a prior, so one reading per frame), and warped to the 128x128 canonical
view level, rolled (an affine map) and rolled + pitched + yawed (a homography). Median milliseconds
per frame over the frames; numpy / PIL on one thread, so run it on an idle machine.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
from PIL import Image

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from layouts import Intrinsics  # noqa: E402
from layouts.canonical import CanonicalView  # noqa: E402
from network.inference.angle_reading import estimate_roll, estimate_tilt  # noqa: E402
from network.training.train_data import open_data  # noqa: E402

#: the angles so far (roll, pitch, yaw): each frame is read once, levelled by them, as the leveller does
PRIOR = (1.0, 0.5, -0.5)


def _size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"want WIDTHxHEIGHT, got {text!r}") from None
    if w < 16 or h < 16:
        raise argparse.ArgumentTypeError(f"want at least 16x16, got {text!r}")
    return w, h


def _ms(fn, frames: list[np.ndarray]) -> float:
    fn(frames[0])  # warm-up
    times = []
    for f in frames:
        t0 = time.perf_counter()
        fn(f)
        times.append(time.perf_counter() - t0)
    return 1000 * float(np.median(times))


def _row(frames: list[np.ndarray], intr: Intrinsics, view: CanonicalView) -> list[float]:
    """Milliseconds per frame: roll read, roll / pitch / yaw read, warp level, rolled, rolled + pitched + yawed."""
    d = 2.7
    return [
        _ms(lambda f: estimate_roll(f, prior_deg=PRIOR[0]), frames),
        _ms(lambda f: estimate_tilt(f, intr, PRIOR), frames),
        _ms(lambda f: view.warp(f, intr, d), frames),
        _ms(lambda f: view.warp(f, intr, d, roll_deg=2.0), frames),
        _ms(lambda f: view.warp(f, intr, d, 2.0, 1.0, -1.0), frames),
    ]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("data", type=Path, help="a generated dataset (its first sequence's frames are used)")
    ap.add_argument("--sizes", type=_size, nargs="+", default=[(128, 128), (256, 256), (1280, 720)])
    ap.add_argument("--frames", type=int, default=20, help="frames timed per size")
    args = ap.parse_args()
    if args.frames < 1:
        ap.error("--frames must be >= 1")
    seq = open_data(args.data).sequences()[0]
    n = min(args.frames, seq.num_frames)
    source = [seq.rgb(i) for i in range(n)]
    view = CanonicalView(128, 128, 3.0)
    print(f"{args.data}: {n} frames per size, median ms per frame, one thread")
    print(f"{'frame':>10s} {'read roll':>10s} {'read r/p/y':>11s} {'warp level':>11s} {'rolled':>7s} {'r/p/y':>7s}")
    for w, h in args.sizes:
        frames = [np.asarray(Image.fromarray(f).resize((w, h), Image.BILINEAR)) for f in source]
        cells = _row(frames, seq.intrinsics.scaled(w, h), view)
        print(f"{f'{w}x{h}':>10s} " + " ".join(f"{c:{k}.1f}" for c, k in zip(cells, (10, 11, 11, 7, 7))), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
