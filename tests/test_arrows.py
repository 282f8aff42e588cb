"""The arrows between the top-level packages point one way (DESIGN.md, "Components").

``layouts`` is the floor (numpy, scipy, scikit-image and Pillow's resampling beside the standard library);
``waresynth`` and ``stitching`` stand on it and on nothing else of ours; ``network`` stands on it and reads
datasets through ``waresynth`` from one module only; ``mvracklay`` composes them all and only the application
folders (demos, tests, benchmarks, scripts, research) import it; ``research`` is imported by nothing. Inside a
package, a wing (the building: ``stitching/building/``, ``waresynth/building/``) stands on the rest of its package,
which never imports it. Every import is read, function-level ones too; a relative import is refused so that none
hides from the check.
"""

from __future__ import annotations

import ast
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
OURS = ("layouts", "waresynth", "network", "stitching", "mvracklay", "research")
#: package -> the packages of ours it may import (itself always)
MAY_IMPORT = {
    "layouts": (),
    "waresynth": ("layouts",),
    "stitching": ("layouts",),
    "network": ("layouts", "waresynth"),
    "mvracklay": ("layouts", "waresynth", "network", "stitching"),
}
#: the third-party packages the floor may import (Pillow: the canonical warp's and the lens's resampling)
LAYOUTS_THIRD_PARTY = {"numpy", "scipy", "skimage", "PIL"}
#: the one module of ``network`` that reads datasets, so the one that imports ``waresynth``
DATASET_READER = "network/training/train_data.py"
#: wings of a package: each may import the rest of its package; the rest never imports it
WINGS = ("stitching.building", "waresynth.building")


def imports(path: Path) -> list[tuple[int, str, int]]:
    """``(line, top-level module, relative level)`` of every import in ``path``, at any depth."""
    out = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), str(path))):
        if isinstance(node, ast.Import):
            out += [(node.lineno, a.name.split(".")[0], 0) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            out.append((node.lineno, (node.module or "").split(".")[0], node.level))
    return out


def dotted_imports(path: Path) -> list[tuple[int, str]]:
    """``(line, dotted name)`` of every module ``path`` imports and every name it imports from one (``from a import
    b`` gives ``a`` and ``a.b``: ``b`` may be a module), at any depth."""
    out = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), str(path))):
        if isinstance(node, ast.Import):
            out += [(node.lineno, a.name) for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module:
            out += [(node.lineno, node.module)] + [(node.lineno, f"{node.module}.{a.name}") for a in node.names]
    return out


def _files(folder: str) -> list[Path]:
    files = sorted((ROOT / folder).rglob("*.py"))
    assert files, f"{folder}/ holds no modules"
    return files


def _where(path: Path, line: int, name: str) -> str:
    return f"{path.relative_to(ROOT)}:{line} imports {name}"


@pytest.mark.parametrize("package", sorted(MAY_IMPORT))
def test_a_package_imports_only_what_stands_below_it(package):
    allowed = {package, *MAY_IMPORT[package]}
    bad = []
    for path in _files(package):
        rel = path.relative_to(ROOT).as_posix()
        for line, name, _ in imports(path):
            if name in OURS and name not in allowed:
                bad.append(_where(path, line, name))
            elif name == "waresynth" and package == "network" and rel != DATASET_READER:
                bad.append(_where(path, line, name) + f" (only {DATASET_READER} reads datasets)")
    assert not bad, "\n".join(bad)


def test_the_floor_imports_numpy_scipy_skimage_pillow_and_the_standard_library_only():
    allowed = LAYOUTS_THIRD_PARTY | set(sys.stdlib_module_names) | {"layouts", "__future__"}
    bad = [_where(p, line, name) for p in _files("layouts") for line, name, _ in imports(p) if name not in allowed]
    assert not bad, "\n".join(bad)


@pytest.mark.parametrize("folder", ["demos", "tests", "benchmarks", "scripts", *sorted(MAY_IMPORT)])
def test_nothing_imports_research(folder):
    files = [p for p in _files(folder) if p.name != Path(__file__).name]
    bad = [_where(p, line, name) for p in files for line, name, _ in imports(p) if name == "research"]
    assert not bad, "\n".join(bad)


@pytest.mark.parametrize("package", sorted(MAY_IMPORT))
def test_no_relative_import_hides_from_the_check(package):
    bad = [_where(p, line, "." * level + name) for p in _files(package) for line, name, level in imports(p) if level]
    assert not bad, "\n".join(bad)


@pytest.mark.parametrize("wing", WINGS)
def test_a_wing_stands_on_its_package_and_the_package_never_on_it(wing):
    package, folder = wing.split(".")[0], ROOT / wing.replace(".", "/")
    assert (folder / "__init__.py").is_file(), f"{wing} is no package"
    bad = [
        f"{path.relative_to(ROOT)}:{line} imports {name}"
        for path in _files(package)
        if folder not in path.parents
        for line, name in dotted_imports(path)
        if name == wing or name.startswith(wing + ".")
    ]
    assert not bad, "\n".join(bad)


def test_the_check_sees_a_bad_arrow(tmp_path):
    bad = tmp_path / "bad.py"
    bad.write_text("def f():\n    from network.model import net\n    import stitching.merge\n")
    assert [(line, name) for line, name, _ in imports(bad)] == [(2, "network"), (3, "stitching")]
    wing = tmp_path / "wing.py"
    wing.write_text("from stitching import building\nimport waresynth.building.plan\n")
    assert [n for _, n in dotted_imports(wing) if n.startswith(WINGS)] == [
        "stitching.building",
        "waresynth.building.plan",
    ]


#: the one test that patches a command's ``run`` to see how the CLI reports an interrupt (the CLI's behaviour)
CLI_TESTS = ("tests/test_cli_light.py",)


@pytest.mark.parametrize("folder", ["mvracklay", "demos", "tests", "benchmarks", "scripts", "research"])
def test_only_the_cli_imports_a_command(folder):
    """A command parses, calls the library and prints: what others need lives in a library module."""
    bad = []
    for path in _files(folder):
        rel = path.relative_to(ROOT).as_posix()
        if rel.startswith("mvracklay/commands/") or rel in ("mvracklay/cli.py", *CLI_TESTS):
            continue
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), str(path))):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else []
            if isinstance(node, ast.ImportFrom) and node.module:
                names = [node.module] + [f"{node.module}.{a.name}" for a in node.names]
            if any(n == "mvracklay.commands" or n.startswith("mvracklay.commands.") for n in names):
                bad.append(f"{rel}:{node.lineno} imports a command module")
    assert not bad, "\n".join(bad)
