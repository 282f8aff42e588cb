"""No module but the CLI reaches a command module by name either: an import path in a string (``importlib``,
``__import__``, a registry of ``"module:attr"`` names) is an import too. tests/test_arrows.py reads the import
statements; this reads the strings."""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
#: a string that names a command module (or something in one): ``mvracklay.commands.run``, ``...:run``
COMMAND_PATH = re.compile(r"^mvracklay\.commands(\.[A-Za-z_][\w.]*)?(:\w+)?$")
#: the CLI, the one test that patches a command's ``run`` to see how the CLI reports an interrupt, and the import
#: statements' own check (it names the package it refuses)
ALLOWED = ("mvracklay/cli.py", "tests/test_cli_light.py", "tests/test_arrows.py")


def command_strings(source: str, name: str = "<source>") -> list[int]:
    """Lines of ``source`` with a string naming a command module: a whole constant, or an f-string's leading text."""
    lines = []
    for node in ast.walk(ast.parse(source, name)):
        if isinstance(node, ast.Constant) and isinstance(node.value, str):
            text = node.value
        elif isinstance(node, ast.JoinedStr) and node.values and isinstance(node.values[0], ast.Constant):
            text = str(node.values[0].value).rstrip(".")
        else:
            continue
        if COMMAND_PATH.match(text.strip()):
            lines.append(node.lineno)
    return lines


@pytest.mark.parametrize("folder", ["mvracklay", "layouts", "waresynth", "network", "stitching", "demos", "tests",
                                    "benchmarks", "scripts"])  # fmt: skip
def test_no_module_names_a_command_module_in_a_string(folder):
    bad = []
    for path in sorted((ROOT / folder).rglob("*.py")):
        rel = path.relative_to(ROOT).as_posix()
        if rel.startswith("mvracklay/commands/") or rel in ALLOWED or "/.venv/" in rel:
            continue
        bad += [f"{rel}:{line} names a command module" for line in command_strings(path.read_text(encoding="utf-8"))]
    assert not bad, "\n".join(bad)


def test_the_check_sees_an_importlib_path_a_registry_entry_and_an_f_string():
    source = (
        "import importlib\n"
        "mod = importlib.import_module('mvracklay.commands.generate')\n"
        "STAGES = {'evaluate': 'mvracklay.commands.evaluate:run'}\n"
        "other = __import__(f'mvracklay.commands.{name}')\n"
        "said = 'the commands live in mvracklay.commands, each a module'\n"  # prose: not a path
        "job = importlib.import_module('mvracklay.generate_job')\n"
    )
    assert command_strings(source) == [2, 3, 4]
