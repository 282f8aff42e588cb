"""The network package's layers point one way: heads <- model <- inference <- training (the shared basics,
`network.fastops`, `precision`, `data`, `checkpoint`, sit beside them).

What a user runs (`network.inference`) and what a model is made of (`network.model`, `network.heads`) never
import the code that trains or fits them (`network.training`), so inference works without it and no import
circle runs through training.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

NETWORK = Path(__file__).resolve().parents[1] / "network"
#: subpackage -> the subpackages it must not import
FORBIDDEN = {
    "model": ("network.training", "network.inference"),
    "heads": ("network.training", "network.inference", "network.model"),
    "inference": ("network.training",),
}


def imported_modules(path: Path) -> list[tuple[int, str]]:
    """``(line, module)`` of every import in a source file, at any depth (function-level imports too)."""
    out = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            out += [(node.lineno, a.name) for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and not node.level:
            out.append((node.lineno, node.module))
            out += [(node.lineno, f"{node.module}.{a.name}") for a in node.names]  # `from network import training`
    return out


@pytest.mark.parametrize("layer", sorted(FORBIDDEN))
def test_a_layer_imports_nothing_above_it(layer):
    files = sorted((NETWORK / layer).rglob("*.py"))
    assert files, f"network/{layer} holds no modules"
    bad = [
        f"{path.relative_to(NETWORK.parent)}:{line} imports {name}"
        for path in files
        for line, name in imported_modules(path)
        if any(name == f or name.startswith(f + ".") for f in FORBIDDEN[layer])
    ]
    assert not bad, "\n".join(bad)


def test_no_relative_imports_hide_from_the_check():
    rel = [
        str(p.relative_to(NETWORK.parent))
        for p in NETWORK.rglob("*.py")
        if any(isinstance(n, ast.ImportFrom) and n.level for n in ast.walk(ast.parse(p.read_text())))
    ]
    assert not rel, rel
