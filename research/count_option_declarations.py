"""Count the places each long command-line option is declared in the product packages.

A place is a declaring call (`DECLARING`) whose positional arguments hold the option's name as a string literal
(``p.add_argument("--threads", ...)``, ``setting("--threads", ...)``), or a call of a function that
declares options itself (``add_threads_option(p)``: the options that function's body names). Prints
the options declared in more than one place, with their counts, and the total.

    python research/count_option_declarations.py [PACKAGE ...]
"""

from __future__ import annotations

import ast
import collections
import sys
from pathlib import Path

PACKAGES = ("mvracklay", "layouts", "network", "stitching", "waresynth")
#: the calls that declare an option by its name (argparse's, and the settings layer's field makers)
DECLARING = {"add_argument", "add", "setting", "option", "_run", "_with_checkpoint", "add_hidden_alias", "_angle"}


def _long(node: ast.AST) -> str | None:
    if isinstance(node, ast.Constant) and isinstance(node.value, str):
        text = node.value
        if text.startswith("--") and len(text) > 2 and " " not in text and "=" not in text:
            return text
    return None


def _callee(call: ast.Call) -> str:
    f = call.func
    return f.attr if isinstance(f, ast.Attribute) else f.id if isinstance(f, ast.Name) else ""


def main(packages: tuple[str, ...]) -> int:
    trees = {}
    for pkg in packages:
        for path in sorted(Path(pkg).rglob("*.py")):
            trees[path] = ast.parse(path.read_text(encoding="utf-8"))
    declares: dict[str, set[str]] = {}  # a function that declares options -> their names
    for tree in trees.values():
        for fn in ast.walk(tree):
            if isinstance(fn, ast.FunctionDef) and fn.name.startswith("add_") and fn.name.endswith("_option"):
                names = {n for c in ast.walk(fn) if isinstance(c, ast.Call) for a in c.args if (n := _long(a))}
                if names:
                    declares[fn.name] = names
    places: collections.Counter[str] = collections.Counter()
    for tree in trees.values():
        for call in ast.walk(tree):
            if not isinstance(call, ast.Call):
                continue
            if _callee(call) in DECLARING:
                for name in {n for a in call.args[:2] if (n := _long(a))}:
                    places[name] += 1
            for name in declares.get(_callee(call), ()):
                places[name] += 1
    repeated = {k: v for k, v in places.items() if v > 1}
    for name, n in sorted(repeated.items(), key=lambda kv: (-kv[1], kv[0])):
        print(f"{n:3d}  {name}")
    print(f"{len(repeated)} long options declared in more than one place (of {len(places)})")
    return 0


if __name__ == "__main__":
    sys.exit(main(tuple(sys.argv[1:]) or PACKAGES))
