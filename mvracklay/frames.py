"""Ordered frame sources for `mvracklay run` and `predict`: a WareSynth sequence, a folder of images (each
turned upright by its EXIF orientation), one image, or a video (its decoded frames counted against the
frames it announces: a cut file is warned about).

Every source is validated when opened (one-line `InputError` naming the file and the problem) and
streams its frames as uint8 RGB arrays ``(H, W, 3)``: nothing holds a whole video in memory; `every_nth`
keeps every N-th.
Camera intrinsics come from the sequence's meta.json, a ``--camera`` JSON file, or the default
camera (the generator's: 60 degree horizontal field of view, square pixels, principal point at the
image centre) scaled to the frame size. Where those intrinsics also give a lens's distortion
(OpenCV's k1, k2, p1, p2, k3; `layouts.lens`), the frames are undistorted as they stream.
"""

from __future__ import annotations

import itertools
import math
import os
import re
import sys
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image, ImageOps

from layouts import Intrinsics
from layouts.camera_record import camera_angles, check_camera_fits, lens_from_record
from layouts.canonical import FILL_RGB
from layouts.errors import InputError
from layouts.fileio import load_json
from layouts.images import rgb8
from layouts.lens import Lens, undistort_frame

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")
VIDEO_SUFFIXES = (".mp4", ".mov", ".avi", ".mkv", ".webm", ".m4v", ".mpg", ".mpeg", ".ts")
SINGLE_FRAME_HINT = (
    "one frame gives one view without the motion the map needs: the map holds one rack span, its scale "
    "from the camera-to-rack distance (read from the frame unless --distance or --camera-height gives it)"
)
_EXIF_ORIENTATION = 0x0112
_SWAPS_SIDES = (5, 6, 7, 8)
"""EXIF orientations whose upright image is the stored one turned by 90 degrees (width and height swap)."""


def natural_key(path: Path) -> list[Any]:
    """Sort key putting ``frame2.png`` before ``frame10.png``."""
    return [int(s) if s.isdigit() else s.lower() for s in re.split(r"(\d+)", path.name)]


def _orientation(im: Image.Image) -> int:
    """The EXIF orientation (1..8) a photo is stored with; 1 (upright) when it has none."""
    v = im.getexif().get(_EXIF_ORIENTATION, 1)
    return v if isinstance(v, int) and 1 <= v <= 8 else 1


def _image_size(path: Path) -> tuple[int, int]:
    """The upright image's size (a photo's EXIF orientation applied)."""
    return _upright_size(path)[:2]


def _upright_size(path: Path) -> tuple[int, int, int]:
    """``(width, height, EXIF orientation)`` of the upright image."""
    try:
        with Image.open(path) as im:
            w, h = im.size
            o = _orientation(im)
            return (h, w, o) if o in _SWAPS_SIDES else (w, h, o)
    except (OSError, ValueError, SyntaxError, Image.DecompressionBombError) as e:
        raise InputError(f"{path}: not a readable image ({type(e).__name__})") from None


def _read_rgb(path: Path, size: tuple[int, int]) -> np.ndarray:
    """The image upright (`PIL.ImageOps.exif_transpose` where its EXIF orientation says so) as RGB."""
    try:
        with Image.open(path) as im:
            upright = ImageOps.exif_transpose(im) if _orientation(im) != 1 else im
            if upright.size != size:
                w, h = upright.size
                raise InputError(f"{path}: {w}x{h} upright, but the first image is {size[0]}x{size[1]}")
            return rgb8(upright, path)  # 16-bit, palette, alpha: converted faithfully or refused
    except (OSError, ValueError, SyntaxError, Image.DecompressionBombError) as e:
        if isinstance(e, InputError):
            raise
        raise InputError(f"{path}: not a readable image ({type(e).__name__})") from None


