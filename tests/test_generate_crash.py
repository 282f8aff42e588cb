"""``kill -9`` during ``mvracklay generate``, then the same command again: the finished dataset is
byte-identical to an uninterrupted run and no temporary file or folder is left."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

from layouts.spec import LayoutSpec
from waresynth.generate import DatasetSettings, generate_dataset

ROOT = Path(__file__).resolve().parents[1]
ARGS = ["--sequences", "3", "--frames", "10", "--size", "96", "--layout-size", "16", "--seed", "11"]


def tree_bytes(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def _command(out: Path) -> list[str]:
    return [sys.executable, "-m", "mvracklay", "generate", str(out), *ARGS, "--workers", "1", "--no-progress"]


def _env() -> dict[str, str]:
    return {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}


def _mid_run(out: Path) -> bool:
    """One sequence complete and another one's frames being written."""
    done = any((out / f"seq_{k:05d}" / "meta.json").is_file() for k in range(3))
    writing = any(any((tmp / "rgb").glob("*.png")) for tmp in out.glob(".seq_*.tmp") if (tmp / "rgb").is_dir())
    return done and writing


def test_kill9_then_rerun_is_byte_identical(tmp_path):
    out = tmp_path / "crash"
    proc = subprocess.Popen(_command(out), cwd=ROOT, env=_env(), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    try:
        deadline = time.monotonic() + 120
        while not _mid_run(out):
            assert proc.poll() is None, f"generate ended before it could be killed: {proc.stderr.read().decode()}"
            assert time.monotonic() < deadline, "generate never reached the middle of a sequence"
            time.sleep(0.005)
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(30)
    assert proc.returncode == -signal.SIGKILL
    assert list(out.glob(".seq_*.tmp")), "the kill did not interrupt a sequence"
    assert not (out / "seq_00002" / "meta.json").exists()

    rerun = subprocess.run(_command(out), cwd=ROOT, env=_env(), capture_output=True, text=True, timeout=120)
    assert rerun.returncode == 0, rerun.stderr

    ref = generate_dataset(
        tmp_path / "ref",
        DatasetSettings(
            num_sequences=3, frames=10, image_size=(96, 96), spec=LayoutSpec(size=16), seed=11, progress=False
        ),
    )
    got = tree_bytes(out)
    assert got == tree_bytes(ref)
    assert len(got) == 1 + 3 * (4 * 10 + 10 + 3)
    leftovers = [str(p.relative_to(out)) for p in out.rglob("*") if p.name.startswith(".") or p.name.endswith(".tmp")]
    assert leftovers == []
