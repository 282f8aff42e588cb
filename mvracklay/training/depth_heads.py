"""What the `fit-back-edges` and `fit-uprights` stages share: their options and the depth errors they print."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import torch

from layouts.errors import InputError
from layouts.fileio import atomic_write_json, nan_to_null
from mvracklay.options import check_counts
from mvracklay.settings import json_out_setting, precision_setting, quiet_setting, setting
from network.model.frozen import trunk_precision, use_precision


def jpeg_share_setting() -> Any:
    """``--jpeg P``: the share of training sequences a fit sees JPEG-compressed."""
    return setting(
        "--jpeg",
        "share of the training sequences whose frames go through JPEG, one quality per sequence drawn from "
        "--jpeg-quality with --seed, as a compressing camera or a video file delivers them (--val stays as it is; "
        "0 = off, default %(default)s)",
        0.0, type=float, metavar="P",
    )  # fmt: skip


def jpeg_quality_setting() -> Any:
    """``--jpeg-quality LOW HIGH``: the JPEG quality range of ``--jpeg``."""
    return setting(
        "--jpeg-quality", "the JPEG quality range of --jpeg, 1 (worst) to 95 (default %(default)s)", [30, 95],
        type=int, nargs=2, metavar=("LOW", "HIGH"),
    )  # fmt: skip


def sequences_setting(default: int) -> Any:
    return setting("--sequences", "training sequences to use (the first N of --data)", default, type=int)


def epochs_setting(default: int) -> Any:
    return setting("--epochs", "passes over the training frames", default, type=int)


@dataclass(frozen=True)
class DepthFitSettings:
    """The options of a stage that fits a depth head to a trained checkpoint (the trunk frozen); each stage
    sets its own ``sequences`` and ``epochs`` defaults."""

    checkpoint: Path | None = setting(
        "--checkpoint", "a trained .pt checkpoint (its .json beside)", type=Path, required=True
    )
    data: list[Path] | None = setting(
        "--data", "generated dataset(s) with ground truth to fit on", type=Path, nargs="+", required=True
    )
    sequences: int = sequences_setting(1000)
    val: Path | None = setting("--val", "generated dataset to measure the depth read on (never trained on)", type=Path)
    epochs: int = epochs_setting(20)
    every: int = setting("--every", "use every N-th frame", 1, type=int)
    seed: int = setting("--seed", "seed of the head's initial weights and batch order", 0, type=int)
    out: Path | None = setting("--out", "write the new checkpoint here (unset: CKPT is updated in place)", type=Path)
    threads: int = setting("--threads", "CPU threads for torch", 2, type=int)
    json_out: Path | None = json_out_setting("also write the fit's summary as JSON here")
    quiet: bool = quiet_setting("hide the progress bars")
    precision: str = precision_setting()
    jpeg: float = jpeg_share_setting()
    jpeg_quality: list[int] = jpeg_quality_setting()


def training_sequences(args: Any) -> list[Any]:
    """The first ``--sequences`` of ``--data``, a ``--jpeg`` share of them compressed; one line if none."""
    from network.data import check_jpeg, compress_share
    from network.training.train_data import open_data

    quality = tuple(args.jpeg_quality)
    check_jpeg(args.jpeg, quality, ("--jpeg", "--jpeg-quality"))
    train = [s for root in args.data for s in open_data(root).sequences(None)][: args.sequences]
    if not train:
        raise InputError(f"--data {' '.join(map(str, args.data))}: no sequences")
    return compress_share(train, args.jpeg, quality, args.seed)


def jpeg_record(args: Any) -> dict[str, Any]:
    """What the checkpoint's record notes of ``--jpeg`` (nothing when off)."""
    return {"jpeg": args.jpeg, "jpeg_quality": list(args.jpeg_quality)} if args.jpeg > 0 else {}


def run_fit(args: Any, cfg: Any, fit: Callable[..., Any], source: str, flag: str, name: str) -> int:
    """Fit a depth head with ``fit(model, train, val, cfg, progress)`` and write the checkpoint with it:
    its weights under ``name.``, the model config's ``flag`` set, the fit's summary in the record under
    ``flag``; prints the depth errors ``source`` gives."""
    from network.checkpoint import load_checkpoint, model_from, save_with_head
    from network.training.train_data import open_data

    check_counts(args, "threads", "sequences")
    cfg = replace(cfg, epochs=args.epochs, every=args.every, seed=args.seed)
    cfg.validate()
    torch.set_num_threads(args.threads)
    payload, record = load_checkpoint(args.checkpoint)
    model = model_from(payload, record, args.checkpoint)
    use_precision(model, args.precision)
    train = training_sequences(args)
    val = open_data(args.val).sequences(None) if args.val else []
    head, summary = fit(model, train, val, cfg, progress=not args.quiet)
    print_depth_errors(summary, source)
    out = args.out or args.checkpoint
    val_name = str(args.val) if args.val else None
    precision = trunk_precision(model)  # what the pass ran, as the other records say
    info = {
        "data": [str(d) for d in args.data],
        "val": val_name,
        **jpeg_record(args),
        "precision": precision,
        **summary,
    }
    save_with_head(out, payload, record, replace(model.cfg, **{flag: True}), name, head, flag, info)
    print(f"wrote {out} (and {Path(out).with_suffix('.json').name})")
    if args.json_out:
        atomic_write_json(args.json_out, nan_to_null(summary))
    return 0


def print_depth_errors(summary: dict[str, Any], source: str) -> None:
    """One line per part (train, val) of a fit's summary: the rack depth ``source`` gives, per frame, over
    the frames so far and at a sequence's end (and the marks' precision / recall where the fit has them)."""
    for name in ("train_depth", "val_depth"):
        if name not in summary:
            continue
        d = summary[name]
        line = (
            f"{name.split('_')[0]:5s} rack depth error from {source} ({d['sequences']} sequences, {d['frames']} "
            f"frames): {cm(d['mae_frame'])} one frame, {cm(d['mae_running'])} over the frames so far, "
            f"{cm(d['mae_sequence'])} at a sequence's end"
        )
        if "marks" in d:
            line += "; marks precision / recall " + ", ".join(
                f"{k} {100 * m['precision']:.0f} / {100 * m['recall']:.0f} %" for k, m in d["marks"].items()
            )
        print(line)


def cm(metres: float | None) -> str:
    return "n/a" if metres is None else f"{100 * metres:.1f} cm"
