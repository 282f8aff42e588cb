"""``mvracklay merge-shards``: join the shards of ``generate --shard I/N`` into one dataset."""

from __future__ import annotations

import argparse

from mvracklay.command_settings import MergeShardsSettings
from mvracklay.settings import add_options

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
    add_options(p, MergeShardsSettings)


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
