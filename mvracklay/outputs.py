"""What the commands write, and how: staged beside OUT and moved in only when complete (`staging_dir`,
`publish`), the map as ``.glb`` (`write_glb`) and the Rerun viewer opened on a written recording
(`spawn_viewer`). Imports no torch: `mvracklay reconstruct` uses it too."""

from __future__ import annotations

import json
import os
import shutil
import struct
import subprocess
import sys
from pathlib import Path

from layouts.errors import InputError
from layouts.fileio import atomic_write_bytes
from stitching.export_gltf import export_glb, map_cuboids
from stitching.warehouse_map import WarehouseMap

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


def empty_glb_bytes() -> bytes:
    """A valid binary glTF holding one empty scene (trimesh refuses to export a scene without meshes)."""
    doc = {
        "asset": {"version": "2.0", "generator": "mvracklay (empty map)"},
        "scene": 0,
        "scenes": [{"name": "warehouse"}],
    }
    body = json.dumps(doc, separators=(",", ":"), sort_keys=True).encode()
    body += b" " * (-len(body) % 4)
    return b"glTF" + struct.pack("<II", 2, 12 + 8 + len(body)) + struct.pack("<I", len(body)) + b"JSON" + body


def write_glb(wmap: WarehouseMap, path: Path) -> None:
    """`stitching.export_gltf.export_glb`, or an empty scene when the map holds no shelf or box."""
    if map_cuboids(wmap):
        export_glb(wmap, path)
    else:
        atomic_write_bytes(path, empty_glb_bytes())


def spawn_viewer(rrd: Path) -> None:
    """Open the Rerun viewer on a written recording (detached; the run does not wait for it)."""
    exe = Path(sys.executable).with_name("rerun")
    cmd = [str(exe), str(rrd)] if exe.is_file() else [sys.executable, "-m", "rerun", str(rrd)]
    try:
        subprocess.Popen(cmd, start_new_session=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    except OSError as e:
        raise InputError(f"cannot start the Rerun viewer ({e}); open the recording with: rerun {rrd}") from None
