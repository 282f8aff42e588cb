"""What the commands write, and how: staged beside OUT and moved in only when complete (`staging_dir`,
`publish`) and the Rerun viewer opened on a written recording (`spawn_viewer`). Imports no torch: `mvracklay reconstruct` uses it too."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

from layouts.errors import InputError

#: what `mvracklay run` writes into OUT
OUTPUTS = ("layouts", "warehouse.json", "warehouse.glb", "warehouse.rrd")


def staging_dir(out: Path) -> Path:
    out.parent.mkdir(parents=True, exist_ok=True)
    stage = out.parent / f".{out.name}.partial-{os.getpid()}"
    if stage.exists():
        shutil.rmtree(stage)
    stage.mkdir()
    return stage


def publish(stage: Path, out: Path, managed: tuple[str, ...] = OUTPUTS) -> None:
    """Move the staged outputs into OUT, replacing those of an earlier run.

    Of the ``managed`` names, an earlier run's output this run did not write is removed (it would
    be stale); nothing else in OUT is touched.
    """
    if out.exists() and not out.is_dir():
        raise InputError(f"--out {out}: exists and is not a folder")
    out.mkdir(parents=True, exist_ok=True)
    made = {p.name for p in stage.iterdir()}
    for name in managed:
        old = out / name
        if name not in made and old.is_dir() and not old.is_symlink():
            shutil.rmtree(old)
        elif name not in made and (old.exists() or old.is_symlink()):
            old.unlink()
    for item in sorted(stage.iterdir()):
        dst = out / item.name
        if dst.is_dir() and not dst.is_symlink():
            shutil.rmtree(dst)
        elif dst.exists() or dst.is_symlink():
            dst.unlink()
        os.replace(item, dst)
    stage.rmdir()


def spawn_viewer(rrd: Path) -> None:
    """Open the Rerun viewer on a written recording (detached; the run does not wait for it)."""
    exe = Path(sys.executable).with_name("rerun")
    cmd = [str(exe), str(rrd)] if exe.is_file() else [sys.executable, "-m", "rerun", str(rrd)]
    try:
        subprocess.Popen(cmd, start_new_session=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    except OSError as e:
        raise InputError(f"cannot start the Rerun viewer ({e}); open the recording with: rerun {rrd}") from None
