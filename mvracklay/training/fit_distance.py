"""Stage ``fit-distance`` of ``mvracklay train``: train the distance reader that reads footage's camera distance."""

from __future__ import annotations

import argparse
from pathlib import Path

NAME = "fit-distance"
HELP = "train the distance reader (the camera-to-rack distance and the floor line, from one frame)"
DESCRIPTION = (
    "Every sample is a generated frame resampled at a wrong assumed distance; the reader learns how far off "
    "the assumption is from how sizes look, and where the floor meets the racks (with a known camera height "
    "that gives the distance by geometry). Trains on the train splits of DATA, validates on their val and "
    "test splits (the reading's median and 90th-percentile error, printed and kept with the file). "
    "`mvracklay run --distance-reader OUT` uses the result; the shipped one is mvracklay/models/distance-reader.pt."
)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("data", nargs="+", type=Path, help="generated datasets")
    p.add_argument("--out", type=Path, required=True, help="the reader file to write (.pt)")
    p.add_argument("--steps", type=int, default=2400, help="training steps")
    p.add_argument("--batch", type=int, default=32, help="frames per step")
    p.add_argument("--seed", type=int, default=0, help="seed of the samples and the initial weights")
    p.add_argument("--threads", type=int, default=2, help="torch CPU threads")


def run(args: argparse.Namespace) -> int:
    from network.training.fit_distance import fit

    figures = fit(args.data, args.out, args.steps, args.batch, args.seed, args.threads)
    print(
        f"fit-distance: wrote {args.out}; validation: median error {figures['median_error_pct']:.2f} %, "
        f"90th percentile {figures['p90_error_pct']:.2f} %"
    )
    return 0
