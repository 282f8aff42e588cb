"""Layouts -> map, as `mvracklay reconstruct` and `eval-reconstruction` do it: the layout folder a path names
(`resolve_layouts`), the generated sequence beside it (`open_sequence`) and the map's place from its first record, the
stitching settings (`stitch_settings`) and the stitched map written with its recording (`reconstruct_folder`).
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from layouts.codecs import LayoutFolder, read_layout_spec
from layouts.errors import InputError

if TYPE_CHECKING:
    from stitching.pipeline import StitchConfig
    from stitching.warehouse_map import WarehouseMap


def open_sequence(seq_dir: Path):
    """A WareSynth `Sequence` when ``seq_dir`` holds meta.json, else None."""
    if not (seq_dir / "meta.json").is_file():
        return None
    from waresynth.dataset import Sequence

    return Sequence(seq_dir, seq_dir.name, "unknown", read_layout_spec(seq_dir / "layouts"))


def resolve_layouts(seq_dir: Path, layouts: str) -> LayoutFolder:
    """The layout folder named by ``--layouts`` (one-line error when missing)."""
    if layouts == "gt":
        if (seq_dir / "layouts" / "spec.json").is_file():
            return LayoutFolder(seq_dir / "layouts")
        if (seq_dir / "spec.json").is_file():
            return LayoutFolder(seq_dir)
        raise InputError(
            f"{seq_dir}: no layouts/spec.json (not a WareSynth sequence) and no spec.json (not a layout folder)"
        )
    folder = Path(layouts)
    if not (folder / "spec.json").is_file():
        raise InputError(f"--layouts {layouts}: not a layout folder (no spec.json)")
    return LayoutFolder(folder)


def gt_upright_columns(seq_dir: Path, size: int, x_extent: float) -> dict[int, np.ndarray]:
    """Per frame of a generated sequence, the layout columns (``size`` over ``x_extent`` metres about the camera)
    that hold an end of one of its racks (scene.json), where the front uprights stand: the ground truth the
    upright head is fitted to, for ``--layouts gt``. {} where the sequence lacks scene.json or meta.json."""
    from layouts.fileio import load_json

    if not ((seq_dir / "scene.json").is_file() and (seq_dir / "meta.json").is_file()):
        return {}
    scene, meta = load_json(seq_dir / "scene.json"), load_json(seq_dir / "meta.json")
    try:
        ends = sorted({float(v) for r in scene["racks"] for v in (r["x_min"], r["x_max"])})
        cams = {int(f["index"]): float(f["camera_position"][0]) for f in meta["frames"]}
    except (KeyError, TypeError, ValueError, IndexError) as e:
        raise InputError(f"{seq_dir}: scene.json / meta.json lack the racks' ends or the cameras ({e})") from None
    out = {}
    for i, cx in cams.items():
        cols = np.zeros(size, bool)
        for x in ends:
            c = int(np.floor((x - cx + x_extent / 2) * size / x_extent))
            cols[max(c - 1, 0) : max(min(c + 2, size), 0)] = True
        out[i] = cols
    return out


def stitch_settings(board_thickness: float = 0.06, noisy: bool = False, keep_steps: int = 0) -> StitchConfig:
    """The stitching settings: ``board_thickness`` metres between a clear height and the next board top,
    ``noisy`` the clean-up for network output (`StitchConfig.noisy`), ``keep_steps`` the last N camera steps
    kept (0 = all)."""
    from stitching.lift import LiftConfig
    from stitching.merge import MergeConfig
    from stitching.pipeline import StitchConfig

    if not (board_thickness >= 0 and board_thickness < 1):
        raise InputError(f"--board-thickness must be in [0, 1) metres, got {board_thickness}")
    if keep_steps < 0:
        raise InputError(f"--keep-steps must be >= 0, got {keep_steps}")
    if noisy:
        return StitchConfig.noisy(board_thickness=board_thickness, keep_steps=keep_steps or None)
    return StitchConfig(
        lift=LiftConfig(board_thickness=board_thickness), merge=MergeConfig(keep_steps=keep_steps or None)
    )


def reconstruct_folder(
    folder: LayoutFolder,
    indices: list[int],
    out: Path,
    seq=None,
    config: StitchConfig | None = None,
    rrd: bool = True,
    log_rgb: bool = True,
    map_every: int = 1,
    progress: bool = True,
) -> tuple[WarehouseMap, float]:
    """Stitch the layouts ``folder`` holds at ``indices`` into a map and write out/warehouse.json, .glb and (``rrd``)
    .rrd; ``seq``: the generated sequence they belong to (its first record places the map, its RGB the
    recording's frames when ``log_rgb``), or None. Returns the map and the seconds spent stitching."""
    from tqdm import tqdm

    from stitching import rerun_log
    from stitching.export_gltf import export_glb
    from stitching.pipeline import stitch_folder
    from stitching.warehouse_map import camera_in_map

    origin, cam_y, cam_z = camera_in_map(seq.frame(indices[0])) if seq is not None else (None, None, None)
    rec = None
    if rrd:
        rec = rerun_log.start("mvracklay-reconstruct", save=out / "warehouse.rrd", num_slots=folder.spec.num_slots)
    path = []

    def log(i, fl, frame_rec, step, stitcher) -> None:
        path.append(rerun_log.camera_point(step.offset, cam_y, cam_z))
        frame_rgb = None
        if seq is not None and log_rgb and seq.rgb_path(i).is_file():
            frame_rgb = seq.rgb(i)
        rerun_log.log_frame(rec, i, fl, frame_rec, step.offset, frame_rgb, path)
        if (len(path) - 1) % map_every == 0 or i == indices[-1]:
            rerun_log.log_map(rec, stitcher.map(), i, folder.spec.num_slots)

    meta = {"layouts": str(folder.root), "frames": len(indices), "spec": folder.spec.to_dict()}
    steps = tqdm(indices, desc="reconstruct", unit="frame", disable=not progress, file=sys.stderr)
    done = stitch_folder(
        folder, steps, config, on_frame=log if rec is not None else None, origin_world=origin, meta=meta
    )
    done.map.save(out / "warehouse.json")
    export_glb(done.map, out / "warehouse.glb")
    if rec is not None:
        rec.flush()
        rec.disconnect()
    return done.map, done.seconds
