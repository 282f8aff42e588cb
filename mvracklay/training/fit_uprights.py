"""Stage ``fit-uprights`` of ``mvracklay train``: give a trained checkpoint the head that reads the rack depth
from its uprights."""

from __future__ import annotations

import argparse

from mvracklay.training.depth_heads import add_fit_arguments, run_fit

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


def add_arguments(p: argparse.ArgumentParser) -> None:
    from network.training.fit_uprights import DEFAULT_FIT

    add_fit_arguments(p, sequences=1000, epochs=DEFAULT_FIT.epochs)


def run(args: argparse.Namespace) -> int:
    from network.training.fit_uprights import DEFAULT_FIT, fit_uprights

    return run_fit(args, DEFAULT_FIT, fit_uprights, "the uprights", "uprights", "uprights")
