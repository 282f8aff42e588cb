"""The stages a recipe of ``mvracklay train`` names, each with its own option parser.

Every stage is a module (or a `Stage` object) with ``NAME``, ``HELP``, ``add_arguments(parser)`` and ``run(settings)``, as
a command of the CLI has; the fitting and calibration stages were commands of their own once, and take the same
options; the stages named as commands run the library's jobs the commands run (`mvracklay.training.job_stages`),
never a command module (only the CLI imports those). A stage with ``SETTINGS`` (a settings dataclass in the style of `mvracklay.settings`: each
field's option name, default, range and help in its metadata) makes its options from it and runs on an
instance of it. `run_stage` runs one stage from an argument list as the CLI ran it (one line and
status 2 on bad input): the tests drive the stages through it, and
``python -m mvracklay.training.stages NAME ARGS...`` does the same from a shell. A recipe's stage needs no
command line: `stage_settings` builds the settings its ``run`` takes (its ``SETTINGS`` dataclass) from the
recipe's values by option name, each converted and checked by that option's own type and choices.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
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
    "blend": "mvracklay.training.blend",
    "copy": "mvracklay.training.small_stages:COPY",
    "export": "mvracklay.training.small_stages:EXPORT",
    "check-seeds": "mvracklay.training.small_stages:CHECK_SEEDS",
    "curves": "mvracklay.training.small_stages:CURVES",
    "python": "mvracklay.training.small_stages:PYTHON",
    "budget": "mvracklay.training.budget",
    "generate": "mvracklay.training.job_stages:GENERATE",
    "evaluate": "mvracklay.training.job_stages:EVALUATE",
    "evaluate-baseline": "mvracklay.training.job_stages:EVALUATE_BASELINE",
    "eval-reconstruction": "mvracklay.training.job_stages:EVAL_RECONSTRUCTION",
}
#: stages the runner itself carries out (they read the run's state, not options alone)
RUNNER_STAGES = ("budget",)


@dataclass(frozen=True)
class Stage:
    """A stage held as an object rather than a module, as a command module has it: ``NAME``, ``HELP``,
    ``SETTINGS`` (its options) and `run` (on an instance of ``SETTINGS``)."""

    NAME: str
    HELP: str
    SETTINGS: type
    run: Callable[[Any], int]


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
    from mvracklay.settings import add_options

    cls = getattr(mod, "SETTINGS", None)
    add_options(p, cls) if cls is not None else mod.add_arguments(p)
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


def stage_config(name: str) -> type | None:
    """Stage ``name``'s settings dataclass (``SETTINGS``); None for a stage that runs on parsed options."""
    return getattr(stage_module(name), "SETTINGS", None)


def settings_of(name: str, parsed: argparse.Namespace) -> Any:
    """What stage ``name``'s ``run`` takes from its parsed options: its ``SETTINGS`` dataclass, else them."""
    from mvracklay.settings import from_args

    cls = stage_config(name)
    return parsed if cls is None else from_args(cls, parsed)


def stage_settings(name: str, options: Mapping[str, Any], args: Sequence[Any] = (), where: str | None = None) -> Any:
    """Stage ``name``'s settings as its ``run`` takes them (its ``SETTINGS`` dataclass): ``options`` by long
    option name (``pass-minutes``; a switch ``true`` / ``false``, a list for several values), ``args`` its
    positional arguments; the fields' defaults for the rest. Each value is converted and checked as its option
    converts it (`mvracklay.options.config_value`); an unknown or missing one is one line (`InputError`),
    beginning with ``where`` (default: the stage's name; "": a recipe's, which names its file and stage).
    """
    from mvracklay.options import config_value

    label = (lambda key: key) if where != "" else (lambda key: f"option {key!r}")
    where = f"stage {name}" if where is None else where

    parser = stage_parser(name)
    by_name = option_actions(name)
    ns = argparse.Namespace()
    for a in parser._actions:
        if a.dest == argparse.SUPPRESS or a.default is argparse.SUPPRESS or hasattr(ns, a.dest):
            continue
        given = isinstance(a.default, str) and callable(a.type)
        setattr(ns, a.dest, a.type(a.default) if given else a.default)  # as argparse converts a string default
    seen = set()
    for key, value in options.items():
        action = by_name.get(key) or parser._option_string_actions.get(f"--{key}")  # a hidden alias too
        if action is None or key == "args":
            raise InputError(f"unknown option {key!r} (the {name} stage takes: {', '.join(sorted(by_name))})")
        if getattr(action, "deprecated_for", None):
            print(f"warning: --{key} is deprecated here: use {action.deprecated_for} (same value)", file=sys.stderr)
        setattr(ns, action.dest, config_value(action, label(key), value, where))
        seen.add(action.dest)
    seen |= _positionals(parser, ns, [str(a) for a in args], where)
    missing = [a for a in parser._actions if a.required and a.dest not in seen]
    if missing:
        said = ", ".join("/".join(a.option_strings) or a.metavar or a.dest for a in missing)
        raise InputError(f"the following arguments are required: {said}")
    return settings_of(name, ns)


def _positionals(parser: argparse.ArgumentParser, ns: argparse.Namespace, args: list[str], where: str) -> set[str]:
    """``args`` shared out over the parser's positional arguments in order, each taking what its ``nargs``
    allows while leaving the later ones their least; returns the dests set."""
    from mvracklay.options import config_value

    positionals = [a for a in parser._actions if not a.option_strings]
    least = [0 if a.nargs in ("?", "*") else 1 if a.nargs in (None, "+") else int(a.nargs) for a in positionals]
    seen, i = set(), 0
    for k, a in enumerate(positionals):
        room = max(len(args) - i - sum(least[k + 1 :]), min(least[k], len(args) - i))  # the earlier ones first
        take = 1 if a.nargs in (None, "?") else room if a.nargs in ("*", "+") else int(a.nargs)
        take = max(0, min(take, room))
        if take < least[k]:
            break  # too few: the required check names what is missing
        if take:
            value = args[i : i + take] if a.nargs not in (None, "?") else args[i]
            setattr(ns, a.dest, config_value(a, a.metavar or a.dest, value, where))
            seen.add(a.dest)
        i += take
    if i < len(args):
        raise InputError(f"{where + ': ' if where else ''}unrecognized arguments: {' '.join(args[i:])}")
    return seen


def run_settings(name: str, settings: Any) -> int:
    """Run stage ``name`` on its settings (`stage_settings`); bad input raises `InputError`."""
    return int(stage_module(name).run(settings) or 0)


def call_stage(name: str, argv: Sequence[str]) -> int:
    """Parse ``argv`` with stage ``name``'s parser and run it; bad input raises `InputError`."""
    mod = stage_module(name)
    args = stage_parser(name).parse_args(list(argv))
    return int(mod.run(settings_of(name, args)) or 0)


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
