"""``mvracklay run``: the main job, from a video or image folder to a 3D warehouse map and free space."""

from __future__ import annotations

import argparse
from pathlib import Path

from layouts.errors import InputError
from layouts.rackdepth import NO_DEPTH_READ_HELP, RACK_DEPTH_HELP
from mvracklay.models import CHECKPOINT_HELP, DEFAULT_MODEL, checkpoint_arg
from network.inference.frozen import add_precision_option
from network.inference.fusion import add_fuse_option
from network.inference.predictor import FLIP_HELP, WHOLE_SEQUENCE_HELP
from network.inference.roll import add_roll_option, describe_angles

NAME = "run"
HELP = "the main job: video / image folder / sequence -> layouts -> 3D map (.glb, .json, .rrd) + free space"
DESCRIPTION = (
    "Run the MVRackLay network over INPUT frame by frame (streaming: one encoder pass per frame, the ConvLSTM "
    "state carried), stitch the per-frame layouts into one 3D map of the rack row, and write OUT/layouts/ "
    "(a layout folder for 'mvracklay reconstruct'), OUT/warehouse.json, OUT/warehouse.glb and "
    "OUT/warehouse.rrd; then print the free space per shelf. INPUT is a WareSynth sequence folder, any folder "
    "of ordered PNG/JPEG images (natural name order, all the same size) or a video file. The camera should "
    "move sideways along one rack row at a roughly constant distance, facing the racks, without turning as it "
    "goes; a camera mounted askew is levelled: its roll read from the frames (--roll), a pitch or yaw given or "
    "read (--pitch, --yaw). "
    "Intrinsics: --camera JSON, else the sequence's meta.json, else the default camera (60 deg horizontal "
    "field of view, principal point at the centre) at the frame size. No ground truth is needed. A failed run "
    "leaves OUT as it was."
)
ORDER = 10


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("input", metavar="INPUT", help="sequence folder, image folder or video file")
    p.add_argument("--out", required=True, type=Path, help="output folder")
    p.add_argument(
        "--checkpoint",
        type=checkpoint_arg,
        help=f"{CHECKPOINT_HELP}; default: the shipped {DEFAULT_MODEL}",
    )
    p.add_argument(
        "--camera",
        type=Path,
        help="JSON with the camera intrinsics: fx, fy, cx, cy in pixels and the width, height they refer to; "
        "with a lens's distortion beside them (OpenCV's k1, k2, p1, p2, k3, as a calibration gives), every "
        "frame is undistorted before the network (~13 ms a 640x360 frame; wider ones shrunk to 640 first)",
    )
    p.add_argument("--mode", choices=["stream", "window"], default="stream", help="network inference mode")
    p.add_argument("--flip-average", action="store_true", help=FLIP_HELP)
    p.add_argument("--max-frames", type=int, default=0, help="process at most N frames (0 = all)")
    p.add_argument(
        "--distance", type=float, help="camera to rack front in metres (default: input records, else the model's)"
    )
    p.add_argument("--rack-depth", type=float, metavar="M", help=RACK_DEPTH_HELP)
    p.add_argument("--no-depth-read", action="store_true", help=NO_DEPTH_READ_HELP)
    p.add_argument("--whole-sequence", action="store_true", help=WHOLE_SEQUENCE_HELP)
    add_fuse_option(p)
    add_roll_option(p)
    p.add_argument("--layout-size", type=int, default=0, help="resolution D of the written layouts (0 = the model's)")
    p.add_argument("--spawn", action="store_true", help="open the Rerun viewer on OUT/warehouse.rrd when done")
    p.add_argument("--no-rrd", action="store_true", help="do not write warehouse.rrd")
    p.add_argument("--no-rgb", action="store_true", help="do not log the RGB frames to Rerun")
    p.add_argument("--map-every", type=int, default=1, help="log the growing map to Rerun every N frames")
    p.add_argument(
        "--no-opening",
        action="store_true",
        help="stitch with the ground-truth settings instead of the clean-up for network output (StitchConfig.noisy)",
    )
    p.add_argument("--board-thickness", type=float, default=0.06, help="assumed shelf board thickness (metres)")
    p.add_argument("--threads", type=int, default=2, help="CPU threads for the network")
    add_precision_option(p)
    p.add_argument("--quiet", action="store_true", help="no progress bars")


def run(args: argparse.Namespace) -> int:
    from mvracklay.frames import open_source
    from mvracklay.pipeline import RunConfig, run_pipeline, spawn_viewer
    from stitching.free_space import format_table

    if args.spawn and args.no_rrd:
        raise InputError("--spawn opens OUT/warehouse.rrd; it cannot be combined with --no-rrd")
    cfg = RunConfig(
        checkpoint=args.checkpoint,
        camera=args.camera,
        mode=args.mode,
        flip=args.flip_average,
        max_frames=args.max_frames,
        layout_size=args.layout_size,
        distance=args.distance,
        rack_depth=args.rack_depth,
        read_depth=not args.no_depth_read,
        whole_sequence=args.whole_sequence,
        fuse_tau=args.fuse_frames,
        roll=args.roll,
        pitch=args.pitch,
        yaw=args.yaw,
        rrd=not args.no_rrd,
        rgb=not args.no_rgb,
        map_every=args.map_every,
        opening=not args.no_opening,
        board_thickness=args.board_thickness,
        threads=args.threads,
        precision=args.precision,
        progress=not args.quiet,
    )
    cfg.validate()
    from mvracklay.pipeline import resolve_checkpoint

    resolve_checkpoint(cfg.checkpoint)  # fail before decoding anything
    source = open_source(args.input)
    res = run_pipeline(source, args.out, cfg)
    wmap = res.map
    print(
        f"{res.frames} frames ({source.kind}, {source.width}x{source.height}, camera: {res.intrinsics_source}) -> "
        f"{len(wmap.racks)} racks, {len(wmap.shelves())} shelves, {len(wmap.boxes())} boxes"
    )
    t = res.seconds
    rate = ", ".join(f"{k} {res.frames / t[k]:.1f} frames/s" for k in ("predict", "stitch", "rerun") if t.get(k, 0) > 0)
    print(f"speed: {rate} (wall, this machine)")
    for line in describe_angles(res.angles_read):
        print(line)
    print(format_table(res.free_space))
    print("wrote " + ", ".join(str(p) for p in res.paths.values()))
    if args.spawn:
        spawn_viewer(res.out / "warehouse.rrd")
    return 0
