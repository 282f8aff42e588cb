"""The one inference path of `mvracklay run` and `predict`: a source's frames streamed through a `Predictor` set
up from `InferenceSettings` (`make_predictor`), each frame's layouts with its visible columns and the angles it was
levelled by (`FrameStream.frames`).

`predict_folder` writes them to a layout folder (``mvracklay predict``); `mvracklay.pipeline` feeds the same
frames to a `stitching.pipeline.Stitcher` (``mvracklay run``).
"""

from __future__ import annotations

import json
import math
import sys
from collections.abc import Callable, Iterator
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from layouts.codecs import FrameLayouts, LayoutFolder
from layouts.errors import InputError
from layouts.fileio import atomic_write_text, load_json
from mvracklay.settings import InferenceSettings

if TYPE_CHECKING:
    from layouts import Intrinsics, LayoutSpec
    from layouts.lens import Lens
    from mvracklay.camera import FrameDistances
    from mvracklay.frames import FrameSource
    from mvracklay.use_settings import PredictSettings
    from network.inference.predictor import Predictor
    from network.inference.result import FramePrediction
    from network.model.net import MVRackLay

#: beside a predicted layout folder's frames: each frame's camera step along the row as the images read it
CAMERA_STEPS = "camera_steps.json"


@dataclass(frozen=True)
class PredictedFrame:
    """One frame of the stream with what the later stages need: its layouts (with the columns in view), the
    distance used, the camera's (roll, pitch, yaw) it was levelled by (degrees; 0 for a level camera) and the
    prediction."""

    index: int
    layouts: FrameLayouts
    distance: float
    prediction: FramePrediction
    angles: tuple[float, float, float] = (0.0, 0.0, 0.0)


def make_predictor(
    model: MVRackLay,
    settings: InferenceSettings,
    intr: Intrinsics,
    distances: FrameDistances,
    recorded_angles: tuple[float, float, float] | None,
) -> Predictor:
    """A `Predictor` for frames of camera ``intr`` at ``distances``; an angle not set is a generated sequence's
    ``recorded_angles``, else read from the frames (`network.inference.roll.resolve_angles`)."""
    from network.inference.predictor import Predictor
    from network.inference.roll import resolve_angles

    roll, pitch, yaw = resolve_angles(settings.roll, settings.pitch, settings.yaw, recorded_angles)
    kwargs = {**settings.predictor_kwargs(), "roll": roll, "pitch": pitch, "yaw": yaw}
    return Predictor(model, lambda i: (intr, distances(i)), **kwargs)


@dataclass
class FrameStream:
    """A source's frames as the network sees them: the camera (``intr``, the ``lens`` undistorted first), the
    distances, the predictor and the layouts' ``spec``; `frames` predicts them one by one. What the stream read
    from the frames (the camera's angles, the rack depth) is told by its frames and `read_angles`."""

    source: FrameSource
    predictor: Predictor
    spec: LayoutSpec
    intr: Intrinsics
    lens: Lens | None
    distances: FrameDistances
    #: where a generated sequence's first camera stood: the map's world origin and the camera's height and distance
    #: in the map frame (`stitching.warehouse_map.camera_in_map`); Nones for footage
    placement: tuple = (None, None, None)

    @classmethod
    def open(
        cls, source: FrameSource, model: MVRackLay, settings: InferenceSettings, camera: tuple, spec: LayoutSpec
    ) -> FrameStream:
        """The stream of ``source`` through ``model`` as ``settings`` say; ``camera``: ``(intrinsics, lens,
        distances)`` of the frames (`make_predictor`)."""
        from stitching.warehouse_map import camera_in_map

        intr, lens, distances = camera
        pred = make_predictor(model, settings, intr, distances, source.camera_angles)
        try:  # a generated sequence's first camera, as the map places it
            placement = camera_in_map(source.records[0]) if source.records else (None, None, None)
        except InputError:
            placement = (None, None, None)
        return cls(source, pred, spec, intr, lens, distances, placement)

    def frames(
        self,
        mode: str = "stream",
        max_frames: int | None = None,
        on_read: Callable[[np.ndarray], None] | None = None,
    ) -> Iterator[PredictedFrame]:
        """Each frame (undistorted through the lens first, if any; footage's distance read from its first frames
        before the first is predicted) predicted, its layouts at the stream's spec; ``on_read`` sees every frame
        as it is read (all of them before the first prediction with ``whole_sequence``)."""
        source, distances, intr, lev = self.source, self.distances, self.intr, self.predictor.leveller

        def read() -> Iterator[np.ndarray]:
            raw = source.frames(max_frames, (intr, self.lens) if self.lens is not None else None)
            for rgb in distances.lead(raw):
                if on_read is not None:
                    on_read(rgb)
                yield rgb

        self.predictor.next_ready = source.next_ready  # a live stream's frames overlap only while one waits
        for i, out in enumerate(self.predictor.predict(read(), mode)):
            lay = out.layouts(self.spec)
            dist = distances(i)
            visible = np.asarray(intr.visible_columns(self.spec, dist), bool)
            levelled = lev is not None and i < len(lev.rolls)
            angles = (lev.rolls[i], lev.pitches[i], lev.yaws[i]) if levelled else (0.0, 0.0, 0.0)
            yield PredictedFrame(i, FrameLayouts(lay["top"], lay["front"], visible), dist, out, angles)

    def read_angles(self) -> dict[str, list[float]]:
        """The camera angles read from the frames, by name, frame by frame (none when all were given or level)."""
        lev = self.predictor.leveller
        return lev.read_angles() if lev is not None else {}

    def median_angles(self) -> tuple[float, float, float]:
        """The median (roll, pitch, yaw) the frames were levelled by (degrees; 0 when none was levelled)."""
        lev = self.predictor.leveller
        lists = (lev.rolls, lev.pitches, lev.yaws) if lev is not None else ([], [], [])
        return tuple(float(np.median(v)) if v else 0.0 for v in lists)  # type: ignore[return-value]


