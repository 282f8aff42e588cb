#!/usr/bin/env python3
"""What undistorting a frame costs as `run` / `predict` do it when the camera file gives a lens
(`layouts.lens.undistort_frame`: frames wider than 640 px shrunk to 640 first), per frame size, on one
thread, after the first frame (the resampling map is cached).

    .venv/bin/python benchmarks/bench_lens.py [--k1 -0.2] [--repeats 20]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from layouts.camera import Intrinsics  # noqa: E402
from layouts.canonical import FILL_RGB  # noqa: E402
from layouts.lens import Lens, undistort_frame  # noqa: E402

SIZES = ((256, 256), (640, 360), (1280, 720), (1920, 1080))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--k1", type=float, default=-0.2, help="the lens's k1 (the cost hardly depends on it)")
    ap.add_argument("--repeats", type=int, default=20, help="frames timed per size")
    args = ap.parse_args()
    if args.repeats < 1:
        ap.error("--repeats must be >= 1")
    lens = Lens(k1=args.k1)
    rng = np.random.default_rng(0)
    print(f"command: python benchmarks/bench_lens.py --k1 {args.k1:g} --repeats {args.repeats}")
    for w, h in SIZES:
        intr = Intrinsics.from_fov(w, h, 60.0)
        rgb = rng.integers(0, 256, (h, w, 3), dtype=np.uint8)
        t0 = time.perf_counter()
        out = undistort_frame(rgb, intr, lens, FILL_RGB)  # builds and caches the map
        first = time.perf_counter() - t0
        t0 = time.perf_counter()
        for _ in range(args.repeats):
            undistort_frame(rgb, intr, lens, FILL_RGB)
        each = (time.perf_counter() - t0) / args.repeats
        size = f"{out.shape[1]}x{out.shape[0]}"
        print(f"{w}x{h}: {each * 1e3:.1f} ms per frame, {size} out ({first * 1e3:.1f} ms the first, map included)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
