#!/usr/bin/env python3
"""A copy of a generated dataset as a rolled, pitched or yawed camera would have filmed it: every RGB frame turned.

    .venv/bin/python research/turn_dataset.py data/heldout128 data/heldout128-roll5 --roll 5
    mvracklay eval-reconstruction data/heldout128-roll5 --checkpoint mvracklay/models/mvracklay-disc-4.pt --noisy --roll auto
    .venv/bin/python research/turn_dataset.py data/heldout128 data/heldout128-yaw3 --yaw 3

Every ``SEQ/rgb/*.png`` is seen by the camera tilted up ``--pitch`` and turned right ``--yaw`` degrees
(`network.inference.roll.tilt_frame`, a homography), then rolled ``--roll`` degrees counter-clockwise about the
principal point (`network.inference.roll.turn_frame`); the uncovered parts take the canonical fill colour.
Everything else (layouts, depth, semantics, cuboids, records) is hard-linked, or copied where links
fail, unchanged. ``TURNED.json`` at the root says what was done. The copy's records still describe a
level camera, so the commands take it as level unless given ``--roll`` / ``--pitch`` / ``--yaw``
(``auto`` or degrees). Refuses to write into a folder that exists.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from rgb_copy import write_rgb_copy  # noqa: E402  (this script's folder is on the path)

from network.inference.roll import check_angle, tilt_frame, turn_frame  # noqa: E402
from waresynth.dataset import open_dataset  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("src", type=Path, help="a generated dataset folder")
    ap.add_argument("dst", type=Path, help="the folder to write (must not exist)")
    ap.add_argument("--roll", default="0", help="degrees, counter-clockwise as displayed")
    ap.add_argument("--pitch", default="0", help="degrees, the optical axis tilted up")
    ap.add_argument("--yaw", default="0", help="degrees, the camera turned right")
    args = ap.parse_args()
    roll, pitch, yaw = (check_angle(getattr(args, n), f"--{n}") for n in ("roll", "pitch", "yaw"))
    for name, v in (("--roll", roll), ("--pitch", pitch), ("--yaw", yaw)):
        if not isinstance(v, float):
            ap.error(f"{name} must be a number of degrees")
    if not (roll or pitch or yaw):
        ap.error("give --roll, --pitch or --yaw (degrees): a copy turned by nothing is the source")
    if args.dst.exists():
        ap.error(f"{args.dst}: exists; give a new folder")
    seqs = open_dataset(args.src).sequences()  # validates the source

    def change(rgb: np.ndarray, seq) -> np.ndarray:
        if pitch or yaw:
            rgb = tilt_frame(rgb, seq.intrinsics, pitch, yaw)
        if roll:
            rgb = turn_frame(rgb, roll, seq.intrinsics.cx, seq.intrinsics.cy)
        return rgb

    said = {"source": str(args.src), "roll_deg": roll, "pitch_deg": pitch, "yaw_deg": yaw}
    frames = write_rgb_copy(args.src, args.dst, seqs, change, "turn", ("TURNED.json", said))
    print(
        f"wrote {args.dst}: {len(seqs)} sequences, {frames} frames, roll {roll:g} / pitch {pitch:g} / yaw {yaw:g} deg"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
