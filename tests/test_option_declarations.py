"""Every long option means one thing across the commands: one type and one default wherever it is taken
(`mvracklay.settings`: each option declared once), and ``--threads`` takes ``N|auto`` everywhere."""

from __future__ import annotations

import argparse
from collections import defaultdict
from functools import lru_cache

import pytest

from mvracklay.cli import build_parser, main

#: options whose name two commands use for different things, so their defaults differ: the reason each
SAME_NAME_OTHER_DEFAULT = {
    "--mode": "evaluate scores the paper's windowed protocol; the others stream",
    "--limit": "diff: changes printed; eval-reconstruction: sequences scored",
    "--max-frames": "inspect: frames sampled for its summary; elsewhere 0 = all",
    "--layouts": "map predicts by default (net); the stitching commands read ground truth (gt)",
    "--layout-size": "generate and train: the dataset's / model's resolution; run and predict: the written one",
    "--split": "evaluate scores the test split by default; eval-reconstruction every split",
    "--workers": "train: the data loader's workers; generate and map: processes",
    "--out": "inspect writes one preview sheet; elsewhere an output folder, required",
    "--threads": "train keeps a fixed count, so that a seed's training run repeats",
}
#: options whose name two commands use for values of different kinds: the reason each
SAME_NAME_OTHER_TYPE = {
    "--rack-depth": "eval-reconstruction also takes 'scene' (each sequence's own depth)",
}


REQUIRED = object()  #: the default of a required option (never used)


@lru_cache(maxsize=1)
def _commands() -> dict[str, argparse.ArgumentParser]:
    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return dict(sub.choices)


def _declared() -> dict[str, dict[str, list[tuple[object, object]]]]:
    """``{long option: {command: [(type, default)]}}`` of every option a command declares (its old names
    and silent aliases, which take their option's value, left out)."""
    out: dict[str, dict[str, list[tuple[object, object]]]] = defaultdict(dict)
    for name, p in _commands().items():
        for a in p._actions:
            if isinstance(a, argparse._HelpAction) or a.default is argparse.SUPPRESS:
                continue
            for s in a.option_strings:
                if s.startswith("--"):  # a required option's default is never used
                    out[s].setdefault(name, []).append((a.type, REQUIRED if a.required else a.default))
    return out


def test_every_long_option_has_one_type_and_one_default():
    declared = _declared()
    problems = []
    for option, by_command in sorted(declared.items()):
        kinds = {t for pairs in by_command.values() for t, _ in pairs}
        defaults = {repr(d) for pairs in by_command.values() for _, d in pairs if d is not REQUIRED}
        if len(kinds) > 1 and option not in SAME_NAME_OTHER_TYPE:
            problems.append(f"{option}: types {sorted(map(str, kinds))} in {sorted(by_command)}")
        if len(defaults) > 1 and option not in SAME_NAME_OTHER_DEFAULT:
            problems.append(f"{option}: defaults {sorted(defaults)} in {sorted(by_command)}")
    assert not problems, "\n".join(problems)


@pytest.mark.parametrize("table", [SAME_NAME_OTHER_DEFAULT, SAME_NAME_OTHER_TYPE])
def test_the_listed_differences_are_still_there(table):
    """An option listed above whose commands came to agree leaves the list (it cannot go stale)."""
    declared = _declared()
    index = 0 if table is SAME_NAME_OTHER_TYPE else 1
    for option in table:
        seen = {repr(pair[index]) for pairs in declared[option].values() for pair in pairs if pair[1] is not REQUIRED}
        assert len(seen) > 1, f"{option} now agrees across commands: drop it from the list"


def test_threads_auto_is_taken_by_every_command_with_threads():
    with_threads = {name: a for name, p in _commands().items() for a in p._actions if "--threads" in a.option_strings}
    assert {"run", "predict", "map", "evaluate", "eval-reconstruction", "train"} <= set(with_threads)
    for name, action in with_threads.items():
        assert action.type("auto") == "auto", name
        assert action.type("3") == 3, name
        assert action.default == ("auto" if name != "train" else 2), name
        with pytest.raises(argparse.ArgumentTypeError):
            action.type("0")


def test_evaluate_takes_threads_auto_on_the_command_line(tmp_path, capsys):
    """``evaluate --threads auto`` gets past the parser: the error is the missing dataset's, not the option's."""
    rc = main(["evaluate", "--checkpoint", str(tmp_path / "m.pt"), "--data", str(tmp_path / "none"),
               "--threads", "auto"])  # fmt: skip
    err = capsys.readouterr().err
    assert rc == 2 and "--threads" not in err and "invalid" not in err


def test_diffs_tolerance_help_is_read_from_its_config():
    """``diff --same`` and the other tolerances say `DiffConfig`'s defaults (any maps; network-made), not copies."""
    from stitching.building.diff import DiffConfig

    helps = {a.dest: a.help for a in _commands()["diff"]._actions}
    for name in ("same", "size_tol", "move_tol"):
        mine, net = getattr(DiffConfig(), name), getattr(DiffConfig.network_made(), name)
        assert f"(default {mine:g}; {net:g} " in helps[name], name


def test_predict_refuses_every_auto_in_one_line(tmp_path, capsys):
    """``--every`` is one option (N|auto) everywhere; predict, whose input is no live source, names it."""
    rc = main(["predict", str(tmp_path), "--out", str(tmp_path / "o"), "--every", "auto"])
    err = capsys.readouterr().err
    assert rc == 2 and err.count("\n") == 1 and "--every must be an integer >= 1" in err
