"""``mvracklay train``: train the layout network, or run a whole training recipe (data, training, calibration,
the depth heads, evaluation) with ``--recipe``.

This module stays light (no torch at import): the training options and the work live in
`mvracklay.training` and are imported when the command runs.
"""

from __future__ import annotations

import argparse
from dataclasses import fields
from pathlib import Path

from layouts.errors import InputError
from mvracklay.training import TRAIN_DESCRIPTION

NAME = "train"
GROUP = "models"
HELP = "train the layout network, or run a training recipe of stages (--recipe smoke|default-128|budget-256|FILE)"
DESCRIPTION = TRAIN_DESCRIPTION + (
    " --recipe NAME|FILE runs a recipe instead: the data it generates and its stages in order (training, "
    "calibrate, fit-back-edges, fit-uprights, fit-box-depth, graft, evaluate, ...) into --out; the same "
    "command again goes on at the stage it reached; --dry-run prints the stages and their arguments; "
    "see docs/training.md."
)
ORDER = 30
#: what `mvracklay` says when interrupted
RESUME = "re-run with --resume to continue from RUN/last.pt; a --recipe run: the same command again"
#: the options of this command that go with --recipe (the others belong to the plain training run)
RECIPE_OPTIONS = ("recipe", "set", "dry_run", "out", "quiet")


def add_arguments(p: argparse.ArgumentParser) -> None:
    from mvracklay.command_settings import RecipeSettings
    from mvracklay.settings import add_options
    from mvracklay.training.train_network import TrainSettings

    out = next(f for f in fields(TrainSettings) if f.name == "out").metadata["help"]
    # a recipe's run folder defaults to the user's cache folder (checked in `run` otherwise)
    more = "; with --recipe by default $XDG_CACHE_HOME/mvracklay/train/RECIPE (~/.cache/...)"
    add_options(p, TrainSettings, helps={"out": out + more}, out={"required": False})
    add_options(p, RecipeSettings)


def run(args: argparse.Namespace) -> int:
    if args.recipe is None:
        if args.set or args.dry_run:
            raise InputError("--set and --dry-run go with --recipe")
        if args.out is None:
            raise InputError("--out is required: the run folder (or the weights file with --export)")
        from mvracklay.settings import from_args
        from mvracklay.training.train_network import TrainSettings
        from mvracklay.training.train_network import run as train

        return train(from_args(TrainSettings, args))
    _refuse_training_options(args)
    from mvracklay.training.runner import default_run_folder, run_recipe

    out = Path(args.out) if args.out is not None else default_run_folder(args.recipe)
    return run_recipe(args.recipe, out, list(args.set), dry_run=args.dry_run, quiet=args.quiet)


def _refuse_training_options(args: argparse.Namespace) -> None:
    """With --recipe the recipe sets the training options: one given on the command line is refused."""
    p = argparse.ArgumentParser()
    add_arguments(p)
    defaults = vars(p.parse_args(["--out", "x"]))
    given = [k for k, v in vars(args).items() if k in defaults and k not in RECIPE_OPTIONS and v != defaults[k]]
    if given:
        flag = "--" + given[0].replace("_", "-")
        raise InputError(f"{flag}: not with --recipe (change the recipe's stage with --set stage.ID.KEY=VALUE)")
