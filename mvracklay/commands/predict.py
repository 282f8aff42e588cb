"""``mvracklay predict``: per-frame layouts of a sequence, written as a layout folder."""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from layouts.errors import InputError
from mvracklay.models import CHECKPOINT_HELP, DEFAULT_MODEL, checkpoint_arg
from mvracklay.options import (
    FLIP_HELP,
    NO_DEPTH_READ_HELP,
    RACK_DEPTH_HELP,
    WHOLE_SEQUENCE_HELP,
    add_device_option,
    add_fuse_option,
    add_hidden_alias,
    add_precision_option,
    add_quiet_option,
    add_roll_option,
    add_threads_option,
)
from mvracklay.threads import resolve_threads

if TYPE_CHECKING:
    import numpy as np

    from layouts import Intrinsics, LayoutSpec
    from layouts.codecs import LayoutFolder
    from layouts.lens import Lens
    from mvracklay.distance import FrameDistances
    from mvracklay.frames import FrameSource
    from network.inference.predictor import Predictor
    from network.model.net import MVRackLay

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
    p.add_argument("--flip-average", action="store_true", help=FLIP_HELP)
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
    p.add_argument("--rack-depth", type=float, metavar="M", help=RACK_DEPTH_HELP)
    p.add_argument("--no-depth-read", action="store_true", help=NO_DEPTH_READ_HELP)
    p.add_argument("--whole-sequence", action="store_true", help=WHOLE_SEQUENCE_HELP)
    add_fuse_option(p)
    add_roll_option(p)
    add_threads_option(p)
    p.add_argument(
        "--every", type=int, default=1, metavar="N", help="predict every N-th input frame (written as 0, 1, 2, ...)"
    )
    add_precision_option(p)
    add_device_option(p)
    add_quiet_option(p, "hide the progress bar")


def _parse_intrinsics(text: str, width: int, height: int) -> tuple[Intrinsics, Lens | None]:
    """``--camera``: fx,fy,cx,cy, or a JSON file with them (and a lens's k1..k3 beside them, if any), read and
    checked as `run` reads it (`mvracklay.camera.load_camera`: scaled to the frames' ``width x height``)."""
    from layouts import Intrinsics
    from mvracklay.camera import load_camera, load_lens

    path = Path(text)
    if path.suffix == ".json" or path.is_file():
        return load_camera(path, width, height), load_lens(path)
    try:
        fx, fy, cx, cy = (float(v) for v in text.split(","))
    except ValueError:
        raise InputError(f"--camera: want a JSON file or fx,fy,cx,cy, got {text!r}") from None
    return Intrinsics(fx, fy, cx, cy, width, height), None


def run(args: argparse.Namespace) -> int:
    import torch

    from layouts.rackdepth import check_rack_depth
    from mvracklay.models import resolve_checkpoint
    from network.checkpoint import load_model
    from network.inference.fusion import check_tau
    from network.inference.roll import resolve_angles
    from network.model.frozen import use_precision
    from network.training.distributed import single_process_device

    fuse_tau = check_tau(args.fuse_frames, "--fuse-frames")
    resolve_angles(args.roll, args.pitch, args.yaw, None)  # checked before the model loads
    if args.distance is not None and (not math.isfinite(args.distance) or args.distance <= 0):
        raise InputError(f"--distance must be a positive number of metres, got {args.distance}")
    if args.rack_depth is not None:
        check_rack_depth(args.rack_depth)
    if args.layout_size and not 8 <= args.layout_size <= 1024:
        raise InputError(f"--layout-size must be in [8, 1024], got {args.layout_size}")
    if args.every < 1:
        raise InputError(f"--every must be an integer >= 1, got {args.every}")
    # the shipped default model without --checkpoint (as `run`); a given path keeps the loader's own messages
    ckpt = args.checkpoint if args.checkpoint is not None else resolve_checkpoint(None)
    torch.set_num_threads(resolve_threads(args.threads))
    model, record = load_model(ckpt)
    model.to(single_process_device(NAME, args.device))
    use_precision(model, args.precision)
    n = predict_folder(
        model,
        record,
        args.seq_dir,
        args.out,
        mode=args.mode,
        flip=args.flip_average,
        layout_size=args.layout_size,
        intrinsics=args.camera,
        distance=args.distance,
        rack_depth=args.rack_depth,
        read_depth=not args.no_depth_read,
        whole_sequence=args.whole_sequence,
        fuse_tau=fuse_tau,
        roll=args.roll,
        pitch=args.pitch,
        yaw=args.yaw,
        progress=not args.quiet,
        every=args.every,
        source=str(ckpt),
    )
    print(f"wrote {n} frames of layouts to {args.out}")
    return 0


