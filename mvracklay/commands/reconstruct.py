"""``mvracklay reconstruct``: stitch a sequence's layouts into a 3D warehouse map (.json, .glb, .rrd)."""

from __future__ import annotations

import argparse
import shutil
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING

from layouts.codecs import LayoutFolder, read_layout_spec
from layouts.errors import InputError
from mvracklay.options import add_quiet_option, add_spawn_option

if TYPE_CHECKING:
    from stitching.pipeline import StitchConfig

NAME = "reconstruct"
HELP = "stitch per-frame layouts of a sequence into a 3D map: warehouse.json, .glb and .rrd"
DESCRIPTION = (
    "Detect boxes and shelves in every frame's top/front layouts, lift them to 3D cuboids, estimate "
    "the camera shift between frames and merge everything into one map. SEQ_DIR is a WareSynth "
    "sequence folder (its ground-truth layouts, RGB and camera records are used when present) or a "
    "layout folder (spec.json + NNNNNN.npz, e.g. written by `mvracklay predict`). Writes "
    "OUT/warehouse.json, OUT/warehouse.glb and OUT/warehouse.rrd."
)
GROUP = "use"
ORDER = 11
#: what the CLI says when interrupted (Ctrl-C, SIGTERM): nothing to resume
INTERRUPTED = "OUT left as it was"
#: what reconstruct writes (an OUT/layouts folder, e.g. from `run`, is never touched)
MAP_OUTPUTS = ("warehouse.json", "warehouse.glb", "warehouse.rrd")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("seq_dir", metavar="SEQ_DIR", help="WareSynth sequence folder or a layout folder")
    p.add_argument(
        "--layouts",
        default="gt",
        help="'gt' for SEQ_DIR/layouts (or SEQ_DIR itself when it is a layout folder), or a layout folder",
    )
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument(
        "--overwrite",
        action="store_true",
        help="write into an OUT holding other files (only the map files there are replaced); without it OUT "
        "must be missing, empty or an earlier run's output folder",
    )
    p.add_argument(
        "--board-thickness", type=float, default=0.06, help="metres between a clear height and the next board top"
    )
    p.add_argument(
        "--noisy",
        action="store_true",
        help="clean-up for network output (StitchConfig.noisy: box-mask openings, small boxes and rarely seen boxes dropped)",
    )
    p.add_argument("--no-rrd", action="store_true", help="do not write warehouse.rrd")
    add_spawn_option(p)
    p.add_argument("--no-rgb", action="store_true", help="do not log RGB frames to Rerun")
    p.add_argument("--map-every", type=int, default=1, help="log the growing map to Rerun every N frames")
    p.add_argument(
        "--keep-steps",
        type=int,
        default=0,
        help="keep the per-frame camera steps of only the last N frames in the map (0 = all); bounds memory on endless streams",
    )
    add_quiet_option(p, "no progress bar")


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


def origin_of(seq, first_index: int) -> tuple[float, float, float] | None:
    """World position of the map origin from the first frame's record (None without records)."""
    if seq is None:
        return None
    from stitching.warehouse_map import origin_from_record

    return origin_from_record(seq.frame(first_index))


def stitch_config(args: argparse.Namespace) -> StitchConfig:
    """The stitching settings ``--board-thickness``, ``--keep-steps`` and ``--noisy`` ask for."""
    from stitching.lift import LiftConfig
    from stitching.merge import MergeConfig
    from stitching.pipeline import StitchConfig

    if not (args.board_thickness >= 0 and args.board_thickness < 1):
        raise InputError(f"--board-thickness must be in [0, 1) metres, got {args.board_thickness}")
    keep = getattr(args, "keep_steps", 0)
    if keep < 0:
        raise InputError(f"--keep-steps must be >= 0, got {keep}")
    if getattr(args, "noisy", False):
        return StitchConfig.noisy(board_thickness=args.board_thickness, keep_steps=keep or None)
    return StitchConfig(
        lift=LiftConfig(board_thickness=args.board_thickness), merge=MergeConfig(keep_steps=keep or None)
    )


