"""What `run` and `reconstruct` write, and where: which OUT they may write into (`check_out`, `check_apart`; the
rules and the publishing are `layouts.publish`) and the Rerun viewer opened on a written recording
(`spawn_viewer`). Imports no torch: `mvracklay reconstruct` and `map` use it too."""

from __future__ import annotations

import json
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

from layouts import publish
from layouts.errors import InputError
from layouts.publish import refuse_overlap

#: what `mvracklay run` writes into OUT
OUTPUTS = ("layouts", "warehouse.json", "warehouse.glb", "warehouse.rrd")


def _format_of(path: Path) -> object:
    """The ``format`` a JSON file declares (None: no such file, not JSON, or none declared)."""
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError, RecursionError):
        return None
    return data.get("format") if isinstance(data, dict) else None


def is_run_output(folder: Path) -> bool:
    """Whether ``folder`` holds a warehouse.json written by `mvracklay run` or `reconstruct`."""
    from stitching.warehouse_map import MAP_FORMAT

    return _format_of(folder / "warehouse.json") == MAP_FORMAT


def check_out(
    out: Path,
    overwrite: bool = False,
    untouched: tuple[str, ...] = (),
    outputs: tuple[str, ...] = OUTPUTS,
    earlier: Callable[[Path], bool] | None = None,
    command: str = "run",
) -> None:
    """`layouts.publish.check_out` with `run`'s outputs (`OUTPUTS`, its warehouse.json a map) by default."""
    publish.check_out(out, overwrite, outputs, earlier or is_run_output, command, untouched)


def check_apart(out: Path, names: tuple[str, ...], inputs: dict[str, object]) -> None:
    """Refuse an OUT whose outputs ``names`` would be, lie inside or hold one of ``inputs`` (what the user
    calls each -> its path or None): an output never replaces an input (`layouts.publish.refuse_overlap`)."""
    given = {k: v for k, v in inputs.items() if isinstance(v, (str, Path)) and Path(v).exists()}
    refuse_overlap([out / n for n in names], given)


def spawn_viewer(rrd: Path) -> None:
    """Open the Rerun viewer on a written recording (detached; the run does not wait for it)."""
    exe = Path(sys.executable).with_name("rerun")
    cmd = [str(exe), str(rrd)] if exe.is_file() else [sys.executable, "-m", "rerun", str(rrd)]
    try:
        subprocess.Popen(cmd, start_new_session=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    except OSError as e:
        raise InputError(f"cannot start the Rerun viewer ({e}); open the recording with: rerun {rrd}") from None


def run_summary(res, source) -> str:
    """What `run` prints at its end (a `mvracklay.pipeline.RunResult` of ``source``): frames, map, speed,
    distance, angles, free space, the files written."""
    from network.inference.roll import describe_angles
    from stitching.free_space import format_table

    wmap = res.map
    lines = [
        f"{res.frames} frames ({source.kind}, {source.width}x{source.height}, camera: {res.intrinsics_source}) -> "
        f"{len(wmap.racks)} racks, {len(wmap.shelves())} shelves, {len(wmap.boxes())} boxes"
    ]
    t = res.seconds
    rate = ", ".join(f"{k} {res.frames / t[k]:.1f} frames/s" for k in ("predict", "stitch", "rerun") if t.get(k, 0) > 0)
    lines.append(f"speed: {rate} (wall, this machine)")
    if res.distance is not None:
        lines.append(f"distance to the racks: {res.distance.describe()}")
    lines += describe_angles(res.angles_read)
    lines.append(format_table(res.free_space, racks=len(wmap.racks)))
    lines.append("wrote " + ", ".join(str(p) for p in res.paths.values()))
    return "\n".join(lines)