def predict_folder(
    model: MVRackLay,
    record: dict[str, Any],
    seq_dir: Path,
    out: Path,
    *,
    mode: str = "stream",
    flip: bool = False,
    layout_size: int = 0,
    intrinsics: str | None = None,
    distance: float | None = None,
    rack_depth: float | None = None,
    read_depth: bool = True,
    whole_sequence: bool = False,
    fuse_tau: float = 0.0,
    roll: float | str | None = None,
    pitch: float | str | None = None,
    yaw: float | str | None = None,
    progress: bool = True,
    source: str = "checkpoint",
    every: int = 1,
) -> int:
    """Write the layouts ``model`` predicts for ``seq_dir`` to the layout folder ``out``; returns the frame count.

    ``seq_dir`` is any input of `mvracklay.frames.open_source` (a sequence, an image folder, an image, a
    video). The canonical warp and the visible columns use ``intrinsics`` / ``distance`` when given, else the
    sequence's intrinsics and per-frame distance from ``meta.json``, else the camera and mean
    distance in ``record``. ``rack_depth`` (metres) redraws every top view that deep
    (`layouts.rackdepth.impose_rack_depth`); without it a model with a back-edge head reads the depth
    itself unless ``read_depth`` is False (`network.inference.predictor.Predictor`), from the frames so far or, with
    ``whole_sequence``, from every frame; ``fuse_tau`` fuses neighbouring frames (`network.inference.fusion`).
    ``roll``: the camera's roll (degrees or "auto", `network.inference.roll`); None: a generated sequence's
    recorded roll (0 for a level camera), else read from the frames; ``pitch`` / ``yaw``: the camera's
    tilt (up > 0) / turn (right > 0), the same.
    """
    from layouts.codecs import LayoutFolder
    from layouts.rackdepth import check_rack_depth
    from mvracklay.camera import camera_warning
    from mvracklay.every import every_nth
    from mvracklay.frames import open_source
    from network.inference.predictor import Predictor
    from network.inference.roll import resolve_angles

    frames = every_nth(open_source(seq_dir, prog=f"mvracklay {NAME}"), every)  # ``every``: every N-th frame
    intr, lens = _sequence_camera(intrinsics, frames, record, source)
    differs = camera_warning(intr, record, source, guessed=intrinsics is None and frames.intrinsics is None)
    if differs:
        print(f"mvracklay predict: warning: camera {differs}", file=sys.stderr)
    dist_of = _frame_distances(distance, frames, record, intr)
    spec = model.cfg.spec if not layout_size else replace(model.cfg.spec, size=layout_size)
    if rack_depth is not None:
        check_rack_depth(rack_depth, spec)
    # a generated sequence's camera rotation is recorded; footage's is read from the frames
    roll, pitch, yaw = resolve_angles(roll, pitch, yaw, frames.camera_angles)
    folder = LayoutFolder.create(out, spec)
    pred = Predictor(
        model,
        lambda i: (intr, dist_of(i)),
        flip=flip,
        rack_depth=rack_depth,
        read_depth=read_depth,
        whole_sequence=whole_sequence,
        fuse_tau=fuse_tau,
        roll=roll,
        pitch=pitch,
        yaw=yaw,
    )
    n, depth = _write_layouts(pred, frames, folder, spec, intr, lens, dist_of, mode, progress)
    if n == 0:
        raise InputError(f"{frames.path}: no frames to process")
    _report_readings(pred, depth, intr, progress)
    if progress and dist_of.reading is not None and not dist_of.recorded:
        print(f"distance to the racks: {dist_of.reading.describe()}")
    return n


