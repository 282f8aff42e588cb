#!/usr/bin/env python3
"""What a known rack depth buys: Table I of a checkpoint's layouts as predicted and with the rack depth imposed.

    .venv/bin/python research/known_rack_depth.py mvracklay/models/mvracklay-disc-4.pt data/heldout128 [--every 2]

Runs the model (streaming) over every sequence of a generated dataset and scores Table I (columns
in view, mIoU in percent) of its layouts as decoded and after `layouts.rackdepth.impose_rack_depth`
(what `mvracklay predict/run --rack-depth M` does) with: the depth the model reads from the boards'
back edges and, with the upright head, the racks' uprights over the frames so far
(`network.heads.backedge`, `network.heads.uprights`; what such models do by default); each scene's true rack
depth (from its scene.json, what a racking spec sheet gives); the true depth in each sequence's first
K frames only (``--first K``) and the depth read after them: what a camera that starts reading
well at once would gain, the reader being poorest while it has seen few frames; the true depth off
by +-ERR cm (a spec that is a little wrong); and one fixed depth for every scene (a guess). A model
with the box-depth head has its carried box backs (and fronts) imposed after the rack depth, as
`mvracklay evaluate` does, wherever a depth is given. Only the top view changes.
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

from layouts.metrics import FrameScorer  # noqa: E402
from network.checkpoint import load_model  # noqa: E402
from network.inference.predictor import Predictor, rack_depth_source, sequence_camera  # noqa: E402
from waresynth.dataset import open_dataset  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("checkpoint", type=Path)
    ap.add_argument("data", type=Path, help="a generated dataset (e.g. the held-out set)")
    ap.add_argument("--every", type=int, default=2, help="score every N-th frame (all frames are run)")
    ap.add_argument("--errors", type=float, nargs="*", default=[2.0, 5.0], help="depth errors to try, cm")
    ap.add_argument("--fixed", type=float, default=1.0, help="the one depth for every scene, metres")
    ap.add_argument(
        "--first", type=int, nargs="*", default=[10], metavar="K",
        help="the true depth in each sequence's first K frames, the read one after",
    )  # fmt: skip
    ap.add_argument("--threads", type=int, default=2)
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    model, record = load_model(args.checkpoint)
    model.eval()
    seqs = open_dataset(args.data).sequences()
    frames = []  # (outputs, ground truth, scene rack depth, spec, depth read, frame index)
    bar = tqdm(total=sum(s.num_frames for s in seqs), desc="predict", unit="frame", leave=False)
    for seq in seqs:
        depth = float(seq.scene()["row"]["depth"])
        pred = Predictor(model, sequence_camera(seq))
        for i, out in enumerate(pred.run((seq.rgb(i) for i in range(seq.num_frames)), "stream")):
            bar.update(1)
            if i % args.every == 0:
                kept = replace(out, maps={}, rows=None)  # what the layouts need
                frames.append((kept, seq.layouts(i), depth, seq.spec, out.rack_depth, i))
    bar.close()
    # each case: name, and the depth it imposes from (true depth, depth read, frame index); NaN imposes none
    cases = [("as decoded", lambda d, r, i: float("nan"))]
    if pred.reads_depth:
        cases.append((rack_depth_source(model), lambda d, r, i: r))
    cases.append(("true rack depth", lambda d, r, i: d))
    if pred.reads_depth:
        cases += [(f"true, first {k} frames, read after", lambda d, r, i, k=k: d if i < k else r) for k in args.first]
    for e in args.errors:
        cases += [
            (f"true {sign}{e:g} cm", lambda d, r, i, s=s, e=e: d + s * e / 100) for sign, s in (("+", 1), ("-", -1))
        ]
    cases.append((f"{args.fixed:g} m for every scene", lambda d, r, i: args.fixed))
    print(f"{record.get('variant')} ({args.checkpoint}) on {args.data}: {len(frames)} frames of {len(seqs)} sequences")
    print(
        f"{'mIoU, columns in view':34s} {'top rack':>9s} {'top box':>8s} {'front rack':>11s} {'front box':>10s} "
        f"{'depth err':>9s}"
    )
    print(f"{'':34s} {'':9s} {'':8s} {'':11s} {'':10s} {'(cm, mean)':>9s}")
    for name, depth_of in cases:
        scorer = FrameScorer()
        errors = []
        for out, gt, depth, spec, read, i in frames:
            new = depth_of(depth, read, i)
            if np.isfinite(new):
                errors.append(abs(new - depth))
            scorer.update(replace(out, rack_depth=float(new)).layouts(spec), gt)
        v = scorer.result()["visible"]
        cells = [v[view][c]["miou"] * 100 for view in ("top", "front") for c in ("rack", "box")]
        err = f"{100 * np.mean(errors):9.1f}" if errors else f"{'':9s}"
        print(f"{name:34s} {cells[0]:9.1f} {cells[1]:8.1f} {cells[2]:11.1f} {cells[3]:10.1f} {err}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
