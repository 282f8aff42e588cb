"""The stages a recipe of ``mvracklay train`` names, each with its own option parser.

Every stage is a module with ``NAME``, ``HELP``, ``add_arguments(parser)`` and ``run(args)``, as a
command of the CLI has; the fitting and calibration stages were commands of their own once, and take
the same options. `run_stage` runs one stage from an argument list as the CLI ran it (one line and
status 2 on bad input): the tests drive the stages through it, and
``python -m mvracklay.training.stages NAME ARGS...`` does the same from a shell.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Sequence
from types import ModuleType
from typing import Any

from layouts.errors import InputError

#: stage name -> module holding it (imported on first use, so listing the stages stays light)
STAGE_MODULES: dict[str, str] = {
    "train": "mvracklay.training.train_network",
    "calibrate": "mvracklay.training.calibrate",
    "fit-back-edges": "mvracklay.training.fit_back_edges",
    "fit-uprights": "mvracklay.training.fit_uprights",
    "fit-box-depth": "mvracklay.training.fit_box_depth",
    "fit-distance": "mvracklay.training.fit_distance",
    "fit-look": "mvracklay.training.fit_look",
    "graft": "mvracklay.training.graft",
    "copy": "mvracklay.training.small_stages:copy",
    "export": "mvracklay.training.small_stages:export",
    "check-seeds": "mvracklay.training.small_stages:check_seeds",
    "curves": "mvracklay.training.small_stages:curves",
    "python": "mvracklay.training.small_stages:python",
    "budget": "mvracklay.training.budget",
    "generate": "mvracklay.commands.generate",
    "evaluate": "mvracklay.commands.evaluate",
    "evaluate-baseline": "mvracklay.commands.evaluate_baseline",
    "eval-reconstruction": "mvracklay.commands.eval_reconstruction",
}
#: stages the runner itself carries out (they read the run's state, not options alone)
RUNNER_STAGES = ("budget",)


class StageParser(argparse.ArgumentParser):
    """An option parser whose errors raise `InputError` (one line naming the option) instead of exiting."""

    def error(self, message: str) -> None:  # type: ignore[override]
        raise InputError(message)


def stage_module(name: str) -> Any:
    """The module (or object) holding stage ``name``; one line naming the known stages if there is none."""
    if name not in STAGE_MODULES:
        raise InputError(f"unknown stage {name!r} (known: {', '.join(sorted(STAGE_MODULES))})")
    path, _, attr = STAGE_MODULES[name].partition(":")
    mod: ModuleType = importlib.import_module(path)
    return getattr(mod, attr) if attr else mod


def stage_parser(name: str) -> StageParser:
    """Stage ``name``'s option parser (the options its command had)."""
    mod = stage_module(name)
    p = StageParser(
        prog=f"mvracklay train stage {name}",
        description=getattr(mod, "DESCRIPTION", mod.HELP),
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    mod.add_arguments(p)
    return p


def option_actions(name: str) -> dict[str, argparse.Action]:
    """Stage ``name``'s options by their long name without dashes (``pass-minutes``), and ``args`` for the
    positional arguments when it takes any."""
    out: dict[str, argparse.Action] = {}
    for a in stage_parser(name)._actions:
        if isinstance(a, argparse._HelpAction):
            continue
        if not a.option_strings:
            out.setdefault("args", a)
            continue
        longs = [s for s in a.option_strings if s.startswith("--")]
        if longs and (a.help != argparse.SUPPRESS or getattr(a, "deprecated_for", None)):  # an old name still taken
            out[longs[0][2:]] = a
    return out


def call_stage(name: str, argv: Sequence[str]) -> int:
    """Parse ``argv`` with stage ``name``'s parser and run it; bad input raises `InputError`."""
    mod = stage_module(name)
    args = stage_parser(name).parse_args(list(argv))
    return int(mod.run(args) or 0)


def run_stage(name: str, argv: Sequence[str]) -> int:
    """Run stage ``name`` with ``argv`` as its command did: 0 when done, 2 and one line on stderr on bad input."""
    try:
        return call_stage(name, argv)
    except InputError as e:
        print(f"mvracklay train: stage {name}: error: {e}", file=sys.stderr)
        return 2


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] in ("-h", "--help"):
        print("usage: python -m mvracklay.training.stages STAGE [OPTIONS...]")
        print("stages: " + ", ".join(sorted(STAGE_MODULES)))
        return 0 if argv else 2
    return run_stage(argv[0], argv[1:])


if __name__ == "__main__":
    sys.exit(main())
