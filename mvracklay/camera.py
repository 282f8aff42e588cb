"""The camera of a run: the intrinsics and lens of the frames (``--camera`` JSON, a sequence's meta.json or
the default 60 degree camera), how they compare with the cameras a model was trained with, and the camera's
distance to the racks and where it came from (`FrameDistances`: printed, and kept in warehouse.json).

`mvracklay.frames` opens the frames; this module says what camera filmed them, and from how far.

The distance, in order: ``--distance`` (given); the camera height ``--camera-height`` with the floor line read
from the first frames; a generated sequence's recorded distances; else read from the first frames' sizes by the
shipped distance reader (`network.inference.distance`). Without a reader file (a copy made without the
weights), or from frames too small to read (`MIN_READ_SIDE`), the default distance is used, and said. A wrong
distance scales the whole map: every length (box sizes, positions along the row, shelf heights) is off by the
same factor. Counts, the order of boxes and free *fractions* are unchanged by the scale.
"""

from __future__ import annotations

import itertools
import math
import os
import sys
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from layouts import Intrinsics
from layouts.camera_record import check_camera_fits, lens_from_record
from layouts.errors import InputError
from layouts.fileio import load_json
from layouts.lens import Lens
from mvracklay.camera_schema import camera_file_record
from mvracklay.models import distance_reader_path
from network.inference.distance import (
    LEAD_FRAMES,
    DistanceReading,
    check_distance,
    distance_warning,
    load_reader,
    read_distance,
)
from network.preprocess import DEFAULT_DISTANCE

if TYPE_CHECKING:
    from mvracklay.frames import FrameSource

DEFAULT_HFOV_DEG = 60.0
"""Horizontal field of view of the default camera (the generator's default, waresynth/default_config.json)."""


def default_intrinsics(width: int, height: int) -> Intrinsics:
    """The documented default camera at this frame size: 60 deg horizontal FOV, centred principal point."""
    return Intrinsics.from_fov(width, height, DEFAULT_HFOV_DEG)


def _camera_record(path: str | os.PathLike) -> dict[str, Any]:
    """A ``--camera`` file's keys, flat and checked against its schema (`mvracklay.camera_schema`)."""
    p = Path(path)
    if not p.is_file():
        raise InputError(f"--camera {p}: file not found")
    return camera_file_record(load_json(p), f"--camera {p}")


def load_camera(path: str | os.PathLike, width: int, height: int) -> Intrinsics:
    """Intrinsics from a ``--camera`` JSON file, scaled to the frame size.

    The file holds ``layouts.Intrinsics`` fields (fx, fy, cx, cy in pixels; width, height of the
    image they refer to, default the frame size), at the top level or under ``"intrinsics"``, and
    optionally the lens's distortion beside them (k1, k2, p1, p2, k3, OpenCV's; `load_lens`), and
    nothing else. A principal point outside the image, or an image of another aspect ratio than the
    frames: `InputError` (scaling it would stretch the camera).
    """
    return camera_from_record(_camera_record(path), width, height, f"--camera {path}")


def camera_from_record(record: dict[str, Any], width: int, height: int, source: str) -> Intrinsics:
    """The one check of a camera, from a ``--camera`` file or typed as fx,fy,cx,cy: `Intrinsics` fields (width
    and height default to the frames'; fields of view and principal point in their physical ranges) and the
    frames' aspect ratio (`check_camera_fits`), scaled to the frame size."""
    intr = Intrinsics.from_dict({"width": width, "height": height, **record}, source)
    check_camera_fits(intr, width, height, source)
    return intr if (intr.width, intr.height) == (width, height) else intr.scaled(width, height)


def load_lens(path: str | os.PathLike) -> Lens | None:
    """The lens distortion a ``--camera`` JSON file gives beside its intrinsics (None: none, a pinhole)."""
    return lens_from_record(_camera_record(path), f"--camera {path}")


def resolve_intrinsics(source: FrameSource, camera: str | os.PathLike | None = None) -> tuple[Intrinsics, str]:
    """``(intrinsics, where they came from)``: ``--camera`` first, then the sequence, then the default."""
    if camera is not None:
        return load_camera(camera, source.width, source.height), f"--camera {camera}"
    if source.intrinsics is not None:
        return source.intrinsics, "given" if source.kind in ("arrays", "live") else f"{source.path / 'meta.json'}"
    return default_intrinsics(source.width, source.height), f"default ({DEFAULT_HFOV_DEG:g} deg horizontal FOV)"