def run(args: argparse.Namespace) -> int:
    from mvracklay.outputs import check_out, publish, spawn_viewer, staging_dir

    seq_dir = Path(args.seq_dir)
    if not seq_dir.is_dir():
        raise InputError(f"{seq_dir}: folder not found")
    if args.map_every < 1:
        raise InputError(f"--map-every must be >= 1, got {args.map_every}")
    if args.spawn and args.no_rrd:
        raise InputError("--spawn opens OUT/warehouse.rrd; it cannot be combined with --no-rrd")
    folder = resolve_layouts(seq_dir, args.layouts)
    indices = folder.indices()
    if not indices:
        raise InputError(f"{folder.root}: no per-frame layout files (NNNNNN.npz)")
    seq = open_sequence(seq_dir)
    if seq is not None and seq.num_frames < indices[-1] + 1:
        raise InputError(f"{folder.root}: frame {indices[-1]} has no record in {seq_dir / 'meta.json'}")
    if seq is not None and args.layouts == "gt" and len(indices) != seq.num_frames:
        gap = sorted(set(range(seq.num_frames)) - set(indices))[0]
        raise InputError(
            f"{folder.path(gap)}: missing, but {seq_dir / 'meta.json'} records {seq.num_frames} frames "
            f"({seq.num_frames - len(indices)} layout files missing)"
        )
    final_out = Path(args.out)
    check_out(final_out, args.overwrite, untouched=("layouts",))
    out = staging_dir(final_out)  # outputs appear in OUT only when the whole run succeeded
    try:
        _reconstruct(args, seq, folder, indices, out)
    except BaseException:
        shutil.rmtree(out, ignore_errors=True)
        raise
    publish(out, final_out, managed=MAP_OUTPUTS)
    print(
        f"wrote {final_out / 'warehouse.json'}, {final_out / 'warehouse.glb'}"
        + ("" if args.no_rrd else f", {final_out / 'warehouse.rrd'}")
    )
    if args.spawn:
        spawn_viewer(final_out / "warehouse.rrd")
    return 0


def _reconstruct(args: argparse.Namespace, seq, folder: LayoutFolder, indices: list[int], out: Path) -> None:
    from tqdm import tqdm

    from stitching import rerun_log
    from stitching.export_gltf import export_glb
    from stitching.pipeline import Stitcher

    origin = origin_of(seq, indices[0])
    stitcher = Stitcher(folder.spec, stitch_config(args))
    rec = None
    if not args.no_rrd:
        rec = rerun_log.start("mvracklay-reconstruct", save=out / "warehouse.rrd", num_slots=folder.spec.num_slots)
    cam_y = cam_z = None
    if seq is not None and origin is not None:
        p0 = seq.frame(indices[0])["camera_position"]
        cam_y, cam_z = float(p0[1]) - origin[1], float(p0[2]) - origin[2]
    path = []
    t_stitch = 0.0
    for i in tqdm(indices, desc="reconstruct", unit="frame", disable=args.quiet, file=sys.stderr):
        fl = folder.read(i)
        t0 = time.perf_counter()
        frame_rec, step = stitcher.push(fl, i)
        t_stitch += time.perf_counter() - t0
        if rec is not None:
            path.append(rerun_log.camera_point(step.offset, cam_y, cam_z))
            rgb = None
            if seq is not None and not args.no_rgb and seq.rgb_path(i).is_file():
                rgb = seq.rgb(i)
            rerun_log.log_frame(rec, i, fl, frame_rec, step.offset, rgb, path)
            if (len(path) - 1) % args.map_every == 0 or i == indices[-1]:
                rerun_log.log_map(rec, stitcher.map(), i, folder.spec.num_slots)
    meta = {"layouts": str(folder.root), "frames": len(indices), "spec": folder.spec.to_dict()}
    wmap = stitcher.map(origin, meta)
    wmap.save(out / "warehouse.json")
    export_glb(wmap, out / "warehouse.glb")
    if rec is not None:
        rec.flush()
        rec.disconnect()
    n_boxes = len(wmap.boxes())
    fps = len(indices) / t_stitch if t_stitch > 0 else float("inf")
    print(
        f"{len(indices)} frames -> {len(wmap.racks)} racks, {len(wmap.shelves())} shelves, {n_boxes} boxes "
        f"(stitching {fps:.0f} frames/s)"
    )
