"""Shared fixtures: a tiny WareSynth dataset generated once per test session."""

from __future__ import annotations

import os
import sys
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

from layouts.spec import LayoutSpec  # noqa: E402

# Property tests assert behaviour, not speed: a loaded CI machine must not fail them on timing.
settings.register_profile("project", deadline=None)
settings.load_profile("project")


@pytest.fixture(scope="session")
def tiny_dataset(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """3 sequences x 8 frames, 128x128 images, layouts D=64, seed 7 (a few seconds)."""
    from waresynth.generate import generate_dataset

    out = tmp_path_factory.mktemp("waresynth") / "tiny"
    return generate_dataset(
        out, num_sequences=3, frames=8, image_size=(128, 128), spec=LayoutSpec(size=64), seed=7, progress=False
    )


@pytest.fixture(scope="session")
def tiny_checkpoint(tiny_dataset: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A tiny network trained 40 steps on the tiny dataset with `mvracklay train` (seconds): it finds
    shelf boards and predicts shelves and boxes, so the stages after the network get real content."""
    from tiny_net import TINY_NET

    from mvracklay.cli import main

    out = tmp_path_factory.mktemp("tiny_net") / "run"
    args = ["train", "--data", str(tiny_dataset), "--out", str(out), "--epochs", "1", "--steps-per-epoch", "40"]
    assert main([*args, "--frames-per-step", "4", "--lr", "3e-3", *TINY_NET]) == 0
    return out / "last.pt"
