#!/usr/bin/env python3
"""A copy of a generated dataset as a rolled camera would have filmed it: every RGB frame turned.

    .venv/bin/python benchmarks/turn_dataset.py data/heldout128 data/heldout128-roll5 --roll 5
    mvracklay eval-reconstruction data/heldout128-roll5 --checkpoint weights/mvracklay-disc-4.pt --noisy --roll auto

Every ``SEQ/rgb/*.png`` is turned ``--roll`` degrees counter-clockwise about the principal point
(`network.roll.turn_frame`: the uncovered corners take the canonical fill colour); everything else
(layouts, depth, semantics, cuboids, records) is hard-linked, or copied where links fail, unchanged.
``TURNED.json`` at the root says what was done. The copy's records still describe a level camera, so
the commands take it as level unless given ``--roll auto`` or ``--roll DEG``. Refuses to write into a
folder that exists.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
from pathlib import Path

import numpy as np
from PIL import Image
from tqdm import tqdm

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from network.roll import check_roll, turn_frame  # noqa: E402
from waresynth.dataset import open_dataset  # noqa: E402


def _link_or_copy(src: str, dst: str) -> None:
    try:
        os.link(src, dst)
    except OSError:
        shutil.copy2(src, dst)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("src", type=Path, help="a generated dataset folder")
    ap.add_argument("dst", type=Path, help="the folder to write (must not exist)")
    ap.add_argument("--roll", required=True, help="degrees, counter-clockwise as displayed")
    args = ap.parse_args()
    roll = check_roll(args.roll, "--roll")
    if not isinstance(roll, float):
        ap.error("--roll must be a number of degrees")
    if args.dst.exists():
        ap.error(f"{args.dst}: exists; give a new folder")
    seqs = open_dataset(args.src).sequences()  # validates the source
    tmp = args.dst.with_name(args.dst.name + ".partial")
    shutil.rmtree(tmp, ignore_errors=True)
    shutil.copytree(args.src, tmp, copy_function=_link_or_copy)
    frames = sum(s.num_frames for s in seqs)
    with tqdm(total=frames, desc="turn", unit="frame") as bar:
        for seq in seqs:
            intr = seq.intrinsics
            rgb_dir = tmp / seq.root.relative_to(args.src) / "rgb"
            for path in sorted(rgb_dir.glob("*.png")):
                with Image.open(path) as im:
                    rgb = np.asarray(im.convert("RGB"))
                path.unlink()  # a hard link: never write through it into the source
                Image.fromarray(turn_frame(rgb, roll, intr.cx, intr.cy)).save(path)
                bar.update(1)
    (tmp / "TURNED.json").write_text(json.dumps({"source": str(args.src), "roll_deg": roll}, indent=2) + "\n")
    tmp.rename(args.dst)
    print(f"wrote {args.dst}: {len(seqs)} sequences, {frames} frames turned {roll:g} deg")
    return 0


if __name__ == "__main__":
    sys.exit(main())
