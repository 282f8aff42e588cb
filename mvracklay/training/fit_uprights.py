"""Stage ``fit-uprights`` of ``mvracklay train``: give a trained checkpoint the head that reads the rack depth
from its uprights."""

from __future__ import annotations

from dataclasses import dataclass

from mvracklay.training.depth_heads import DepthFitSettings, epochs_setting, run_fit, sequences_setting
from network.training.fit_uprights import DEFAULT_FIT

NAME = "fit-uprights"
HELP = "fit the upright head (reads the rack depth from the racks' front and rear uprights) to a trained checkpoint"
DESCRIPTION = (
    "A rack's rear uprights stand a rack depth behind its front ones, at the same X, so in the image they "
    "are drawn toward the centre by a factor that gives the depth. This fits a small head that marks front "
    "and rear uprights per image column (the rest of the network frozen, one pass per frame over generated "
    "data with ground truth) and writes CKPT with the head added; predict, run and evaluate then read the "
    "rack depth from the uprights (with the back edges, when the checkpoint has that head) over the frames "
    "seen so far (--whole-sequence: over all of them). Validation prints the depth's error."
)


@dataclass(frozen=True)
class FitUprightsSettings(DepthFitSettings):
    """The options of stage ``fit-uprights``: a depth head's fit (`DepthFitSettings`), with its own defaults."""

    sequences: int = sequences_setting(1000)
    epochs: int = epochs_setting(DEFAULT_FIT.epochs)


SETTINGS = FitUprightsSettings


def run(args: FitUprightsSettings) -> int:
    from network.training.fit_uprights import fit_uprights

    return run_fit(args, DEFAULT_FIT, fit_uprights, "the uprights", "uprights", "uprights")