@dataclass
class FrameSource:
    """An ordered, validated source of RGB frames.

    ``kind`` is ``sequence`` (WareSynth folder), ``images`` (a folder of images, or one image file) or
    ``video`` (``arrays``: frames in memory, `array_source`); ``num_frames`` is None when a video container does not say. ``intrinsics``, ``records``
    (per-frame camera records) and ``camera_angles`` are known only for a WareSynth sequence.
    What streaming finds worth saying (one frame only; a video that decodes fewer frames than it
    announces) is printed to stderr as ``PROG: warning: ...`` and kept in ``warnings``.
    """

    kind: str
    path: Path
    width: int
    height: int
    num_frames: int | None
    intrinsics: Intrinsics | None = None
    records: list[dict[str, Any]] | None = None
    #: the camera's recorded rotation (roll, pitch, yaw) in degrees: a WareSynth sequence's; None for footage
    camera_angles: tuple[float, float, float] | None = None
    #: the lens distortion meta.json's intrinsics give (a WareSynth sequence's; None: a pinhole camera)
    lens: Lens | None = None
    image_paths: list[Path] = field(default_factory=list, repr=False)
    #: frames a video's container announces (its frame count, else duration x rate; None: it does not say)
    announced: int | None = None
    #: whether ``announced`` is the container's own frame count (not estimated from the duration)
    announced_exact: bool = False
    #: the command the warnings are printed as coming from
    prog: str = "mvracklay"
    warnings: list[str] = field(default_factory=list)
    #: an ``arrays`` source's frames (any iterable; consumed once)
    arrays: Iterable[Any] | None = field(default=None, repr=False)

    def next_ready(self) -> bool:
        """Whether the next frame can be read without waiting for a camera: always, for files and arrays (a live
        stream's says whether its buffer holds one; the predictor overlaps frames only then)."""
        return True

    def warn(self, said: str) -> None:
        """Print ``said`` as one warning line on stderr and keep it in ``warnings``."""
        self.warnings.append(said)
        print(f"{self.prog}: warning: {said}", file=sys.stderr)

    def frames(
        self, max_frames: int | None = None, undistort: tuple[Intrinsics, Lens] | None = None
    ) -> Iterator[np.ndarray]:
        """Stream the frames in order (at most ``max_frames``); ``undistort=(intrinsics, lens)`` resamples
        each to the pinhole camera's image (`layouts.lens.undistort_frame`: frames wider than 640 px come
        shrunk to 640; unseen corners take the canonical fill colour)."""
        if self.num_frames == 1:
            self.warn(f"{self.path}: {SINGLE_FRAME_HINT}")
        for rgb in self._raw_frames(max_frames):
            yield rgb if undistort is None else undistort_frame(rgb, undistort[0], undistort[1], FILL_RGB)

    def _raw_frames(self, max_frames: int | None) -> Iterator[np.ndarray]:
        limit = max_frames if max_frames else None
        if self.kind == "video":
            yield from self._video_frames(limit)
            return
        if self.kind == "arrays":
            for n, a in enumerate(self.arrays or ()):
                if limit and n >= limit:
                    return
                yield _rgb_array(a, n, (self.width, self.height))
            return
        paths = self.image_paths[:limit] if limit else self.image_paths
        for p in paths:
            yield _read_rgb(p, (self.width, self.height))

    def _video_frames(self, limit: int | None) -> Iterator[np.ndarray]:
        """Decode the video one frame at a time; fewer frames than announced, or a decoding error after some,
        is warned about (the file looks cut), none at all refused."""
        import av

        container = _open_video(self.path)
        n, failed = 0, None
        try:
            stream = container.streams.video[0]
            stream.thread_type = "AUTO"
            try:
                for frame in container.decode(stream):
                    rgb = frame.to_ndarray(format="rgb24")
                    if (rgb.shape[1], rgb.shape[0]) != (self.width, self.height):
                        raise InputError(
                            f"{self.path}: frame {n} is {rgb.shape[1]}x{rgb.shape[0]}, "
                            f"the first frame {self.width}x{self.height}"
                        )
                    yield rgb
                    n += 1
                    if limit and n >= limit:
                        return
            except av.FFmpegError as e:
                if n == 0:
                    raise InputError(
                        f"{self.path}: video decoding failed at its first frame ({type(e).__name__})"
                    ) from None
                failed = type(e).__name__
        finally:
            container.close()
        self._check_decoded(n, failed)

    def _check_decoded(self, n: int, failed: str | None) -> None:
        """Warn when a video decoded to its end gave fewer frames than it announces (or stopped on an error)."""
        m = self.announced
        short = m is not None and n < m - (0 if self.announced_exact else max(1, round(0.02 * m)))
        if not short and failed is None:
            return
        said = f"decoded {n} of {m} frames announced by {self.path}" if m else f"decoded {n} frames of {self.path}"
        self.warn(said + ": the file looks cut" + (f" (decoding stopped: {failed})" if failed else ""))

    def frame_numbers(self) -> list[int] | None:
        """The input's frame numbers of the frames given out where frames were left out as they came (a live
        stream's); None when they are the input's in order (``every_nth`` says its own step)."""
        return None

    def frame_count(self, max_frames: int | None = None) -> int | None:
        """Frames that `frames` will yield (None when unknown before decoding)."""
        if self.num_frames is None:
            return None
        return min(self.num_frames, max_frames) if max_frames else self.num_frames

    def distance(self, index: int) -> float | None:
        """Camera-to-rack-front distance of a frame when the source records it."""
        if self.records and index < len(self.records):
            d = self.records[index].get("distance")
            if isinstance(d, (int, float)) and math.isfinite(d) and d > 0:
                return float(d)
        return None


