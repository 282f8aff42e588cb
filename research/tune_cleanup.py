#!/usr/bin/env python3
"""Choose the stitching clean-up for network output: box F1 of a grid of `StitchConfig` settings.

    .venv/bin/python research/tune_cleanup.py runs/mvracklay-disc-4/calibrated.pt data/tune128

Predicts every sequence of a *tuning* set once (streaming, the checkpoint's box offsets applied),
then stitches the same layouts with every combination of box-mask openings (0-2), merge support
(0.3-0.7) and minimum box area (0.012-0.05 m^2), scores each map against the generator's cuboids
(`mvracklay.reconstruction_eval.evaluate_sequence`, 3D IoU 0.5, pooled over sequences) and
prints the combinations by box F1, best first, with `StitchConfig.noisy()`'s row marked. Choose on
a tuning set, never on the held-out set you report.
"""

from __future__ import annotations

import argparse
import itertools
import sys
import tempfile
from pathlib import Path

import torch
from tqdm import tqdm

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from layouts.codecs import LayoutFolder  # noqa: E402
from mvracklay.inference import predict_folder  # noqa: E402
from mvracklay.reconstruction_eval import evaluate_sequence  # noqa: E402
from mvracklay.use_settings import PredictSettings  # noqa: E402
from network.checkpoint import load_model  # noqa: E402
from stitching.detect import DetectConfig  # noqa: E402
from stitching.merge import MergeConfig  # noqa: E402
from stitching.pipeline import StitchConfig  # noqa: E402
from waresynth.dataset import open_dataset  # noqa: E402

OPENINGS = (0, 1, 2)
SUPPORTS = (0.3, 0.5, 0.7)
AREAS = (0.012, 0.03, 0.05)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("checkpoint", type=Path)
    ap.add_argument("data", type=Path, help="a tuning dataset (generated, with ground truth)")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--top", type=int, default=10, help="rows to print")
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    model, record = load_model(args.checkpoint)
    seqs = open_dataset(args.data).sequences()
    noisy = StitchConfig.noisy()
    grid = list(itertools.product(OPENINGS, SUPPORTS, AREAS))
    rows = []
    with tempfile.TemporaryDirectory(prefix="tune-cleanup-") as tmp:
        folders = []
        for seq in tqdm(seqs, desc="predict", unit="seq", leave=False):
            out = Path(tmp) / seq.name
            job = PredictSettings(seq_dir=seq.root, out=out, mode="stream", quiet=True)
            predict_folder(model, record, job, source=str(args.checkpoint))
            folders.append(LayoutFolder(out))
        for opening, support, area in tqdm(grid, desc="stitch", unit="setting", leave=False):
            cfg = StitchConfig(
                detect=DetectConfig(opening=opening, min_box_area=area),
                lift=noisy.lift,
                merge=MergeConfig(min_support=support),
            )
            tp = fp = fn = 0
            for seq, folder in zip(seqs, folders):
                res, _ = evaluate_sequence(seq, folder, cfg)
                tp, fp, fn = tp + res.tp, fp + res.fp, fn + res.fn
            p = tp / (tp + fp) if tp + fp else 1.0
            r = tp / (tp + fn) if tp + fn else 1.0
            f1 = 2 * p * r / (p + r) if p + r else 0.0
            mark = (
                " <- noisy()"
                if (opening, support, area)
                == (noisy.detect.opening, noisy.merge.min_support, noisy.detect.min_box_area)
                else ""
            )
            rows.append((f1, r, p, opening, support, area, mark))
    rows.sort(key=lambda x: -x[0])
    print(f"{args.checkpoint} on {args.data} ({len(seqs)} sequences): box F1 at 3D IoU 0.5, best first")
    print(f"{'F1':>6s} {'recall':>7s} {'prec':>6s} {'opening':>8s} {'support':>8s} {'min area':>9s}")
    shown = rows[: args.top] + [r for r in rows[args.top :] if r[-1]]
    for f1, r, p, o, s, a, mark in shown:
        print(f"{f1:6.3f} {r:7.3f} {p:6.3f} {o:8d} {s:8.1f} {a:9.3f}{mark}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
