"""``mvracklay evaluate-baseline``: Table I of the depth-projection baseline on a generated dataset."""

from __future__ import annotations

import argparse

from layouts.errors import InputError
from mvracklay.command_settings import EvaluateBaselineSettings
from mvracklay.settings import add_options

NAME = "evaluate-baseline"
HELP = "Table I of the depth-projection baseline (ground-truth depth + masks, visible surfaces only)"
DESCRIPTION = (
    "Back-project each frame's ground-truth depth with its ground-truth semantic masks into shelf-centric "
    "layouts (no learning, no amodal reasoning: see mvracklay/baselines/depth_projection.py) and score them "
    "like 'mvracklay evaluate' does a checkpoint: what seeing alone gives."
)
GROUP = "models"
ORDER = 32


SETTINGS = EvaluateBaselineSettings


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_options(p, EvaluateBaselineSettings)


def run(args: EvaluateBaselineSettings) -> int:
    from layouts.fileio import atomic_write_json, nan_to_null
    from layouts.metrics import format_table
    from layouts.publish import refuse_overlap
    from mvracklay.baselines.depth_projection import evaluate_depth_projection
    from waresynth.dataset import open_dataset

    refuse_overlap([args.json_out] if args.json_out else [], {"--data": args.data}, "--json-out")
    if args.max_frames < 0:
        raise InputError(f"--max-frames must be >= 0, got {args.max_frames}")
    ds = open_dataset(args.data)
    seqs = ds.sequences(None if args.split == "all" else args.split)
    if not seqs:
        raise InputError(f"{args.data}: has no '{args.split}' sequences")
    res = evaluate_depth_projection(seqs, args.max_frames or None, progress=not args.quiet)
    title = f"depth-projection baseline on {args.data} [{args.split}], {res['frames']} frames of {len(seqs)} sequences"
    print(format_table(res["visible"], title + " -- columns in view"))
    print()
    print(format_table(res["all"], title + " -- all cells"))
    if args.json_out:
        atomic_write_json(
            args.json_out, nan_to_null({"data": str(args.data), "split": args.split, "sequences": len(seqs), **res})
        )
        print(f"wrote {args.json_out}")
    return 0
