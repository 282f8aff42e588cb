"""``mvracklay fit-back-edges``: give a trained checkpoint the head that reads the rack depth."""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path

import torch

from layouts.errors import InputError
from layouts.fileio import atomic_write_json, nan_to_null

NAME = "fit-back-edges"
HELP = "fit the back-edge head (reads the rack depth from the shelf boards' back edges) to a trained checkpoint"
DESCRIPTION = (
    "The top view is centred on the rack's depth, so a misread rack depth moves every shelf front and box. "
    "This fits a small head that finds the shelf boards' back edges in the image (the rest of the network "
    "frozen, one pass per frame over generated data with ground truth) and writes CKPT with the head added; "
    "predict, run and evaluate then read the rack depth from the back edges over the frames seen so far "
    "and redraw the top views at it (--no-depth-read turns that off). Validation prints the depth's error."
)
ORDER = 34


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--checkpoint", type=Path, required=True, help="a trained .pt checkpoint (its .json beside)")
    p.add_argument(
        "--data", type=Path, nargs="+", required=True, help="generated dataset(s) with ground truth to fit on"
    )
    p.add_argument("--sequences", type=int, default=1200, help="training sequences to use (the first N of --data)")
    p.add_argument("--val", type=Path, help="generated dataset to measure the depth read on (never trained on)")
    p.add_argument("--epochs", type=int, default=20, help="passes over the training frames")
    p.add_argument("--every", type=int, default=1, help="use every N-th frame")
    p.add_argument("--seed", type=int, default=0, help="seed of the head's initial weights and batch order")
    p.add_argument("--out", type=Path, help="write the new checkpoint here (unset: CKPT is updated in place)")
    p.add_argument("--threads", type=int, default=2, help="CPU threads for torch")
    p.add_argument("--json", type=Path, help="also write the fit's summary as JSON here")
    p.add_argument("--quiet", action="store_true", help="hide the progress bars")


def run(args: argparse.Namespace) -> int:
    from network.checkpoint import load_checkpoint, model_from, save_with_head
    from network.fit_backedge import FitConfig, fit_back_edges
    from network.train import open_data

    if args.threads < 1:
        raise InputError(f"--threads must be >= 1, got {args.threads}")
    if args.sequences < 1:
        raise InputError(f"--sequences must be >= 1, got {args.sequences}")
    cfg = FitConfig(epochs=args.epochs, every=args.every, seed=args.seed)
    cfg.validate()
    torch.set_num_threads(args.threads)
    payload, record = load_checkpoint(args.checkpoint)
    model = model_from(payload, record, args.checkpoint)
    train = [s for root in args.data for s in open_data(root).sequences(None)][: args.sequences]
    val = open_data(args.val).sequences(None) if args.val else []
    head, summary = fit_back_edges(model, train, val, cfg, progress=not args.quiet)
    for name in ("train_depth", "val_depth"):
        if name in summary:
            d = summary[name]
            print(
                f"{name.split('_')[0]:5s} rack depth error ({d['sequences']} sequences, {d['frames']} frames): "
                f"{_cm(d['mae_frame'])} one frame, {_cm(d['mae_running'])} over the frames so far, "
                f"{_cm(d['mae_sequence'])} at a sequence's end"
            )
    out = args.out or args.checkpoint
    info = {"data": [str(d) for d in args.data], "val": str(args.val) if args.val else None, **summary}
    save_with_head(out, payload, record, replace(model.cfg, back_edges=True), "back", head, "back_edges", info)
    print(f"wrote {out} (and {Path(out).with_suffix('.json').name})")
    if args.json:
        atomic_write_json(args.json, nan_to_null(summary))
    return 0


def _cm(metres: float | None) -> str:
    return "n/a" if metres is None else f"{100 * metres:.1f} cm"
