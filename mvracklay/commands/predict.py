"""``mvracklay predict``: per-frame layouts of a sequence, written as a layout folder."""

from __future__ import annotations

import argparse
from pathlib import Path

from layouts.errors import InputError
from mvracklay.models import CHECKPOINT_HELP, DEFAULT_MODEL, checkpoint_arg
from mvracklay.options import (
    add_device_option,
    add_hidden_alias,
    add_precision_option,
    add_quiet_option,
    add_threads_option,
)
from mvracklay.settings import InferenceSettings, add_options, from_args
from mvracklay.threads import resolve_threads

NAME = "predict"
HELP = "predict top/front layouts for every frame of a sequence, image folder, image or video"
DESCRIPTION = (
    "Run a checkpoint over INPUT (the inputs of 'mvracklay run': a generated sequence folder with rgb/ and "
    "meta.json, any folder of images in name order, one image, or a video file) and write a layout folder (spec.json + NNNNNN.npz with top, front, visible) that "
    "'mvracklay reconstruct' reads. Streaming mode carries the ConvLSTM state frame to frame (one encoder "
    "pass per frame); window mode predicts each frame from the last seq_len frames, as in the paper. "
    "Every frame is warped into the model's canonical view with the camera intrinsics and the "
    "camera-to-rack distance, which also give the visible columns: --camera / --distance when given, else "
    "meta.json's, else the default camera and the distance read from the first frames (as 'mvracklay run' "
    "reads it, printed). A wrong distance scales the layouts (and the map) by true / used distance: pass "
    "--distance when you know it. Without --checkpoint it runs the shipped "
    f"{DEFAULT_MODEL}, as 'mvracklay run' does."
)
GROUP = "use"
ORDER = 13


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("seq_dir", type=Path, metavar="INPUT", help="sequence folder, image folder, image or video file")
    p.add_argument("--checkpoint", type=checkpoint_arg, help=f"{CHECKPOINT_HELP}; default: the shipped {DEFAULT_MODEL}")
    p.add_argument("--out", type=Path, required=True, help="layout folder to write")
    p.add_argument(
        "--mode", choices=["stream", "window"], default="stream",
        help="streaming (memory carried frame to frame) or windowed (the paper)",
    )  # fmt: skip
    p.add_argument("--layout-size", type=int, default=0, help="D of the written layouts (0 = the model's)")
    p.add_argument(
        "--camera",
        metavar="FILE|fx,fy,cx,cy",
        help="the camera intrinsics: a JSON file (as `run --camera`: fx, fy, cx, cy, width, height and a lens's "
        "distortion beside them, OpenCV's k1, k2, p1, p2, k3: every frame is then undistorted first), or fx,fy,cx,cy "
        "in pixels of the input images",
    )
    add_hidden_alias(p, "--intrinsics", "camera")
    p.add_argument(
        "--distance", type=float, help="camera to rack front in metres (default: meta.json, else read from the frames)"
    )
    add_options(p, InferenceSettings)  # --flip-average, --rack-depth, --no-depth-read, ... (mvracklay.settings)
    add_threads_option(p)
    p.add_argument(
        "--every", type=int, default=1, metavar="N", help="predict every N-th input frame (written as 0, 1, 2, ...)"
    )
    add_precision_option(p)
    add_device_option(p)
    add_quiet_option(p, "hide the progress bar")


def run(args: argparse.Namespace) -> int:
    from mvracklay.inference import predict_folder
    from mvracklay.models import resolve_checkpoint
    from network.inference.distance import check_distance
    from network.inference.loading import load_for_inference

    settings = from_args(InferenceSettings, args)
    settings.validate()  # checked before the model loads
    check_distance(args.distance)
    if args.layout_size and not 8 <= args.layout_size <= 1024:
        raise InputError(f"--layout-size must be in [8, 1024], got {args.layout_size}")
    if args.every < 1:
        raise InputError(f"--every must be an integer >= 1, got {args.every}")
    # the shipped default model without --checkpoint (as `run`); a given path keeps the loader's own messages
    ckpt = args.checkpoint if args.checkpoint is not None else resolve_checkpoint(None)
    model, record = load_for_inference(ckpt, NAME, args.device, args.precision, resolve_threads(args.threads))
    n = predict_folder(
        model,
        record,
        args.seq_dir,
        args.out,
        settings,
        mode=args.mode,
        layout_size=args.layout_size,
        intrinsics=args.camera,
        distance=args.distance,
        progress=not args.quiet,
        every=args.every,
        source=str(ckpt),
    )
    print(f"wrote {n} frames of layouts to {args.out}")
    return 0