def _image_folder(folder: Path, kind: str = "images") -> FrameSource:
    paths = sorted((p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES), key=natural_key)
    if not paths:
        raise InputError(f"{folder}: no images ({', '.join(IMAGE_SUFFIXES)}) found")
    w0, h0, o0 = _upright_size(paths[0])
    for p in paths[1:]:
        w, h, o = _upright_size(p)
        if (w, h) != (w0, h0):
            turned = " upright (after the photos' EXIF orientation)" if o != 1 or o0 != 1 else ""
            raise InputError(f"{p}: {w}x{h}{turned}, but the first image ({paths[0].name}) is {w0}x{h0}")
    size = (w0, h0)
    return FrameSource(kind, folder, size[0], size[1], len(paths), image_paths=paths)


def _sequence(folder: Path) -> FrameSource:
    meta_path = folder / "meta.json"
    meta = load_json(meta_path)
    from waresynth.meta_schema import check_meta

    check_meta(meta, str(meta_path))  # the declared schema (`waresynth.meta_schema`)
    src = _image_folder(folder / "rgb", "sequence")
    src.path = folder
    if "intrinsics" in meta:
        intr = Intrinsics.from_dict(meta["intrinsics"], str(meta_path))
        src.intrinsics = (
            intr if (intr.width, intr.height) == (src.width, src.height) else intr.scaled(src.width, src.height)
        )
        if isinstance(meta["intrinsics"], dict):
            src.lens = lens_from_record(meta["intrinsics"], str(meta_path))
    src.camera_angles = camera_angles(meta.get("camera"), str(meta_path))
    frames = meta.get("frames")
    if isinstance(frames, list) and all(isinstance(f, dict) for f in frames):
        src.records = frames
        expected = [folder / "rgb" / f"{i:06d}.png" for i in range(len(frames))]
        present = set(src.image_paths or [])
        missing = [p for p in expected if p not in present]
        if missing:
            more = f" (and {len(missing) - 1} more)" if len(missing) > 1 else ""
            raise InputError(f"{missing[0]}: missing, but {meta_path} records {len(frames)} frames{more}")
    return src


def _open_video(path: Path):
    import av

    try:
        container = av.open(str(path))
    except (av.FFmpegError, OSError, ValueError) as e:
        raise InputError(f"{path}: not a readable video ({type(e).__name__})") from None
    if not container.streams.video:
        container.close()
        raise InputError(f"{path}: holds no video stream")
    return container


def _video(path: Path) -> FrameSource:
    import av

    container = _open_video(path)
    try:
        stream = container.streams.video[0]
        try:
            first = next(container.decode(stream), None)
        except av.FFmpegError as e:
            raise InputError(f"{path}: not a decodable video ({type(e).__name__})") from None
        if first is None:
            raise InputError(f"{path}: the video holds no frames")
        n = int(stream.frames or 0) or None
        src = FrameSource("video", path, int(first.width), int(first.height), n)
        src.announced, src.announced_exact = (n, True) if n else (_frames_from_duration(container, stream), False)
        return src
    finally:
        container.close()


def _frames_from_duration(container: Any, stream: Any) -> int | None:
    """Frames a container announces through its duration x the stream's frame rate (None: it says neither)."""
    rate = stream.average_rate or stream.guessed_rate
    if stream.duration and stream.time_base:
        seconds = float(stream.duration * stream.time_base)
    elif container.duration:
        seconds = container.duration / 1_000_000  # AV_TIME_BASE
    else:
        return None
    if not rate:
        return None
    return round(seconds * float(rate)) or None


def open_source(path: str | os.PathLike, prog: str = "mvracklay") -> FrameSource:
    """Open INPUT: a WareSynth sequence folder (meta.json + rgb/), a folder of images, one image file, or a
    video file; ``prog`` names the command in the source's warnings."""
    p = Path(path)
    if p.is_dir():
        src = _sequence(p) if (p / "meta.json").is_file() and (p / "rgb").is_dir() else _image_folder(p)
    elif p.is_file():
        if p.suffix.lower() in IMAGE_SUFFIXES:
            w, h = _image_size(p)
            src = FrameSource("images", p, w, h, 1, image_paths=[p])
        else:
            src = _video(p)
    else:
        raise InputError(f"{p}: input not found (want a sequence folder, an image folder, an image or a video file)")
    src.prog = prog
    return src


