#!/usr/bin/env python3
"""How much a sequence model's slot memory changes its layouts.

    .venv/bin/python research/memory_use.py runs/mvracklay-disc-4/best.pt data/heldout128 [--sequences 6]

Streams every frame of the first sequences twice through the same weights: once carrying the
memory from frame to frame (as `mvracklay predict` does), once with a fresh memory at every frame
(the single-frame network inside the sequence model). Prints, per view, the share of cells whose
class differs, the share of the fresh run's box cells that change, and the mIoU of both runs
against the truth on those frames (columns in view), so a memory that learned to do nothing
shows as ~0 % and equal scores. ``--true-motion`` adds a third run whose aligned memory is moved
by the ground-truth camera steps instead of the image estimate (what a perfect motion estimate
would be worth).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from layouts import BOX, VIEWS  # noqa: E402
from layouts.metrics import FrameScorer  # noqa: E402
from network.checkpoint import load_checkpoint, model_from  # noqa: E402
from network.inference.decision import apply_box_offset  # noqa: E402
from network.inference.predictor import Predictor, sequence_camera  # noqa: E402
from network.inference.result import logits_to_layout  # noqa: E402
from waresynth.dataset import open_dataset  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("checkpoint", type=Path)
    ap.add_argument("data", type=Path, help="a generated dataset folder")
    ap.add_argument("--sequences", type=int, default=6, help="how many sequences (manifest order)")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--true-motion", action="store_true", help="also run with the ground-truth camera steps")
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    model = model_from(*load_checkpoint(args.checkpoint), args.checkpoint)
    if model.memory is None:
        sys.exit(f"{args.checkpoint}: variant {model.cfg.variant} has no slot memory")
    ds = open_dataset(args.data)
    changed = {v: [] for v in VIEWS}
    box_changed = {v: [0, 0] for v in VIEWS}
    runs = ("memory", "fresh", "true motion") if args.true_motion else ("memory", "fresh")
    scorers = {k: FrameScorer() for k in runs}
    seqs = ds.sequences()[: args.sequences]
    with torch.no_grad():
        for seq in tqdm(seqs, desc="sequences", leave=False):
            pred = Predictor(model, sequence_camera(seq), fuse_tau=0)  # the model alone
            state = true_state = None
            cam_x = np.asarray(seq.camera_positions(), dtype=np.float64)[:, 0]
            for i in range(seq.num_frames):
                x = pred.preprocess(seq.rgb(i), i)
                outs = {}
                outs["memory"], state = model.step(x, state)
                outs["fresh"], _ = model.step(x, None)
                if args.true_motion:
                    step = torch.tensor([cam_x[i] - cam_x[i - 1] if i else 0.0])
                    outs["true motion"], true_state = model.step(x, true_state, motion=step)
                truth = seq.layouts(i)
                size = truth.top.shape[-1]
                lays = {}
                for name, o in outs.items():
                    lays[name] = {
                        v: logits_to_layout(apply_box_offset(o[v][0], model.box_logit_offset.get(v, 0.0)), size)
                        for v in VIEWS
                    }
                    scorers[name].update(lays[name], truth)
                for v in VIEWS:
                    a, b = lays["memory"][v], lays["fresh"][v]
                    changed[v].append(float((a != b).mean()))
                    box_changed[v][0] += int(((a == BOX) != (b == BOX)).sum())
                    box_changed[v][1] += int((b == BOX).sum())
    print(
        f"{args.checkpoint} on {args.data}: {sum(s.num_frames for s in seqs)} frames of {len(seqs)} sequences, streaming"
    )
    res = {k: s.result()["visible"] for k, s in scorers.items()}
    for v in VIEWS:
        bc = 100 * box_changed[v][0] / max(1, box_changed[v][1])
        m, f = res["memory"][v], res["fresh"][v]
        print(
            f"  {v:5s} cells changed by the memory {100 * np.mean(changed[v]):.2f} %, box cells {bc:.2f} %; "
            f"mIoU rack / box with memory {100 * m['rack']['miou']:.1f} / {100 * m['box']['miou']:.1f}, "
            f"fresh each frame {100 * f['rack']['miou']:.1f} / {100 * f['box']['miou']:.1f}"
            + (
                f", true motion {100 * res['true motion'][v]['rack']['miou']:.1f} / "
                f"{100 * res['true motion'][v]['box']['miou']:.1f}"
                if args.true_motion
                else ""
            )
        )


if __name__ == "__main__":
    main()
