#!/usr/bin/env python3
"""Where the row head anchors the shelf slots against the ground truth's boards, per sequence.

    .venv/bin/python research/slot_anchors.py DATA [--checkpoint NAME] [--sequences seq_00000,seq_00004]

For each generated sequence: the levels the camera sees (`meta.json` `visible_levels`), the slots' board
rows in the canonical view (ground truth, `network.data.board_rows`) and the row head's (streamed,
`Predictor`), at the first, middle and last frame, and how many frames find another set of slots. A board
row outside ``0..H`` lies beyond the canonical view: the row head cannot find it, and when the ground truth
counts it as slot 0 every slot the network finds names the level below its own (docs/results.md,
*A high camera over a floor-level shelf*).
"""

from __future__ import annotations

import argparse

import numpy as np
import torch

from mvracklay.models import resolve_checkpoint
from network.checkpoint import load_model
from network.data import board_rows
from network.inference.predictor import Predictor, sequence_camera
from waresynth.dataset import open_dataset


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("data")
    ap.add_argument("--checkpoint", default="mvracklay-disc-4")
    ap.add_argument("--sequences", default="", help="comma-separated names (default: all)")
    ap.add_argument("--threads", type=int, default=1)
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    model, _ = load_model(resolve_checkpoint(args.checkpoint))
    names = set(filter(None, args.sequences.split(",")))
    slots, view = model.cfg.spec.num_slots, model.cfg.view
    for seq in open_dataset(args.data).sequences():
        if names and seq.name not in names:
            continue
        n, other, shown = seq.num_frames, 0, []
        pred = Predictor(model, sequence_camera(seq), None)
        for i, out in enumerate(pred.predict((seq.rgb(i) for i in range(n)), "stream")):
            gt = board_rows(seq, i, view, slots)[0]
            found = out.anchors.float().numpy()
            same = np.isfinite(gt).sum() == np.isfinite(found).sum()
            if not same or (np.isfinite(gt[0]) and abs(float(gt[0]) - float(np.nan_to_num(found[0]))) > 3):
                other += 1
            if i in (0, n // 2, n - 1):
                shown.append(f"  frame {i}: truth {np.round(gt, 1).tolist()}  row head {np.round(found, 1).tolist()}")
        print(f"{seq.name}: visible levels {seq.meta['visible_levels']}, canonical rows 0..{view.height}, "
              f"frames with other slots {other}/{n}")  # fmt: skip
        print("\n".join(shown))


if __name__ == "__main__":
    main()