def _write_layouts(
    pred: Predictor,
    seq: FrameSource,
    folder: LayoutFolder,
    spec: LayoutSpec,
    intr: Intrinsics,
    lens: Lens | None,
    dist_of: FrameDistances,
    mode: str,
    progress: bool,
) -> tuple[int, float]:
    """Predict every frame of ``seq`` (undistorted through ``lens`` first, if any) and write its layouts with
    its visible columns to ``folder`` (at ``spec``); returns the frames written and the last rack depth read
    (NaN when none)."""
    import numpy as np
    from tqdm import tqdm

    from layouts.codecs import FrameLayouts
    from network.inference.predictor import frame_layouts

    bar = tqdm(total=seq.frame_count(), desc=f"predict ({mode})", unit="frame", disable=not progress)

    def frames() -> Iterator[np.ndarray]:  # the bar counts frames read (all of them first with whole_sequence)
        raw = seq.frames(undistort=(intr, lens) if lens is not None else None)
        for rgb in dist_of.lead(raw):  # footage: its distance read from its first frames first
            yield rgb
            bar.update(1)

    depth, n = float("nan"), 0
    steps: dict[str, list[float]] = {"step": [], "confidence": []}
    for i, logits in enumerate(pred.run(frames(), mode)):
        lay = frame_layouts(logits, spec)
        depth = float(logits["rack_depth"])
        visible = np.asarray(intr.visible_columns(spec, dist_of(i)), bool)
        folder.write(i, FrameLayouts(lay["top"], lay["front"], visible))
        if "camera_step" in logits:
            steps["step"].append(round(float(logits["camera_step"]), 6))
            steps["confidence"].append(round(float(logits["camera_step_confidence"]), 4))
        n = i + 1
    bar.close()
    if n and len(steps["step"]) == n:
        write_camera_steps(folder.root, steps["step"], steps["confidence"])
    return n, depth


#: beside a predicted layout folder's frames: each frame's camera step along the row as the images read it
CAMERA_STEPS = "camera_steps.json"


def write_camera_steps(root: Path, steps: list[float], confidence: list[float]) -> None:
    """Store the image-read camera steps (metres, frame i-1 -> i; ``steps[0]`` is 0) and their confidences."""
    import json

    from layouts.fileio import atomic_write_text

    doc = {"frames": len(steps), "step_m": steps, "confidence": confidence}
    atomic_write_text(Path(root) / CAMERA_STEPS, json.dumps(doc) + "\n")


def read_camera_steps(root: Path) -> tuple[list[float], list[float]] | None:
    """The steps `write_camera_steps` stored in ``root`` (None when there are none), checked."""
    from layouts.fileio import load_json

    path = Path(root) / CAMERA_STEPS
    if not path.is_file():
        return None
    doc = load_json(path)
    steps, conf = (doc.get(k) if isinstance(doc, dict) else None for k in ("step_m", "confidence"))
    ok = isinstance(steps, list) and isinstance(conf, list) and len(steps) == len(conf)
    ok = ok and all(isinstance(v, (int, float)) and math.isfinite(v) for v in steps + conf)
    if not ok:
        raise InputError(f"{path}: expected step_m and confidence, two lists of finite numbers of one length")
    return [float(v) for v in steps], [float(v) for v in conf]


def _sequence_camera(
    intrinsics: str | None, frames: FrameSource, record: dict[str, Any], source: str
) -> tuple[Intrinsics, Lens | None]:
    """The camera of the frames and its lens's distortion, if any (each frame is then undistorted first):
    ``--camera``, else the sequence's meta.json, else the checkpoint's record, else a 60 degree view."""
    from layouts import Intrinsics

    width, height = frames.width, frames.height
    if intrinsics:
        return _parse_intrinsics(intrinsics, width, height)
    if frames.intrinsics is not None:
        return frames.intrinsics, frames.lens
    if record.get("intrinsics"):
        return Intrinsics.from_dict(record["intrinsics"], source).scaled(width, height), None
    return Intrinsics.from_fov(width, height, 60.0), None


def _frame_distances(
    distance: float | None, frames: FrameSource, record: dict[str, Any], intr: Intrinsics
) -> FrameDistances:
    """Frame index -> camera-to-rack distance, as `mvracklay run` has it (`mvracklay.distance.FrameDistances`):
    ``distance`` when given, else the frames' in meta.json, else read from the first frames."""
    from mvracklay.distance import FrameDistances, default_distance

    return FrameDistances(frames, intr, distance, None, default_distance(record), prog=f"mvracklay {NAME}")


def _report_readings(pred: Predictor, depth: float, intr: Intrinsics, progress: bool) -> None:
    """Say what the run read from the frames: the rack depth (with the back-edge head) and the camera's angles,
    and warn about angles that look wrong."""
    from network.inference.roll import angle_warnings, describe_angles

    if pred.reads_depth and progress:
        said = f"{depth:.3f} m" if math.isfinite(depth) else "none (no board showed its back edge)"
        print(f"rack depth read from the boards' back edges: {said}")
    read = pred.leveller.read_angles() if pred.leveller is not None else {}
    for line in describe_angles(read) if progress else []:
        print(line)
    for said in angle_warnings(read, width=intr.width):
        print(f"mvracklay predict: warning: {said}", file=sys.stderr)
