"""The package installs like one: a wheel built from the repository holds the code, the shipped inference
models and every data file beside the code (configs, recipes), and nothing of the repository around it
(tests, benchmarks, research, training intermediates); installed away from the checkout, the default
model resolves and loads without it.

The wheel is built from a copy of the tree (an in-tree build would leave build/ in the checkout, and a
stale build/ would leak deleted modules into later wheels), with this venv's setuptools
(``--no-build-isolation``: no download), and installed with ``--target`` into a folder that a fresh
interpreter puts first on its path, the checkout and its editable install taken off it."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("layouts", "waresynth", "network", "stitching", "mvracklay")
#: what the copy leaves out: not part of the source, or large and never packaged
SKIP = (".git", ".venv", "node_modules", "build", "dist", "*.egg-info", "__pycache__", "data", "runs", "out", "logs")

#: run in the installed copy, cwd outside the checkout: where everything comes from, and the model loads
PROBE = r"""
import json, os, sys
site, root = sys.argv[1], os.path.realpath(sys.argv[2])
venv = os.path.realpath(sys.prefix)  # this venv's packages (torch, ...) may lie inside the checkout


def in_checkout(path):
    path = os.path.realpath(path)
    return (path == root or path.startswith(root + os.sep)) and not path.startswith(venv + os.sep)


sys.meta_path[:] = [f for f in sys.meta_path if "editable" not in repr(f).lower()]
sys.path[:] = [site] + [p for p in sys.path if p and not in_checkout(p)]
from mvracklay import models, pipeline
from network.checkpoint import load_model
from waresynth.config import load_config
ckpt = models.resolve_checkpoint(None)
model, record = load_model(ckpt)
big = models.resolve_checkpoint("mvracklay-disc-4-256")
load_config(None)
mods = [m for name, m in sys.modules.items() if name.split(".")[0] in {PACKAGES}]
print(json.dumps({
    "default": str(ckpt), "pipeline_default": str(pipeline.DEFAULT_CHECKPOINT), "big": str(big),
    "from_checkout": sorted(m.__name__ for m in mods if in_checkout(m.__file__ or root)),
    "modules": len(mods), "params": sum(p.numel() for p in model.parameters()),
}))
""".replace("{PACKAGES}", repr(set(PACKAGES)))


def _pip(*args: str, cwd: Path) -> None:
    done = subprocess.run([sys.executable, "-m", "pip", *args, "-q", "--disable-pip-version-check"], cwd=cwd,
                          capture_output=True, text=True, timeout=300)  # fmt: skip
    assert done.returncode == 0, done.stderr[-3000:]


@pytest.fixture(scope="module")
def wheel(tmp_path_factory: pytest.TempPathFactory) -> Path:
    tmp = tmp_path_factory.mktemp("wheel")
    src = tmp / "src"
    shutil.copytree(ROOT, src, ignore=shutil.ignore_patterns(*SKIP), symlinks=True)
    _pip("wheel", str(src), "--no-deps", "--no-build-isolation", "-w", str(tmp / "dist"), cwd=tmp)
    (whl,) = (tmp / "dist").glob("mvracklay-*.whl")
    return whl, src


def test_the_wheel_holds_the_code_the_models_and_the_data_files_and_nothing_else(wheel: tuple[Path, Path]):
    wheel, src = wheel
    names = set(zipfile.ZipFile(wheel).namelist())
    for name in ("mvracklay-disc-4", "mvracklay-disc-4-256"):
        assert {f"mvracklay/models/{name}.pt", f"mvracklay/models/{name}.json"} <= names, name
    assert "mvracklay/models/README.md" in names and "waresynth/default_config.json" in names
    assert "mvracklay/models/distance-reader.pt" in names and "waresynth/configs/shifted_look.json" in names
    # every file of the packages' source is in it: modules, configs, recipes (a package-data line forgotten shows)
    beside_code = {
        p.relative_to(src).as_posix()
        for pkg in PACKAGES
        for p in (src / pkg).rglob("*")
        if p.is_file() and "__pycache__" not in p.parts
    }
    assert beside_code - names == set()
    assert any(n.startswith("mvracklay/recipes/") for n in names) == (src / "mvracklay" / "recipes").is_dir()
    top = {n.split("/")[0] for n in names if not n.startswith("mvracklay-")}  # the dist-info folder aside
    assert top == set(PACKAGES), top
    assert not [n for n in names if "racklay256-stage1" in n or "/tests/" in n or n.startswith("tests/")]
    entry = next(n for n in names if n.endswith(".dist-info/entry_points.txt"))
    assert "mvracklay = mvracklay.cli:main" in zipfile.ZipFile(wheel).read(entry).decode()


def test_an_installed_copy_finds_and_loads_the_default_model_without_the_checkout(wheel: tuple[Path, Path], tmp_path):
    site = tmp_path / "site"
    _pip("install", "--no-deps", "--no-compile", "--target", str(site), str(wheel[0]), cwd=tmp_path)
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    done = subprocess.run([sys.executable, "-c", PROBE, str(site.resolve()), str(ROOT)], cwd=tmp_path, env=env,
                          capture_output=True, text=True, timeout=300)  # fmt: skip
    assert done.returncode == 0, done.stderr[-3000:]
    got = json.loads(done.stdout.strip().splitlines()[-1])
    shipped = site.resolve() / "mvracklay" / "models"
    assert got["default"] == got["pipeline_default"] == str(shipped / "mvracklay-disc-4.pt")
    assert got["big"] == str(shipped / "mvracklay-disc-4-256.pt")
    assert got["from_checkout"] == [] and got["modules"] > 10 and got["params"] > 0