def resolve_lens(source: FrameSource, camera: str | os.PathLike | None = None) -> Lens | None:
    """The lens to undistort the frames through: ``--camera``'s when given (None if it gives none), else the
    sequence's meta.json's."""
    return load_lens(camera) if camera is not None else source.lens


def run_camera(
    source: FrameSource,
    camera: str | os.PathLike | None,
    record: dict[str, Any],
    checkpoint: str,
    warnings: list[str],
    prog: str = "mvracklay run",
) -> tuple[Intrinsics, str, Lens | None]:
    """``run``'s ``(intrinsics, where they came from, lens)`` of the frames (`resolve_intrinsics`,
    `resolve_lens`); a camera unlike the cameras the model (``record``, read from ``checkpoint``) was trained
    with is warned about (printed and added to ``warnings``)."""
    intr, intr_source = resolve_intrinsics(source, camera)
    lens = resolve_lens(source, camera)
    if lens is not None:
        intr_source += (
            ", frames undistorted through its lens ("
            + ", ".join(f"{k} {v:g}" for k, v in lens.to_dict().items() if v)
            + ")"
        )
    differs = camera_warning(intr, record, checkpoint, guessed=camera is None and source.intrinsics is None)
    if differs:
        warnings.append(f"camera ({intr_source}) {differs}")
        print(f"{prog}: warning: {warnings[-1]}", file=sys.stderr)
    return intr, intr_source, lens


def nearest_trained_camera(intr: Intrinsics, trained: Intrinsics, hfov_range: Any = None) -> Intrinsics:
    """The training camera nearest ``intr``: ``trained`` itself, or, for a model trained on fields of view
    drawn from ``hfov_range`` ([low, high] degrees, a checkpoint record's ``hfov_range_deg``), the one
    at ``intr``'s field of view clamped into that range (same image size and principal point)."""
    ok = (
        isinstance(hfov_range, (list, tuple))
        and len(hfov_range) == 2
        and all(isinstance(v, (int, float)) and math.isfinite(v) and 1.0 <= v <= 170.0 for v in hfov_range)
        and hfov_range[0] <= hfov_range[1]
    )
    if not ok or hfov_range[1] - hfov_range[0] <= 0.01:  # no range: the one camera as recorded
        return trained
    fov = min(max(intr.hfov_deg, float(hfov_range[0])), float(hfov_range[1]))
    return replace(Intrinsics.from_fov(trained.width, trained.height, fov), cx=trained.cx, cy=trained.cy)


def camera_mismatch(
    intr: Intrinsics, trained: Intrinsics, fov_tol_deg: float = 2.0, pp_tol: float = 0.02, hfov_range: Any = None
) -> str | None:
    """Why ``intr`` differs from the training camera (None when it matches within tolerance).

    Images are resized to the model's input, so only the fields of view and the principal point
    relative to the image size matter. A model trained on a range of fields of view (``hfov_range``)
    is compared with its training camera nearest ``intr`` (`nearest_trained_camera`).
    """
    trained = nearest_trained_camera(intr, trained, hfov_range)
    problems = []
    if abs(intr.hfov_deg - trained.hfov_deg) > fov_tol_deg:
        problems.append(f"horizontal FOV {intr.hfov_deg:.1f} deg vs {trained.hfov_deg:.1f}")
    vfov = math.degrees(2 * math.atan(intr.height / (2 * intr.fy)))
    vfov_t = math.degrees(2 * math.atan(trained.height / (2 * trained.fy)))
    if abs(vfov - vfov_t) > fov_tol_deg:
        problems.append(f"vertical FOV {vfov:.1f} deg vs {vfov_t:.1f}")
    pp = (intr.cx / intr.width, intr.cy / intr.height)
    pp_t = (trained.cx / trained.width, trained.cy / trained.height)
    if max(abs(pp[0] - pp_t[0]), abs(pp[1] - pp_t[1])) > pp_tol:
        problems.append(f"principal point at ({pp[0]:.2f}, {pp[1]:.2f}) of the image vs ({pp_t[0]:.2f}, {pp_t[1]:.2f})")
    return "; ".join(problems) or None


