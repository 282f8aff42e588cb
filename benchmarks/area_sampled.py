#!/usr/bin/env python3
"""A copy of a generated dataset whose RGB frames are area-sampled: each pixel the mean of 2x2 pixels of the
same dataset rendered at twice the size (same seeds and config), as a camera that integrates light over
its pixels sees it. The renderer samples each pixel at its centre, so its edges are staircases; a real
sensor (and a frame resampled bilinearly, as `turn_dataset.py` makes) has sub-pixel edges.

    mvracklay generate data/heldout256-yaw3r --sequences 24 --frames 50 --size 256 --seed 202 --config yaw3.json
    .venv/bin/python benchmarks/area_sampled.py data/heldout128-yaw3r data/heldout256-yaw3r data/heldout128-yaw3r-aa

Everything but ``SEQ/rgb/*.png`` (layouts, depth, semantics, records) is hard-linked from SRC, or copied
where links fail. Refuses to write into a folder that exists, or a pair of datasets whose scenes differ.
"""

from __future__ import annotations

import argparse
import shutil
import sys
from pathlib import Path

import numpy as np
from PIL import Image
from tqdm import tqdm

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from turn_dataset import _link_or_copy  # noqa: E402  (this script's folder is on the path)

from waresynth.dataset import open_dataset  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("src", type=Path, help="a generated dataset (its frames are replaced)")
    ap.add_argument("double", type=Path, help="the same dataset generated at twice the image size")
    ap.add_argument("dst", type=Path, help="the folder to write (must not exist)")
    args = ap.parse_args()
    if args.dst.exists():
        ap.error(f"{args.dst}: exists; give a new folder")
    low, high = open_dataset(args.src), open_dataset(args.double)
    (w, h), (w2, h2) = low.image_size, high.image_size
    if (w2, h2) != (2 * w, 2 * h):
        ap.error(f"{args.double}: images {w2}x{h2}, want twice {args.src}'s {w}x{h}")
    seqs = low.sequences()
    for seq in seqs:
        if seq.scene() != high.sequence(seq.name).scene():
            ap.error(f"{seq.name}: the two datasets' scenes differ (generate both with the same seed and config)")
    tmp = args.dst.with_name(args.dst.name + ".partial")
    shutil.rmtree(tmp, ignore_errors=True)
    shutil.copytree(args.src, tmp, copy_function=_link_or_copy)
    with tqdm(total=sum(s.num_frames for s in seqs), desc="area-sample", unit="frame") as bar:
        for seq in seqs:
            big = high.sequence(seq.name)
            for i in range(seq.num_frames):
                rgb = big.rgb(i).astype(np.float32).reshape(h, 2, w, 2, 3).mean((1, 3))
                path = tmp / seq.root.relative_to(args.src) / "rgb" / f"{i:06d}.png"
                path.unlink()  # a hard link: never write through it into the source
                Image.fromarray(np.rint(rgb).astype(np.uint8)).save(path)
                bar.update(1)
    tmp.rename(args.dst)
    print(f"wrote {args.dst}: {len(seqs)} sequences, frames the 2x2 means of {args.double}'s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
