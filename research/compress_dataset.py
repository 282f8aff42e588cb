#!/usr/bin/env python3
"""A copy of a generated dataset whose RGB frames went through JPEG at ``--quality Q``, as footage from a
compressing camera or a video file shows them (blocks, ringing at edges, smeared colour).

    .venv/bin/python research/compress_dataset.py data/heldout128-ss2 data/heldout128-ss2-q50 --quality 50
    mvracklay evaluate --checkpoint mvracklay/models/mvracklay-disc-4.pt --data data/heldout128-ss2-q50 --split all

Each ``SEQ/rgb/*.png`` is encoded as a baseline JPEG (Pillow, 4:2:0 chroma) and decoded again, and
stored back as PNG so the copy stays a generated dataset; everything else (layouts, depth, semantics,
records) is hard-linked from SRC, or copied where links fail. ``COMPRESSED.json`` at the root says
what was done. Refuses to write into a folder that exists.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from rgb_copy import write_rgb_copy  # noqa: E402  (this script's folder is on the path)

from network.data import jpeg_round_trip  # noqa: E402
from waresynth.dataset import open_dataset  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("src", type=Path, help="a generated dataset folder")
    ap.add_argument("dst", type=Path, help="the folder to write (must not exist)")
    ap.add_argument("--quality", type=int, required=True, help="JPEG quality, 1 (worst) to 95")
    args = ap.parse_args()
    if not 1 <= args.quality <= 95:
        ap.error(f"--quality must be in [1, 95], got {args.quality}")
    if args.dst.exists():
        ap.error(f"{args.dst}: exists; give a new folder")
    seqs = open_dataset(args.src).sequences()  # validates the source
    said = {"source": str(args.src), "jpeg_quality": args.quality}
    write_rgb_copy(
        args.src,
        args.dst,
        seqs,
        lambda rgb, _seq: jpeg_round_trip(rgb, args.quality),
        f"JPEG q{args.quality}",
        ("COMPRESSED.json", said),
    )
    print(f"wrote {args.dst}: {len(seqs)} sequences, frames through JPEG quality {args.quality}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
