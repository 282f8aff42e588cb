"""``mvracklay merge-shards``: join the shards of ``generate --shard I/N`` into one dataset."""

from __future__ import annotations

import argparse
from pathlib import Path

from mvracklay.options import add_quiet_option

NAME = "merge-shards"
GROUP = "data"
ORDER = 23
#: what `mvracklay` says when the command is interrupted
RESUME = "re-run the same command to resume"
HELP = "join dataset shards written by `generate --shard I/N` into one dataset with one manifest"
DESCRIPTION = (
    "Check that the SHARD_DIRs were generated with the same settings and together hold every sequence "
    "exactly once, complete; then move (or with --link hard-link) their sequence folders into OUT and write "
    "OUT/manifest.json last, atomically. The result is byte-identical to an unsharded `generate` run. "
    "An interrupted merge is resumed by running the same command again. See docs/scale_and_safety.md."
)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("out", metavar="OUT", type=Path, help="merged dataset folder (new or empty)")
    p.add_argument("shards", metavar="SHARD_DIR", type=Path, nargs="+", help="shard folders, all N of them")
    p.add_argument(
        "--link",
        action="store_true",
        help="hard-link the files instead of moving the folders (the shards stay usable; copies across filesystems)",
    )
    add_quiet_option(p, "hide the progress bar")


def run(args: argparse.Namespace) -> int:
    from waresynth.dataset import open_dataset
    from waresynth.shards import merge_shards

    root = merge_shards(args.out, args.shards, link=args.link, progress=not args.quiet)
    ds = open_dataset(root)
    counts = {s: len(ds.sequences(s)) for s in ("train", "val", "test")}
    print(
        f"{root}: merged {len(args.shards)} shards, {sum(counts.values())} sequences "
        f"(train {counts['train']}, val {counts['val']}, test {counts['test']})"
        + ("" if args.link else "; the shard folders now hold only their manifest.json")
    )
    return 0