def camera_advice(intr: Intrinsics, trained: Intrinsics, hfov_range: Any = None, guessed: bool = False) -> str:
    """What to do about a camera `camera_mismatch` flagged, for what actually differs (measured in
    docs/network.md, *Lens distortion* and *Training on a range of cameras*); ``guessed``: the intrinsics
    are the default guess, not the user's camera, so the first advice is to give them (``--camera``)."""
    trained = nearest_trained_camera(intr, trained, hfov_range)
    said = []
    if guessed:
        said.append(
            "these intrinsics are a guess (a centred pinhole with a 60 deg horizontal field of view): give your "
            "camera's with --camera FILE (README, Filming)"
        )
    narrow = math.tan(math.radians(trained.hfov_deg) / 2) / math.tan(math.radians(intr.hfov_deg) / 2)
    if abs(intr.hfov_deg - trained.hfov_deg) > 2.0:
        if narrow > 1.0:
            said.append(
                f"a narrower camera sees less of each rack from the same distance: stand it about {narrow:.2f}x "
                f"further back, or train on data generated with camera.hfov_deg {intr.hfov_deg:.1f} (or a range "
                "that holds it)"
            )
        else:
            said.append(
                f"the model reads the middle {100 * narrow:.0f} % of each frame's width at its own scale; to use "
                f"all of it, train on data generated with camera.hfov_deg {intr.hfov_deg:.1f} (or a range that "
                "holds it)"
            )
    vfov = math.degrees(2 * math.atan(intr.height / (2 * intr.fy)))
    vfov_t = math.degrees(2 * math.atan(trained.height / (2 * trained.fy)))
    if vfov < vfov_t - 2.0:
        said.append(
            f"the frames show {vfov:.0f} of the {vfov_t:.0f} deg the model was trained to see vertically: shelves "
            "above and below that are not seen (film from further back, or hold the camera upright, to see more)"
        )
    pp = (intr.cx / intr.width, intr.cy / intr.height)
    pp_t = (trained.cx / trained.width, trained.cy / trained.height)
    if max(abs(pp[0] - pp_t[0]), abs(pp[1] - pp_t[1])) > 0.02 and not guessed:
        said.append("an off-centre principal point is handled by the resampling: check cx / cy in --camera")
    return "; ".join(said) or "nothing to change: the frames are resampled to the model's view"


def camera_warning(intr: Intrinsics, record: dict[str, Any], source: str, guessed: bool = False) -> str | None:
    """How ``intr`` differs from the cameras a checkpoint (its ``record``, read from ``source``) was trained
    with and what to do about it, as one clause ("differs from ...: why; advice"); None when it matches or
    the record names no camera. ``guessed``: ``intr`` is the default guess (no ``--camera`` given)."""
    if not record.get("intrinsics"):
        return None
    trained = Intrinsics.from_dict(record["intrinsics"], f"{source} (intrinsics)")
    fov_range = record.get("hfov_range_deg")
    why = camera_mismatch(intr, trained, hfov_range=fov_range)
    if why is None:
        return None
    advice = camera_advice(intr, trained, fov_range, guessed)
    return f"differs from the ones the model was trained with: {why}; {advice}"


def parse_camera_option(text: str, width: int, height: int) -> tuple[Intrinsics, Lens | None]:
    """``predict --camera``: fx,fy,cx,cy, or a JSON file with them (and a lens's k1..k3 beside them, if any), read
    and checked as `run` reads it (`load_camera`: scaled to the frames' ``width x height``)."""
    path = Path(text)
    if path.suffix == ".json" or path.is_file():
        return load_camera(path, width, height), load_lens(path)
    try:
        fx, fy, cx, cy = (float(v) for v in text.split(","))
    except ValueError:
        raise InputError(f"--camera: want a JSON file or fx,fy,cx,cy, got {text!r}") from None
    return camera_from_record({"fx": fx, "fy": fy, "cx": cx, "cy": cy}, width, height, f"--camera {text}"), None


def frames_camera(
    camera: str | None, frames: FrameSource, record: dict[str, Any], source: str
) -> tuple[Intrinsics, Lens | None]:
    """``predict``'s camera of the frames and its lens's distortion, if any (each frame is then undistorted first):
    ``--camera``, else the sequence's meta.json, else the checkpoint's record, else a 60 degree view."""
    width, height = frames.width, frames.height
    if camera:
        return parse_camera_option(camera, width, height)
    if frames.intrinsics is not None:
        return frames.intrinsics, frames.lens
    if record.get("intrinsics"):
        return Intrinsics.from_dict(record["intrinsics"], source).scaled(width, height), None
    return Intrinsics.from_fov(width, height, DEFAULT_HFOV_DEG), None


