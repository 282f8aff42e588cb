"""``mvracklay generate``: write a WareSynth synthetic dataset (resumable)."""

from __future__ import annotations

import argparse
from pathlib import Path

from layouts.errors import InputError
from mvracklay.options import add_quiet_option

NAME = "generate"
GROUP = "data"
ORDER = 20
#: what `mvracklay` says when the command is interrupted
RESUME = "re-run the same command to resume: complete sequences are kept"
HELP = "generate a synthetic warehouse dataset (WareSynth) with ground-truth layouts"
DESCRIPTION = (
    "Render camera sequences along procedurally generated rack rows: RGB, depth, semantic and "
    "instance images plus top/front layouts per shelf, intrinsics, poses and 3D cuboids. "
    "Re-running the same command resumes an interrupted run (complete sequences are skipped) "
    "and gives byte-identical output. See docs/waresynth.md for the format and the config keys."
)


def add_arguments(p: argparse.ArgumentParser) -> None:
    from waresynth.exporters import EXPORT_FORMATS

    p.add_argument("out", metavar="OUT", type=Path, help="output dataset folder")
    p.add_argument("--sequences", metavar="N", type=int, default=10, help="sequences (one scene + camera path each)")
    p.add_argument("--frames", metavar="F", type=int, default=50, help="frames per sequence")
    p.add_argument("--size", metavar="S", type=int, default=256, help="image width and height in pixels")
    p.add_argument("--layout-size", metavar="D", type=int, default=128, help="layout resolution (pixels per side)")
    p.add_argument("--slots", metavar="R", type=int, default=3, help="shelf slots per layout")
    p.add_argument("--seed", type=int, default=0, help="dataset seed (same seed + config -> same bytes)")
    p.add_argument(
        "--config",
        metavar="FILE",
        type=Path,
        default=None,
        help="JSON config overriding waresynth/default_config.json, or a shipped one by name (wide_look: the wider camera and building look meant for training; shifted_look: a look outside it, for held-out tests)",
    )
    p.add_argument(
        "--supersample",
        metavar="S",
        type=int,
        choices=(1, 2, 3, 4),
        default=None,
        help="each pixel's colour the mean of S x S rays over its area, as a camera's sensor integrates light "
        "(S^2 the rendering cost; depth and labels stay sampled at pixel centres); sets the config's "
        "sensor.supersample (default: the config's, 1)",
    )
    p.add_argument("--workers", metavar="W", type=int, default=1, help="worker processes (one sequence at a time each)")
    p.add_argument(
        "--format",
        choices=("native", *EXPORT_FORMATS),
        default="native",
        help="also export the dataset in this format (as `mvracklay export` does) to --export-out",
    )
    p.add_argument(
        "--export-out", metavar="DIR", type=Path, default=None, help="export folder (default: OUT_<format> beside OUT)"
    )
    p.add_argument(
        "--overwrite", action="store_true", help="delete a non-empty OUT (or export folder) that is not this dataset"
    )
    p.add_argument(
        "--shard",
        metavar="I/N",
        default=None,
        help="write only shard I of N (sequences k with k %% N == I), e.g. one job of an array; "
        "join the shards with `mvracklay merge-shards`",
    )
    add_quiet_option(p, "hide the progress bar")


def run(args: argparse.Namespace) -> int:
    from layouts.spec import LayoutSpec
    from waresynth.dataset import open_dataset
    from waresynth.generate import generate_dataset

    for flag, value, lo, hi in (
        ("--sequences", args.sequences, 1, 100000),
        ("--frames", args.frames, 1, 100000),
        ("--size", args.size, 16, 8192),
        ("--layout-size", args.layout_size, 1, 4096),
        ("--slots", args.slots, 1, 16),
        ("--workers", args.workers, 1, 256),
        ("--seed", args.seed, 0, 2**63 - 1),
    ):
        if not lo <= value <= hi:
            raise InputError(f"{flag} must be in [{lo}, {hi}], got {value}")
    from layouts.publish import refuse_overlap

    if args.config is not None and Path(args.config).exists():
        refuse_overlap([args.out], {"--config": args.config}, "OUT")
    if args.format != "native" and args.export_out is not None:
        refuse_overlap([args.export_out], {"OUT": args.out}, "--export-out")
    shard = None
    if args.shard is not None:
        from waresynth.generate import parse_shard

        shard = parse_shard(args.shard)
        if args.format != "native":
            raise InputError("--format exports a whole dataset: export after `mvracklay merge-shards`, not per shard")
    config = args.config
    if args.supersample is not None:
        from waresynth.config import load_config

        config = load_config(config)  # the file checked under its own name first
        config["sensor"]["supersample"] = args.supersample
    spec = LayoutSpec(num_slots=args.slots, size=args.layout_size)
    root = generate_dataset(
        args.out,
        num_sequences=args.sequences,
        frames=args.frames,
        image_size=(args.size, args.size),
        spec=spec,
        seed=args.seed,
        config=config,
        workers=args.workers,
        overwrite=args.overwrite,
        progress=not args.quiet,
        shard=shard,
    )
    ds = open_dataset(root)
    counts = {s: len(ds.sequences(s)) for s in ("train", "val", "test")}
    what = "" if shard is None else f" (shard {shard[0]}/{shard[1]}; join with `mvracklay merge-shards`)"
    print(
        f"{root}{what}: {sum(counts.values())} sequences x {args.frames} frames "
        f"(train {counts['train']}, val {counts['val']}, test {counts['test']}), "
        f"images {args.size}x{args.size}, layouts {spec.shape}"
    )
    if args.format != "native":
        from waresynth.exporters import export_dataset

        dest = args.export_out or root.parent / f"{root.name}_{args.format}"
        if dest.is_dir() and any(dest.iterdir()) and not args.overwrite:
            # A re-run (resume) of the same command: the export was made from this same dataset.
            print(f"{dest}: exists, kept (pass --overwrite to export again)")
            return 0
        out = export_dataset(root, dest, args.format, overwrite=args.overwrite, progress=not args.quiet)
        print(f"{out}: {args.format} export")
    return 0
