"""Stage ``fit-look`` of ``mvracklay train``: a trained checkpoint made to see footage in other looks as it sees
the generator's default one (the trunk tuned, everything after it as trained)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from layouts.errors import InputError
from mvracklay.settings import json_out_setting, quiet_setting, setting

NAME = "fit-look"
HELP = "tune a trained checkpoint's trunk so dim, tinted, noisy, blurred, compressed frames give its usual features"
DESCRIPTION = (
    "Every sample is a generated frame (default look) and a copy of it in a look drawn from --look (light "
    "level and an uneven field, exposure, white balance, vignetting, shot and read noise, tone curve, motion "
    "blur along the row, JPEG / H.264-like compression, each object recoloured; waresynth/restyle.py). The trunk (encoder and "
    "pyramid) is tuned so that its maps of the copy match the untouched checkpoint's maps of the frame; "
    "the decoders, the memory and the depth heads are kept as they are, so their fits still hold. Writes "
    "OUT with the record's look_fit; rerunning the command resumes an interrupted fit."
)


@dataclass(frozen=True)
class FitLookSettings:
    """The options of stage ``fit-look`` (each field's option, default and help in its metadata)."""

    checkpoint: str | None = setting(
        "--checkpoint", "a trained .pt checkpoint or a shipped model's name", required=True
    )
    data: list[Path] | None = setting(
        "--data", "generated dataset(s) in the default look", type=Path, nargs="+", required=True
    )
    sequences: int = setting("--sequences", "training sequences to use (the first N of --data)", 600, type=int)
    out: Path | None = setting("--out", "the checkpoint to write (.pt)", type=Path, required=True)
    look: str = setting(
        "--look", "the config whose lighting and sensor ranges the copies are drawn from (a file or a shipped name)",
        "wide_look",
    )  # fmt: skip
    steps: int = setting("--steps", "optimiser steps (the learning rate's cosine spans them)", 1500, type=int)
    minutes: float | None = setting("--minutes", "stop at this wall time even if steps remain", type=float)
    batch: int = setting("--batch", "frames per step", 12, type=int)
    lr: float = setting("--lr", "peak learning rate", 1e-4, type=float)
    clean_share: float = setting(
        "--clean-share", "share of samples the student sees unaltered (keeps the default look)", 0.25, type=float
    )
    layout_weight: float = setting(
        "--layout-weight",
        "weight of the single-frame layouts' divergence from the untouched model's (0: the maps and rows only)",
        1.0, type=float,
    )  # fmt: skip
    seed: int = setting("--seed", "seed of the samples and their looks", 0, type=int)
    threads: int = setting("--threads", "CPU threads for torch", 2, type=int)
    json_out: Path | None = json_out_setting("also write the fit's summary as JSON here")
    quiet: bool = quiet_setting()


SETTINGS = FitLookSettings


def run(args: FitLookSettings) -> int:
    from layouts.fileio import atomic_write_json
    from mvracklay.models import resolve_checkpoint
    from network.training.fit_look import fit_look
    from network.training.train_data import open_data
    from waresynth.restyle import Restyler

    if args.threads < 1 or args.sequences < 1:
        raise InputError(f"--threads and --sequences must be >= 1, got {args.threads} and {args.sequences}")
    if args.minutes is not None and args.minutes <= 0:
        raise InputError(f"--minutes must be > 0, got {args.minutes}")
    ckpt = resolve_checkpoint(args.checkpoint)
    restyler = Restyler(args.look)
    train, val = [], []
    for root in args.data:
        data = open_data(root)
        train += data.sequences("train")
        val += data.sequences("val") + data.sequences("test")
    train = train[: args.sequences]
    if not train or not val:
        raise InputError(f"--data {' '.join(map(str, args.data))}: needs train and val/test sequences")

    def restyle(rgb, rng, intr, step_px, labels):
        return restyler.apply(rgb, restyler.draw(rng, intr), intr, step_px, labels)

    fit = fit_look(
        ckpt, train, val, args.out, restyle,
        steps=args.steps, minutes=args.minutes, batch=args.batch, lr=args.lr, clean_share=args.clean_share, layout_weight=args.layout_weight,
        seed=args.seed, threads=args.threads, progress=not args.quiet,
        info={"look": str(args.look), "data": [str(d) for d in args.data], "sequences": len(train)},
    )  # fmt: skip
    if args.json_out:
        atomic_write_json(args.json_out, fit)
    before, after = fit["val_loss"]
    print(
        f"fit-look: wrote {args.out} after {fit['steps']} steps ({fit['wall_minutes']:.1f} min); the loss on "
        f"{len(val)} held-back sequences in drawn looks {before:.4f} -> {after:.4f}"
    )
    return 0