#: pixels a frame's shorter side must have for its distance to be read: the reader resamples each frame to its
#: 128-pixel view, and from fewer pixels it reads noise (the default distance is used, and said)
MIN_READ_SIDE = 32


def default_distance(record: dict[str, Any]) -> float:
    """The distance used when none is given, recorded or read: the checkpoint record's ``nominal_distance``
    (its training data's mean), else `network.preprocess.DEFAULT_DISTANCE`."""
    nominal = record.get("nominal_distance")
    return float(nominal) if isinstance(nominal, (int, float)) and nominal > 0 else DEFAULT_DISTANCE


class FrameDistances:
    """Frame index -> distance, known before the first frame is predicted (`lead` reads it when it must)."""

    def __init__(
        self,
        source: FrameSource,
        intr: Intrinsics,
        given: float | None = None,
        camera_height: float | None = None,
        default: float = DEFAULT_DISTANCE,
        reader: str | Path | None = None,
        prog: str = "mvracklay run",
    ) -> None:
        self.source, self.intr, self.given, self.camera_height = source, intr, given, camera_height
        self.default, self.reader_path, self.prog = default, Path(reader) if reader else None, prog
        self.reading: DistanceReading | None = None
        self.warnings: list[str] = []
        recorded: list[float | None] = []
        if given is not None:
            self.reading = DistanceReading(float(given), "given")
        elif camera_height is None and source.distance(0) is not None:
            recorded = [source.distance(i) for i in range(len(source.records or []))]
            self.reading = DistanceReading(float(np.median([d for d in recorded if d])), "recorded")
        self._check_range(given, recorded if self.recorded else [])

    def _check_range(self, given: float | None, recorded: list[float | None]) -> None:
        """A given or recorded distance outside the limits refused, outside the trained range warned of."""
        checks = [(given, "--distance")] if given is not None else []
        known = [d for d in recorded if d]
        if known:
            where = f"{self.source.path / 'meta.json'}"
            checks += [(min(known), where), (max(known), where)]
        for value, where in checks:
            check_distance(float(value), where)
            said = distance_warning(float(value), where)
            if said and said not in self.warnings:
                self.warnings.append(said)
                print(f"{self.prog}: warning: {said}", file=sys.stderr)

    @property
    def recorded(self) -> bool:
        return self.reading is not None and self.reading.source == "recorded"

    def __call__(self, index: int) -> float:
        if self.recorded:
            return self.source.distance(index) or self.reading.distance
        return self.reading.distance if self.reading is not None else self.default

    def lead(self, frames: Iterator[np.ndarray]) -> Iterator[np.ndarray]:
        """``frames`` unchanged; when the distance must be read, the first `LEAD_FRAMES` are read first."""
        if self.reading is not None:
            yield from frames
            return
        first = list(itertools.islice(frames, LEAD_FRAMES))
        if first:
            self.reading = self._read(first)
        yield from first
        yield from frames

    def _read(self, frames: list[np.ndarray]) -> DistanceReading:
        path = self.reader_path or distance_reader_path()
        height, width = min(f.shape[0] for f in frames), min(f.shape[1] for f in frames)
        if min(height, width) < MIN_READ_SIDE:
            return self._default(
                f"frames of {width}x{height} pixels are too small to read the distance from (under {MIN_READ_SIDE} "
                f"a side)"
            )
        if not path.is_file():
            return self._default(f"no distance reader ({path} is absent)")
        reader, _ = load_reader(path)
        reading = read_distance(reader, frames, self.intr, self.camera_height, start=self.default)
        if reading.note:
            self.warnings.append(reading.note)
            print(f"{self.prog}: warning: {reading.note}", file=sys.stderr)
        return reading

    def _default(self, why: str) -> DistanceReading:
        """The default distance where none can be read, said with ``why``."""
        said = f"{why}: the default {self.default:.2f} m is used; pass --distance"
        self.warnings.append(said)
        print(f"{self.prog}: warning: {said}", file=sys.stderr)
        return DistanceReading(self.default, "default", note=said)