def _rgb_array(a: Any, n: int, size: tuple[int, int] | None = None) -> np.ndarray:
    """Frame ``n`` of an in-memory source as uint8 ``(H, W, 3)`` (grey and RGBA taken; anything else refused)."""
    a = np.asarray(a)
    if a.ndim == 2:
        a = np.repeat(a[..., None], 3, axis=2)
    if a.ndim != 3 or a.shape[2] not in (3, 4) or a.dtype != np.uint8 or 0 in a.shape:
        raise InputError(f"frames[{n}]: want a uint8 array (H, W, 3), got {a.dtype} {a.shape}")
    if size is not None and (a.shape[1], a.shape[0]) != size:
        raise InputError(f"frames[{n}]: {a.shape[1]}x{a.shape[0]}, the first frame {size[0]}x{size[1]}")
    return np.ascontiguousarray(a[..., :3])


def first_frame(
    frames: Iterable[Any], intrinsics: Intrinsics | None
) -> tuple[np.ndarray, Iterator[Any], Intrinsics | None]:
    """The first of in-memory ``frames`` (checked, as uint8 RGB), an iterator over the rest, and ``intrinsics``
    checked against and scaled to its size; one line when ``frames`` is not an iterable of frames or is empty."""
    try:
        it = iter(frames)
    except TypeError:
        raise InputError(f"frames: want an iterable of uint8 (H, W, 3) arrays, got {type(frames).__name__}") from None
    first = next(it, None)
    if first is None:
        raise InputError("frames: no frames given")
    rgb = _rgb_array(first, 0)
    h, w = rgb.shape[:2]
    if intrinsics is not None:
        check_camera_fits(intrinsics, w, h, "camera")
        intrinsics = intrinsics if (intrinsics.width, intrinsics.height) == (w, h) else intrinsics.scaled(w, h)
    return rgb, it, intrinsics


def array_source(
    frames: Iterable[Any], intrinsics: Intrinsics | None = None, prog: str = "mvracklay.reconstruct"
) -> FrameSource:
    """Frames in memory (uint8 ``(H, W, 3)`` arrays, any iterable, streamed once) as a `FrameSource`."""
    if isinstance(frames, np.ndarray) and frames.ndim == 3 and frames.shape[-1] in (3, 4) and frames.dtype == np.uint8:
        frames = [frames]  # one image, not a stack of grey frames
    first, it, intrinsics = first_frame(frames, intrinsics)
    h, w = first.shape[:2]
    count = len(frames) if hasattr(frames, "__len__") else None
    return FrameSource(
        "arrays", Path("<frames>"), w, h, count, intrinsics=intrinsics, prog=prog, arrays=_chain(first, it)
    )


def _chain(first: np.ndarray, rest: Iterator[Any]) -> Iterator[Any]:
    yield first
    yield from rest


@dataclass
class _EveryNthVideo(FrameSource):
    """A video source yielding frames 0, N, 2N, ... (decoded all, kept every N-th)."""

    every: int = 1

    def _raw_frames(self, max_frames: int | None) -> Iterator[np.ndarray]:
        limit = (max_frames - 1) * self.every + 1 if max_frames else None
        yield from itertools.islice(super()._raw_frames(limit), 0, None, self.every)

    def frame_count(self, max_frames: int | None = None) -> int | None:
        if self.num_frames is None:
            return None
        n = -(-self.num_frames // self.every)
        return min(n, max_frames) if max_frames else n


def every_nth(source: FrameSource, every: int | str, option: str = "--every") -> FrameSource:
    """``source`` keeping frames 0, N, 2N, ... (``--every N``: video at 30 fps moves a few cm a frame, so a run may
    skip frames), numbered 0, 1, 2, ... (their layouts, stitching steps and map); ``source`` itself when ``every``
    is 1; one-line error unless N >= 1.
    A live source (`mvracklay.live_source`) thins itself as frames arrive (N, or ``auto``): it is returned as it is."""
    if source.kind == "live":
        return source
    if every == "auto":
        raise InputError(
            f"{option} auto keeps a live stream's frames a few cm apart; for a file give N (--every 3 on a 30 fps walk)"
        )
    if not isinstance(every, int) or isinstance(every, bool) or every < 1:
        raise InputError(f"{option} must be an integer >= 1, got {every!r}")
    if every == 1:
        return source
    if source.kind == "video":
        return _EveryNthVideo(**{f.name: getattr(source, f.name) for f in fields(source)}, every=every)
    paths = source.image_paths[::every]
    records = source.records[::every] if source.records is not None else None
    return replace(source, image_paths=paths, num_frames=len(paths), records=records)
