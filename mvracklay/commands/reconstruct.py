"""``mvracklay reconstruct``: stitch a sequence's layouts into a 3D warehouse map (.json, .glb, .rrd)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from layouts.errors import InputError
from mvracklay.reconstruction import open_sequence, reconstruct_folder, resolve_layouts, stitch_settings
from mvracklay.settings import add_options
from mvracklay.use_settings import ReconstructSettings

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
    add_options(p, ReconstructSettings)


def run(args: argparse.Namespace) -> int:
    from layouts.publish import output_folder
    from mvracklay.outputs import is_run_output, spawn_viewer
    from stitching.path_record import registration_warning

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
    config = stitch_settings(args.board_thickness, args.noisy, args.keep_steps)
    final_out = Path(args.out)
    inputs = {"layouts": folder.root, "meta.json": seq_dir / "meta.json", "rgb": seq_dir / "rgb", "INPUT": seq_dir}
    with output_folder(final_out, MAP_OUTPUTS, command="run", earlier=is_run_output, inputs=inputs,
                       overwrite=args.overwrite, untouched=("layouts",), may_hold_inputs=True) as out:  # fmt: skip
        wmap, t_stitch = reconstruct_folder(
            folder, indices, out, seq, config, not args.no_rrd, not args.no_rgb, args.map_every, not args.quiet
        )
    said = registration_warning(wmap.meta.get("registration"), len(indices))
    if said:
        print(f"mvracklay reconstruct: warning: {said}", file=sys.stderr)
    fps = len(indices) / t_stitch if t_stitch > 0 else float("inf")
    print(
        f"{len(indices)} frames -> {len(wmap.racks)} racks, {len(wmap.shelves())} shelves, {len(wmap.boxes())} boxes "
        f"(stitching {fps:.0f} frames/s)"
    )
    print(
        f"wrote {final_out / 'warehouse.json'}, {final_out / 'warehouse.glb'}"
        + ("" if args.no_rrd else f", {final_out / 'warehouse.rrd'}")
    )
    if args.spawn:
        spawn_viewer(final_out / "warehouse.rrd")
    return 0
