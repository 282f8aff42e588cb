"""benchmarks/ holds benchmarks only, each of which still starts (``--help`` against the current code), and
research/ stays outside the product: no package, recipe or test imports or runs its scripts."""

from __future__ import annotations

import ast
import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
BENCHES = sorted((ROOT / "benchmarks").glob("*.py"))
PACKAGES = ("layouts", "waresynth", "network", "stitching", "mvracklay")
#: every bench's --help in one interpreter (the heavy imports paid once); prints the scripts that failed
HELP_ALL = r"""
import runpy, sys
bad = []
for path in sys.argv[1:]:
    sys.argv = [path, "--help"]
    try:
        runpy.run_path(path, run_name="__main__")
        bad.append(path + ": no exit")
    except SystemExit as e:
        if e.code not in (0, None):
            bad.append(f"{path}: exit {e.code}")
    except Exception as e:
        bad.append(f"{path}: {type(e).__name__}: {e}")
print("BAD", bad)
"""


def test_benchmarks_are_bench_scripts_only():
    assert BENCHES and all(p.name.startswith("bench_") for p in BENCHES), [p.name for p in BENCHES]


def test_every_benchmark_starts():
    done = subprocess.run([sys.executable, "-c", HELP_ALL, *map(str, BENCHES)], cwd=ROOT, capture_output=True,
                          text=True, timeout=300)  # fmt: skip
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.strip().splitlines()[-1] == "BAD []", done.stdout[-2000:]


def _imports(path: Path) -> set[str]:
    names = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            names |= {a.name.split(".")[0] for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module and not node.level:
            names.add(node.module.split(".")[0])
    return names


def test_nothing_of_the_product_uses_research():
    research = {p.stem for p in (ROOT / "research").glob("*.py")} | {"research"}
    code = [p for pkg in PACKAGES for p in (ROOT / pkg).rglob("*.py")] + sorted((ROOT / "tests").glob("*.py"))
    code += BENCHES
    assert not {str(p.relative_to(ROOT)): _imports(p) & research for p in code if _imports(p) & research}
    # nor runs one: a test or recipe naming a research script's path outside a comment
    runs = re.compile(r"""["']research["']|research/\w+\.py""")
    recipes = [p for p in (ROOT / "mvracklay" / "recipes").rglob("*") if p.is_file()]
    checkers = (Path(__file__).name, "test_arrows.py")  # the tests that name research/ to keep it apart
    tests = [p for p in (ROOT / "tests").glob("*.py") if p.name not in checkers]
    uncommented = {
        p: "\n".join(x for x in p.read_text().splitlines() if not x.lstrip().startswith("#")) for p in tests + recipes
    }
    assert not [str(p.relative_to(ROOT)) for p, text in uncommented.items() if runs.search(text)]
