#!/usr/bin/env python3
"""What the box-depth head buys the top view: per frame, where it says shown, and carried along the row.

    .venv/bin/python research/box_depth_reader.py CKPT --eval data/heldout256 [--sequences N] [--every 2]

CKPT is a checkpoint with the box-depth head (the `fit-box-depth` stage of a training recipe, `network.heads.boxdepth`).
`research/box_top_faces.py` measured, on the shipped predictions, that the true depth of every box
whose depth the frame shows (any face) would lift the 256x256 top box from 66.8 to 75.0, and of every
box some frame so far showed, to 81.2; this prints how much of that the head reads.

Scored like `box_top_faces.py` (streamed, the rack depth read, Table I top view): each predicted
box's back moved to the head's depth per column (a) everywhere, (b) where the head says the frame
shows it, and (c) carried along the row (`network.heads.boxdepth.BoxDepthReader`) with the camera's X
from the poses or read from the images (`network.model.motion.camera_shift`): the latter is what
`mvracklay predict`, `run` and `evaluate` do. Then the oracles of `box_top_faces.py`.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from box_top_faces import Table, seen_in  # noqa: E402  (research/, the script's own folder)

from layouts.boxdepth import box_parts  # noqa: E402
from network.checkpoint import load_model  # noqa: E402
from network.heads.boxdepth import BoxDepthReader, decode, frame_head_inputs, reading  # noqa: E402
from network.inference.predictor import Predictor, sequence_camera  # noqa: E402
from waresynth.dataset import open_dataset  # noqa: E402
from waresynth.visibility import SeenTracker  # noqa: E402

MIN_SHOWN = 0.5  #: shown probability from which this script counts a column as shown by its frame


def run(model, seqs, every: int) -> list[dict]:
    """Every frame streamed (rack and box depths read); per scored frame what the table needs."""
    frames = []
    view, spec_m = model.cfg.view, model.cfg.spec
    bar = tqdm(total=sum(s.num_frames for s in seqs), desc="evaluate", unit="frame", leave=False)
    for seq in seqs:
        camera = sequence_camera(seq)
        seen = SeenTracker(seq)
        true_depth = float(seq.scene()["row"]["depth"])
        poses = BoxDepthReader(spec_m)
        xs = seq.camera_positions()[:, 0]
        pred = Predictor(model, camera)
        for i, out in enumerate(pred.run(seq.rgb(j) for j in range(seq.num_frames))):
            bar.update(1)
            seen.add(i)
            dist = camera(i)[1]
            with torch.no_grad():
                win, extra = frame_head_inputs(out.head_inputs(), view, dist)
                logits = model.box_logits(win, extra)
                z, p = decode(logits)
            valid = torch.isfinite(out.anchors).numpy()
            by_pose = poses.add(*reading(logits), valid, xs[i] - xs[i - 1] if i else 0.0)
            if i % every:
                continue
            read = out.rack_depth
            spec = seq.spec
            frames.append({"pred": replace(out, box_back=None).layouts(spec), "truth": seq.layouts(i),
                           "anchors": out.anchors.numpy(), "spec": spec,
                           "depth": read if np.isfinite(read) else true_depth, "distance": dist,
                           "seen": seen.labels(i), "z": z, "p": p, "carry_pose": by_pose,
                           "carry_image": out.box_back})  # fmt: skip
    bar.close()
    return frames


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("checkpoint", type=Path, help="a checkpoint with the box-depth head (fit-box-depth stage)")
    ap.add_argument("--eval", type=Path, required=True, help="generated evaluation scenes (depth, instance, scene)")
    ap.add_argument("--sequences", type=int, default=None, help="only the first N evaluation sequences")
    ap.add_argument("--every", type=int, default=2, help="score every N-th frame (all frames are run)")
    ap.add_argument("--threads", type=int, default=2)
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    model, _ = load_model(args.checkpoint)
    if model.box_depth is None:
        ap.error(f"{args.checkpoint}: no box-depth head (a training recipe's fit-box-depth stage fits one)")
    seqs = open_dataset(args.eval).sequences()[: args.sequences]
    frames = run(model.eval(), seqs, args.every)
    print(f"{args.eval}: {len(frames)} frames of {len(seqs)} sequences; top view, mIoU")
    line = Table(frames, model.cfg.view, width=58).line

    def head_cols(f, cols):
        return cols * f["z"].shape[1] // f["spec"].size

    def from_head(key: str | None, gate: bool):
        def choose(f, r, cols, zf, h_top, c, back, has):
            j = head_cols(f, cols)
            if key is not None:
                z = f[key][r, j]
                return z if np.isfinite(z).any() else None
            if gate and f["p"][r, j].mean() < MIN_SHOWN:
                return None
            return f["z"][r, j]

        return choose

    def decoder(gate: bool):
        def choose(f, r, cols, zf, h_top, c, back, has):
            if gate and f["p"][r, head_cols(f, cols)].mean() < MIN_SHOWN:
                return None
            for c2, _, zb, _ in box_parts(f["pred"]["top"][r], f["pred"]["front"][r], f["spec"], f["depth"]):
                if np.array_equal(c2, cols):
                    return zb
            return None

        return choose

    line("prediction (the decoder's box depths)", lambda *a: None)
    line("prediction, its error on every box", decoder(False))
    line(f"prediction, its error where the head says shown (p >= {MIN_SHOWN:g})", decoder(True))
    line("head's depth, every box", from_head(None, False))
    line(f"head's depth where it says the frame shows it (p >= {MIN_SHOWN:g})", from_head(None, True))
    line("carried along the row, camera X from the poses", from_head("carry_pose", False))
    line("carried along the row, camera X read from the images", from_head("carry_image", False))
    line("oracle: true depth where this frame shows it", seen_in(2))
    line("oracle: true depth where this or an earlier frame showed it", seen_in(1))
    shown_p = np.concatenate([f["p"].ravel() for f in frames])
    print(f"head says shown (p >= {MIN_SHOWN:g}) for {100 * (shown_p >= MIN_SHOWN).mean():.1f} % of slot columns")
    return 0


if __name__ == "__main__":
    sys.exit(main())
