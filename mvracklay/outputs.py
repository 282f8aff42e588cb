"""What the commands write, and how: staged beside OUT and moved in only when complete (`staging_dir`,
`publish`) and the Rerun viewer opened on a written recording (`spawn_viewer`). Imports no torch: `mvracklay reconstruct` uses it too."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

from layouts.errors import InputError

#: what `mvracklay run` writes into OUT
OUTPUTS = ("layouts", "warehouse.json", "warehouse.glb", "warehouse.rrd")


def _is_map(path: Path) -> bool:
    """Whether ``path`` is a warehouse.json written by `mvracklay run` or `reconstruct`."""
    from stitching.warehouse_map import MAP_FORMAT

    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return False
    return isinstance(data, dict) and data.get("format") == MAP_FORMAT


def check_out(out: Path, overwrite: bool = False, untouched: tuple[str, ...] = ()) -> None:
    """Refuse an OUT that is neither missing, empty nor an earlier run's output folder (only `OUTPUTS` in it,
    its warehouse.json a map), unless ``overwrite``: then only the command's own outputs are replaced.
    ``untouched``: outputs the command leaves alone (reconstruct's layouts/), alone in OUT they count as empty."""
    if out.exists() and not out.is_dir():
        raise InputError(f"--out {out}: exists and is not a folder")
    if overwrite or not out.is_dir():
        return
    names = {p.name for p in out.iterdir()}
    if names <= set(untouched):
        return
    if names <= set(OUTPUTS) and _is_map(out / "warehouse.json"):
        return  # an earlier run's (or reconstruct's) output folder
    other = sorted(names - set(OUTPUTS))
    what = f"holds other files ({', '.join(other[:3])}{', ...' if len(other) > 3 else ''})" if other else "has no map"
    raise InputError(
        f"--out {out}: {what}, not an earlier run's output folder; give --overwrite to replace the outputs there "
        "(nothing else is touched) or another --out"
    )


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:
        return True  # e.g. another user's process
    return True


def staging_dir(out: Path) -> Path:
    """A fresh staging folder ``.OUT.partial-PID`` beside OUT; stale ones of processes no longer alive are removed."""
    out.parent.mkdir(parents=True, exist_ok=True)
    prefix = f".{out.name}.partial-"
    for old in out.parent.glob(f"{prefix}*"):
        pid = old.name[len(prefix) :]
        if pid.isdigit() and int(pid) != os.getpid() and not _alive(int(pid)) and old.is_dir():
            shutil.rmtree(old, ignore_errors=True)
    stage = out.parent / f"{prefix}{os.getpid()}"
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
