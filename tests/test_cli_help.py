"""`mvracklay COMMAND --help` explains every option."""

from __future__ import annotations

import argparse

from mvracklay.cli import build_parser


def test_every_option_of_every_command_has_help() -> None:
    parser = build_parser()
    (sub,) = (a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    assert len(sub.choices) >= 10
    bare = [
        f"{name} {'/'.join(a.option_strings or [a.dest])}"
        for name, p in sub.choices.items()
        for a in p._actions
        if not isinstance(a, argparse._HelpAction) and not (a.help or "").strip()
    ]
    assert not bare, "options without help: " + ", ".join(bare)
