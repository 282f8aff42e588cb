"""Stage ``calibrate`` of ``mvracklay train``: choose a checkpoint's per-view box-logit offsets, or its
rack-depth offset, on a tuning set."""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path

import torch

from layouts.errors import InputError
from layouts.fileio import atomic_write_json, nan_to_null
from mvracklay.options import FLIP_HELP, check_counts
from mvracklay.settings import json_out_setting, quiet_setting, setting
from network.checkpoint import load_checkpoint, model_from, save_checkpoint
from network.training.calibrate import GRID, fit_box_offsets, fit_rack_depth_offset

NAME = "calibrate"
HELP = "choose a checkpoint's box decision offsets or rack-depth offset on a tuning set (writes them into the record)"
DESCRIPTION = (
    "Training weights the rare box class, which makes predicted boxes too large. This runs CKPT over a "
    "tuning set (with ground truth; never the set you report on), scores a grid of offsets subtracted "
    "from the box logit, and stores the best per view in the checkpoint's record as box_logit_offset: "
    "evaluate, predict and run apply it from then on. With --target rack-depth it instead measures how far "
    "the rack depth that a model with the upright or back-edge head reads lies from the true one (the "
    "median over the frames, streamed; a generated tuning set) and stores the offset that undoes it as "
    "rack_depth_offset (metres), added to every reading from then on. The weights are not changed."
)


@dataclass(frozen=True)
class CalibrateSettings:
    """The options of stage ``calibrate`` (each field's option, default and help in its metadata)."""

    checkpoint: Path | None = setting("--checkpoint", "a .pt checkpoint (its .json beside)", type=Path, required=True)
    data: Path | None = setting(
        "--data", "tuning data with ground truth (dataset or RackLay export)", type=Path, required=True
    )
    split: str = setting("--split", "which split of --data to use (train, val, test, or all)", "all")
    target: str = setting(
        "--target",
        "what to calibrate: the box decision offsets (default) or the offset of the rack depth the model reads",
        "box", choices=["box", "rack-depth"],
    )  # fmt: skip
    out: Path | None = setting(
        "--out", "write the calibrated checkpoint here (unset: CKPT is updated in place)", type=Path
    )
    every: int = setting("--every", "score every N-th frame (every frame is run)", 2, type=int)
    mode: str = setting(
        "--mode", "streaming (memory carried frame to frame) or windowed (the paper)", "stream",
        choices=["window", "stream"],
    )  # fmt: skip
    flip_average: bool = setting("--flip-average", FLIP_HELP, False, action="store_true")
    threads: int = setting("--threads", "CPU threads for torch", 2, type=int)
    json_out: Path | None = json_out_setting(
        "also write the scores (every box offset's, or the depth errors) as JSON here"
    )
    quiet: bool = quiet_setting()


SETTINGS = CalibrateSettings


def run(args: CalibrateSettings) -> int:
    from network.training.train_data import open_data

    check_counts(args, "threads", "every")
    torch.set_num_threads(args.threads)
    payload, record = load_checkpoint(args.checkpoint)
    model = model_from(payload, record, args.checkpoint)
    seqs = open_data(args.data).sequences(None if args.split == "all" else args.split)
    if not seqs:
        raise InputError(f"{args.data}: has no '{args.split}' sequences")
    opts = {"every": args.every, "mode": args.mode, "flip": args.flip_average, "progress": not args.quiet}
    if args.target == "rack-depth":
        res = fit_rack_depth_offset(model, seqs, **opts)
        if not res["frames"]:
            print(f"warning: {args.checkpoint} read no rack depth on {args.data}: its rack-depth offset is left at 0",
                  file=sys.stderr)  # fmt: skip
        print(
            f"rack depth: offset {100 * res['rack_depth_offset']:+.2f} cm  mean error {100 * res['error_before']:.2f} "
            f"-> {100 * res['error_after']:.2f} cm ({res['frames']} frames with a reading)"
        )
        key, source_key = "rack_depth_offset", "rack_depth_calibration"
    else:
        res = fit_box_offsets(model, seqs, grid=GRID, **opts)
        best = res["box_logit_offset"]
        for v in ("top", "front"):
            s0, sb = res["scores"][v]["0"], res["scores"][v][f"{best[v]:g}"]
            print(
                f"{v:5s}: box offset {best[v]:.2f}  rack {s0['rack'] * 100:.1f} -> {sb['rack'] * 100:.1f}  "
                f"box {s0['box'] * 100:.1f} -> {sb['box'] * 100:.1f} mIoU ({res['frames']} frames, columns in view)"
            )
        key, source_key = "box_logit_offset", "calibration"
    record = {k: v for k, v in record.items() if k not in ("format", "format_version")}
    record[key] = res[key]
    record[source_key] = {
        "data": str(args.data),
        "split": args.split,
        **{k: res[k] for k in ("frames", "mode", "flip_average", "every")},
    }
    out = args.out or args.checkpoint
    save_checkpoint(out, {k: v for k, v in payload.items() if k != "record_json"}, record)
    print(f"wrote {out} (and {Path(out).with_suffix('.json').name})")
    if args.json_out:
        atomic_write_json(args.json_out, nan_to_null(res))
    return 0