def predict_folder(
    model: MVRackLay,
    record: dict[str, Any],
    settings: PredictSettings,
    *,
    source: str = "checkpoint",
    prog: str = "mvracklay predict",
) -> int:
    """Write the layouts ``model`` predicts for ``settings.seq_dir`` to the layout folder ``settings.out``; returns
    the frame count.

    ``seq_dir`` is any input of `mvracklay.frames.open_source` (a sequence, an image folder, an image, a
    video); ``every``: every N-th frame. The canonical warp and the visible columns use ``camera`` (``--camera``)
    / ``distance`` when given, else the sequence's intrinsics and per-frame distance from ``meta.json``, else
    the checkpoint ``record``'s camera and the distance read from the first frames (`mvracklay.camera.FrameDistances`).
    ``inference``: what the prediction does (`InferenceSettings`: flip, rack depth, depth reading, whole
    sequence, fusion, the camera's angles); ``mode``, ``layout_size``, ``quiet``: as `PredictSettings` says.
    """
    from tqdm import tqdm

    from layouts.publish import output_folder
    from layouts.rackdepth import check_rack_depth
    from mvracklay.camera import FrameDistances, camera_warning, default_distance, frames_camera
    from mvracklay.frames import every_nth, open_source

    seq_dir, out, layout_size, progress = settings.seq_dir, settings.out, settings.layout_size, not settings.quiet
    intrinsics = str(settings.camera) if settings.camera is not None else None
    frames = every_nth(open_source(seq_dir, prog=prog), settings.every)
    # the layouts never land in (or over) the input; a layout folder written whole, an earlier one replaced
    with output_folder(out, None, command="predict", earlier=lambda d: (d / "spec.json").is_file(),
                       inputs={"INPUT": seq_dir}) as st:  # fmt: skip
        intr, lens = frames_camera(intrinsics, frames, record, source)
        differs = camera_warning(intr, record, source, guessed=intrinsics is None and frames.intrinsics is None)
        if differs:
            print(f"{prog}: warning: camera {differs}", file=sys.stderr)
        dist_of = FrameDistances(frames, intr, settings.distance, None, default_distance(record), prog=prog)
        spec = model.cfg.spec if not layout_size else replace(model.cfg.spec, size=layout_size)
        if settings.inference.rack_depth is not None:
            check_rack_depth(settings.inference.rack_depth, spec)
        stream = FrameStream.open(frames, model, settings.inference, (intr, lens, dist_of), spec)
        folder = LayoutFolder.create(st, spec)
        bar = tqdm(total=frames.frame_count(), desc=f"predict ({settings.mode})", unit="frame", disable=not progress)
        depth, n = float("nan"), 0
        steps: list[float] = []
        confidence: list[float] = []
        for frame in stream.frames(settings.mode, on_read=lambda _: bar.update(1)):
            folder.write(frame.index, frame.layouts)
            depth, n = frame.prediction.rack_depth, frame.index + 1
            if frame.prediction.camera_step is not None:
                steps.append(round(frame.prediction.camera_step, 6))
                confidence.append(round(float(frame.prediction.camera_step_confidence), 4))
        bar.close()
        if n == 0:
            raise InputError(f"{frames.path}: no frames to process")
        if len(steps) == n:
            write_camera_steps(folder.root, steps, confidence)
    report_readings(stream, depth, progress, prog)
    if progress and dist_of.reading is not None and not dist_of.recorded:
        print(f"distance to the racks: {dist_of.reading.describe()}")
    return n


def write_camera_steps(root: Path, steps: list[float], confidence: list[float]) -> None:
    """Store the image-read camera steps (metres, frame i-1 -> i; ``steps[0]`` is 0) and their confidences."""
    doc = {"frames": len(steps), "step_m": steps, "confidence": confidence}
    atomic_write_text(Path(root) / CAMERA_STEPS, json.dumps(doc) + "\n")


def read_camera_steps(root: Path) -> tuple[list[float], list[float]] | None:
    """The steps `write_camera_steps` stored in ``root`` (None when there are none), checked."""
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


def report_readings(stream: FrameStream, depth: float, progress: bool, prog: str) -> None:
    """Say what the prediction read from the frames: the rack depth (with the back-edge head) and the camera's
    angles, and warn about angles that look wrong."""
    from network.inference.roll import angle_warnings, describe_angles

    if stream.predictor.reads_depth and progress:
        said = f"{depth:.3f} m" if math.isfinite(depth) else "none (no board showed its back edge)"
        print(f"rack depth read from the boards' back edges: {said}")
    read = stream.read_angles()
    for line in describe_angles(read) if progress else []:
        print(line)
    for said in angle_warnings(read, width=stream.intr.width):
        print(f"{prog}: warning: {said}", file=sys.stderr)
