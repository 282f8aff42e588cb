"""Shared fixtures: a tiny WareSynth dataset, the fixed tiny network (tests/data), a tiny building and its map, made or copied once per run and shared by the workers; a local Ray per test file that asks."""

from __future__ import annotations

import os
import secrets
import shutil
import sys
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

# The suite runs on both cores at once (pytest-xdist): OpenMP threads that sleep when idle instead of spinning
# keep two workers' torch threads from starving each other (set before torch loads; subprocesses inherit it).
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
# Models load in torch's graphs here: exporting each part to ONNX Runtime costs ~1 s a model, which every command
# run by the tests would pay; tests/test_ortgraph.py holds the ONNX Runtime path (the commands' default) to them.
os.environ.setdefault("MVRACKLAY_RUNTIME", "torch")
os.environ.setdefault("MVRACKLAY_ONNX_CACHE", "off")  # nothing written to the user's cache (tests/test_ortgraph.py)

import pytest

# Import the working tree's packages even where an older editable install maps them elsewhere.
_ROOT = str(Path(__file__).resolve().parents[1])
if _ROOT not in sys.path:
    sys.path.insert(0, _ROOT)

from hypothesis import settings  # noqa: E402

# Property tests assert behaviour, not speed: a loaded CI machine must not fail them on timing.
settings.register_profile("project", deadline=None)
settings.load_profile("project")


@pytest.fixture(scope="session")
def tiny_dataset(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """3 sequences x 8 frames, 128x128 images, layouts D=64, seed 7 (`tiny_net.TINY_DATASET`; a few seconds), made
    once per run (the workers share it: read only)."""
    from tiny_net import tiny_dataset

    with _shared(tmp_path_factory, "tiny_dataset") as (root, made):
        if not made:
            tiny_dataset(root / "tiny")
    return root / "tiny"


@pytest.fixture(scope="session")
def tiny_checkpoint(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The fixed tiny network (`tiny_net.TINY_CHECKPOINT`: 40 steps of `mvracklay train` on the tiny dataset, fp16
    weights): it finds shelf boards and predicts shelves and boxes, so the stages after the network get real
    content. Data, not trained here: the same weights on every CPU. A copy per run, shared by the workers (a command
    that writes beside its checkpoint cannot touch the file in the tests)."""
    from tiny_net import TINY_CHECKPOINT

    with _shared(tmp_path_factory, "tiny_net") as (root, made):
        if not made:
            for src in (TINY_CHECKPOINT, TINY_CHECKPOINT.with_suffix(".json")):
                shutil.copyfile(src, root / src.name)
    return root / TINY_CHECKPOINT.name


@contextmanager
def _shared(factory: pytest.TempPathFactory, name: str) -> Iterator[tuple[Path, bool]]:
    """A folder ``name`` every parallel worker of this run shares (a worker's own without xdist), locked for the
    block: yields it and whether a worker made its content already (the block makes it; a failed block leaves
    it to be made again)."""
    base = factory.getbasetemp().parent if os.environ.get("PYTEST_XDIST_WORKER") else factory.getbasetemp()
    root = base / name
    with _locked(base / f"{name}.lock"):
        done = root / ".made"
        if not done.is_file():
            shutil.rmtree(root, ignore_errors=True)
            root.mkdir(parents=True)
        yield root, done.is_file()
        done.touch()


@contextmanager
def _locked(path: Path) -> Iterator[None]:
    """An exclusive lock on ``path`` between processes (the parallel workers), held for the block."""
    import fcntl  # POSIX: the suite runs on Linux

    with open(path, "a") as f:
        fcntl.flock(f, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(f, fcntl.LOCK_UN)


@pytest.fixture(scope="module")
def ray_local() -> Iterator[str]:
    """A local Ray of 2 CPUs, started once for the test file that asks for it (about 5 s; its tests run on one
    worker) and stopped after it; yields the ``ray`` address to give `mvracklay.parallel.run_tasks` / ``--ray`` (this process stays
    connected, so any address reaches it). Token authentication stays on, its token kept in the environment
    (nothing written to ~/.ray), its sessions' files in a temporary folder removed after it; the workers import
    this checkout and the test modules (a task's function may be a test module's). Skipped where Ray is not
    installed."""
    pytest.importorskip("ray")
    from mvracklay.parallel import connect, shutdown

    # a short folder of its own: Ray's socket paths under it must stay within the 107 characters of a Unix socket
    temp = tempfile.mkdtemp(prefix="ray-")
    with pytest.MonkeyPatch.context() as env:
        env.setenv("RAY_TMPDIR", temp)
        env.delenv("RAY_AUTH_MODE", raising=False)  # Ray's default for a local cluster: token authentication
        env.setenv("RAY_AUTH_TOKEN", secrets.token_hex(32))
        env.setenv("RAY_USAGE_STATS_ENABLED", "0")
        paths = (_ROOT, str(Path(__file__).parent), os.environ.get("PYTHONPATH"))
        env.setenv("PYTHONPATH", os.pathsep.join(p for p in paths if p))
        shutdown()
        connect("local", num_cpus=2)
        try:
            yield "local"
        finally:
            shutdown()
            shutil.rmtree(temp, ignore_errors=True)


#: a tiny building (2 aisles of 3-4 bays; 32x24 images, 128 px layouts: the maps read only the layouts)
TINY_BUILDING = {
    "aisles": 2, "bays": [3, 4], "bay_width": [1.6, 2.0], "levels": [2, 3], "pass_length": 4.5,
    "overlap": [1.5, 2.0], "twice_share": 0.5,
}  # fmt: skip
TINY_CONFIG = {"camera": {"step": [0.25, 0.3]}}


@pytest.fixture(scope="session")
def tiny_building(tmp_path_factory) -> Path:
    """A generated tiny building (`TINY_BUILDING`, seed 3), made once per run (the workers share it: read only)."""
    from layouts.spec import LayoutSpec
    from waresynth.building.generate import generate_building

    with _shared(tmp_path_factory, "tiny_building") as (root, made):
        if not made:
            generate_building(root / "b", building=TINY_BUILDING, config=TINY_CONFIG, image_size=(32, 24),
                              spec=LayoutSpec(size=128), seed=3, progress=False)  # fmt: skip
    return root / "b"


@pytest.fixture(scope="session")
def tiny_building_map(tiny_building, tmp_path_factory) -> Path:
    """`tiny_building` mapped from its ground-truth layouts (`mvracklay map --layouts gt`): the MAP folder (once per
    run, shared, read only)."""
    from mvracklay.building_job import MapSettings, map_building
    from mvracklay.settings import OutputSettings

    with _shared(tmp_path_factory, "tiny_building_map") as (root, made):
        if not made:
            map_building(tiny_building, root / "m", MapSettings(layouts="gt"), outputs=OutputSettings(quiet=True))
    return root / "m"
