"""Stage ``fit-back-edges`` of ``mvracklay train``: give a trained checkpoint the head that reads the rack depth."""

from __future__ import annotations

from dataclasses import dataclass

from mvracklay.training.depth_heads import DepthFitSettings, epochs_setting, run_fit, sequences_setting

NAME = "fit-back-edges"
HELP = "fit the back-edge head (reads the rack depth from the shelf boards' back edges) to a trained checkpoint"
DESCRIPTION = (
    "The top view is centred on the rack's depth, so a misread rack depth moves every shelf front and box. "
    "This fits a small head that finds the shelf boards' back edges in the image (the rest of the network "
    "frozen, one pass per frame over generated data with ground truth) and writes CKPT with the head added; "
    "predict, run and evaluate then read the rack depth from the back edges over the frames seen so far "
    "and redraw the top views at it (--no-depth-read turns that off). Validation prints the depth's error."
)


@dataclass(frozen=True)
class FitBackEdgesSettings(DepthFitSettings):
    """The options of stage ``fit-back-edges``: a depth head's fit (`DepthFitSettings`), with its own defaults."""

    sequences: int = sequences_setting(1200)
    epochs: int = epochs_setting(20)


SETTINGS = FitBackEdgesSettings


def run(args: FitBackEdgesSettings) -> int:
    from network.training.fit_back_edges import FitConfig, fit_back_edges

    return run_fit(args, FitConfig(), fit_back_edges, "the back edges", "back_edges", "back")
