#!/usr/bin/env python3
"""A copy of a generated dataset as a dim, noisy camera moving fast would have filmed it.

    .venv/bin/python research/degrade_frames.py data/heldout256 /tmp/heldout256-dim --limit 12
    mvracklay eval-reconstruction /tmp/heldout256-dim --checkpoint mvracklay-disc-4-256 --noisy --limit 12 --json

Every ``SEQ/rgb/*.png`` of the first ``--limit`` sequences is darkened (a gain drawn per sequence from
``--gain``, then a gamma of 1.2: shadows sink more than highlights), given signal-dependent noise
(shot noise of variance ``--shot * x`` plus read noise of ``--read`` standard deviation, on a 0-1
scale), blurred along the row by a box of ``--blur`` pixels (a length drawn per sequence: the camera
moves along X) and stored through JPEG at ``--quality`` (then written back as PNG, as the generator
stores frames). Everything else is hard-linked, unchanged (the ground truth is the source's).
``DEGRADED.json`` at the root records the settings. Seeded: the same arguments give the same copy.
"""

from __future__ import annotations

import argparse
import io
import sys
from pathlib import Path

import numpy as np
from PIL import Image

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from rgb_copy import write_rgb_copy  # noqa: E402  (this script's folder is on the path)

from waresynth.dataset import open_dataset  # noqa: E402


def degrade(rgb: np.ndarray, rng: np.random.Generator, gain: float, blur: int, args: argparse.Namespace) -> np.ndarray:
    """One frame ``(H, W, 3)`` uint8 as the dim camera sees it (uint8)."""
    x = gain * (rgb.astype(np.float64) / 255.0) ** 1.2
    sigma = np.sqrt(args.shot * x + args.read**2)
    x = np.clip(x + rng.normal(size=x.shape) * sigma, 0.0, 1.0)
    if blur > 1:
        k = np.ones(blur) / blur
        pad = np.pad(x, ((0, 0), (blur // 2, blur - 1 - blur // 2), (0, 0)), mode="edge")
        x = sum(k[i] * pad[:, i : i + x.shape[1]] for i in range(blur))
    out = (np.clip(x, 0, 1) * 255 + 0.5).astype(np.uint8)
    buf = io.BytesIO()
    Image.fromarray(out).save(buf, format="JPEG", quality=args.quality)
    buf.seek(0)
    with Image.open(buf) as im:
        return np.asarray(im.convert("RGB"))


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("src", type=Path)
    p.add_argument("dst", type=Path)
    p.add_argument("--limit", type=int, default=0, help="degrade the first N sequences only (0 = all)")
    p.add_argument("--gain", type=float, nargs=2, default=(0.3, 0.5), help="range of the per-sequence gain")
    p.add_argument("--shot", type=float, default=0.004, help="shot-noise variance per unit signal")
    p.add_argument("--read", type=float, default=0.02, help="read-noise standard deviation")
    p.add_argument("--blur", type=int, nargs=2, default=(3, 6), help="range of the horizontal blur length (px)")
    p.add_argument("--quality", type=int, default=40, help="JPEG quality")
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args(argv)
    if args.dst.exists():
        p.error(f"{args.dst}: exists")
    seqs = open_dataset(args.src).sequences()
    seqs = seqs[: args.limit] if args.limit else seqs
    looks: dict[str, tuple[float, int]] = {}
    rngs: dict[str, np.random.Generator] = {}
    for k, seq in enumerate(seqs):
        r = np.random.default_rng([args.seed, k])
        looks[seq.name] = (float(r.uniform(*args.gain)), int(r.integers(args.blur[0], args.blur[1] + 1)))
        rngs[seq.name] = r

    def change(rgb: np.ndarray, seq) -> np.ndarray:
        gain, blur = looks[seq.name]
        return degrade(rgb, rngs[seq.name], gain, blur, args)

    said = {k: v for k, v in vars(args).items() if k not in ("src", "dst")}
    said["looks"] = {n: {"gain": g, "blur": b} for n, (g, b) in looks.items()}
    n = write_rgb_copy(args.src, args.dst, seqs, change, "degrade", ("DEGRADED.json", said))
    print(f"{n} frames degraded -> {args.dst}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
