#!/usr/bin/env python3
"""What a rolled camera costs, and what reading its roll (`--roll auto`) gives back: Table I on turned frames.

    .venv/bin/python research/roll_robustness.py mvracklay/models/mvracklay-disc-4.pt data/heldout128 --rolls 0 2 5

Every frame of the dataset is turned by the roll (degrees, counter-clockwise about the principal
point, as a camera rolled the other way would see it; the corners the turn uncovers take the
canonical fill colour, where a real camera would see more of the scene) and run through the whole
pipeline of ``mvracklay evaluate`` (windowed, depth heads, columns in view), once taking the camera
as level and once reading its roll from the frames (`network.inference.roll`); ``--levelled-by truth`` adds a
row with the true roll given (what the turn's lost corners cost alone), ``read-all`` one with the
roll, pitch and yaw all read. The angle read is compared with the truth, frame by frame. ``--axis pitch`` / ``yaw`` tilts the camera up / turns it right
instead (`network.inference.roll.tilt_frame`, a homography), read with ``--pitch auto`` / ``--yaw auto``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from network.checkpoint import load_model  # noqa: E402
from network.inference.layout_eval import evaluate_sequences  # noqa: E402
from network.inference.roll import ANGLES, tilt_frame, turn_frame  # noqa: E402
from network.training.train_data import open_data  # noqa: E402


class Turned:
    """A sequence whose frames are seen by a camera rolled / pitched / yawed ``deg`` degrees (``axis``)."""

    def __init__(self, seq: Any, deg: float, axis: str = "roll") -> None:
        self._seq, self._deg, self._axis = seq, float(deg), axis

    def __getattr__(self, name: str) -> Any:
        return getattr(self._seq, name)

    def rgb(self, i: int) -> np.ndarray:
        rgb = self._seq.rgb(i)
        if not self._deg:
            return rgb
        intr = self._seq.intrinsics
        if self._axis == "roll":
            return turn_frame(rgb, self._deg, intr.cx, intr.cy)
        return tilt_frame(rgb, intr, **{f"{self._axis}_deg": self._deg})


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("checkpoint", type=Path)
    ap.add_argument("data", type=Path, help="a dataset with ground truth")
    ap.add_argument("--rolls", type=float, nargs="+", default=[0.0, 2.0, 5.0], help="camera angles to simulate")
    ap.add_argument(
        "--axis",
        choices=ANGLES,
        default="roll",
        help="roll (about the optical axis), pitch (tilted up) or yaw (turned right)",
    )
    ap.add_argument(
        "--levelled-by",
        nargs="+",
        choices=["none", "read", "read-all", "truth"],
        default=["none", "read"],
        help="none: the camera taken as level; read: --roll (--pitch, --yaw) auto; read-all: roll, pitch and yaw "
        "all read; truth: the true angle given",
    )
    ap.add_argument("--sequences", type=int, default=0, help="the first N sequences (0 = all)")
    ap.add_argument("--threads", type=int, default=2)
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    model, _ = load_model(args.checkpoint)
    seqs = open_data(args.data).sequences()
    seqs = seqs[: args.sequences] if args.sequences else seqs

    print(
        f"{args.checkpoint} on {args.data} ({len(seqs)} sequences, camera {args.axis}): mIoU, columns in view, windowed"
    )
    print(f"{args.axis:>5s} {'levelled by':>12s} {'top rack':>9s} {'top box':>8s} {'front rack':>11s} {'front box':>10s}"
          f" {'read: mean / p95 / max error':>34s}")  # fmt: skip
    for deg in args.rolls:
        for how in args.levelled_by:
            if how == "read-all":
                given = {"roll": "auto", "pitch": "auto", "yaw": "auto"}
            else:
                angle = {"none": None if args.axis == "roll" else 0.0, "read": "auto", "truth": deg}[how]
                given = {"roll": None, "pitch": 0.0, "yaw": 0.0} | {args.axis: angle}
            turned = [Turned(s, deg, args.axis) for s in seqs]
            res = evaluate_sequences(model, turned, progress=False, **given)
            r = res["visible"]
            cells = [100 * r[v][c]["miou"] for v in ("top", "front") for c in ("rack", "box")]
            read = res[{"roll": "rolls", "pitch": "pitches", "yaw": "yaws"}[args.axis]]
            err = np.abs(np.asarray(read) - deg) if how.startswith("read") else None
            said = "" if err is None else f"{err.mean():.2f} / {np.percentile(err, 95):.2f} / {err.max():.2f} deg"
            print(
                f"{deg:5g} {how:>12s} {cells[0]:9.1f} {cells[1]:8.1f} {cells[2]:11.1f} {cells[3]:10.1f} {said:>34s}",
                flush=True,
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())
