"""Stage ``fit-distance`` of ``mvracklay train``: train the distance reader that reads footage's camera distance."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from mvracklay.settings import setting

NAME = "fit-distance"
HELP = "train the distance reader (the camera-to-rack distance and the floor line, from one frame)"
DESCRIPTION = (
    "Every sample is a generated frame resampled at a wrong assumed distance; the reader learns how far off "
    "the assumption is from how sizes look, and where the floor meets the racks (with a known camera height "
    "that gives the distance by geometry). Trains on the train splits of DATA, validates on their val and "
    "test splits (the reading's median and 90th-percentile error, printed and kept with the file). "
    "`mvracklay run --distance-reader OUT` uses the result; the shipped one is mvracklay/models/distance-reader.pt."
)


@dataclass(frozen=True)
class FitDistanceSettings:
    """The options of stage ``fit-distance`` (each field's option, default and help in its metadata)."""

    data: list[Path] | None = setting("data", "generated datasets", nargs="+", type=Path)
    out: Path | None = setting("--out", "the reader file to write (.pt)", type=Path, required=True)
    steps: int = setting("--steps", "training steps", 2400, type=int)
    batch: int = setting("--batch", "frames per step", 32, type=int)
    seed: int = setting("--seed", "seed of the samples and the initial weights", 0, type=int)
    threads: int = setting("--threads", "torch CPU threads", 2, type=int)


SETTINGS = FitDistanceSettings


def run(args: FitDistanceSettings) -> int:
    from network.training.fit_distance import fit

    figures = fit(args.data, args.out, args.steps, args.batch, args.seed, args.threads)
    print(
        f"fit-distance: wrote {args.out}; validation: median error {figures['median_error_pct']:.2f} %, "
        f"90th percentile {figures['p90_error_pct']:.2f} %"
    )
    return 0
