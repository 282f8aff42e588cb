"""Ordered frame sources for `mvracklay run` and `predict`: a WareSynth sequence, a folder of images (each
turned upright by its EXIF orientation), one image, or a video (its decoded frames counted against the
frames it announces: a cut file is warned about).

Every source is validated when opened (one-line `InputError` naming the file and the problem) and
streams its frames as uint8 RGB arrays ``(H, W, 3)``: nothing holds a whole video in memory.
Camera intrinsics come from the sequence's meta.json, a ``--camera`` JSON file, or the default
camera (the generator's: 60 degree horizontal field of view, square pixels, principal point at the
image centre) scaled to the frame size. Where those intrinsics also give a lens's distortion
(OpenCV's k1, k2, p1, p2, k3; `layouts.lens`), the frames are undistorted as they stream.
"""

from __future__ import annotations

import math
import os
import re
import sys
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image, ImageOps

from layouts import Intrinsics
from layouts.camera_record import camera_angles, camera_file_record, check_camera_fits, lens_from_record
from layouts.canonical import FILL_RGB
from layouts.errors import InputError
from layouts.fileio import load_json
from layouts.lens import Lens, undistort_frame
from waresynth.imageio import rgb8

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")
VIDEO_SUFFIXES = (".mp4", ".mov", ".avi", ".mkv", ".webm", ".m4v", ".mpg", ".mpeg", ".ts")
DEFAULT_HFOV_DEG = 60.0
"""Horizontal field of view of the default camera (the generator's default, waresynth/default_config.json)."""
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


def array_source(
    frames: Iterable[Any], intrinsics: Intrinsics | None = None, prog: str = "mvracklay.reconstruct"
) -> FrameSource:
    """Frames in memory (uint8 ``(H, W, 3)`` arrays, any iterable, streamed once) as a `FrameSource`."""
    if isinstance(frames, np.ndarray) and frames.ndim == 3 and frames.shape[-1] in (3, 4) and frames.dtype == np.uint8:
        frames = [frames]  # one image, not a stack of grey frames
    try:
        it = iter(frames)
    except TypeError:
        raise InputError(f"frames: want an iterable of uint8 (H, W, 3) arrays, got {type(frames).__name__}") from None
    first = next(it, None)
    if first is None:
        raise InputError("frames: no frames given")
    first = _rgb_array(first, 0)
    h, w = first.shape[:2]
    if intrinsics is not None:
        check_camera_fits(intrinsics, w, h, "camera")
        intrinsics = intrinsics if (intrinsics.width, intrinsics.height) == (w, h) else intrinsics.scaled(w, h)
    count = len(frames) if hasattr(frames, "__len__") else None
    return FrameSource(
        "arrays", Path("<frames>"), w, h, count, intrinsics=intrinsics, prog=prog, arrays=_chain(first, it)
    )


def _chain(first: np.ndarray, rest: Iterator[Any]) -> Iterator[Any]:
    yield first
    yield from rest


def default_intrinsics(width: int, height: int) -> Intrinsics:
    """The documented default camera at this frame size: 60 deg horizontal FOV, centred principal point."""
    return Intrinsics.from_fov(width, height, DEFAULT_HFOV_DEG)


def _camera_record(path: str | os.PathLike) -> dict[str, Any]:
    """A ``--camera`` file's keys, flat and checked (`layouts.camera_record.camera_file_record`)."""
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
    and height default to the frames'), the principal point inside the image and the frames' aspect ratio
    (`check_camera_fits`), scaled to the frame size."""
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
        return source.intrinsics, "given" if source.kind == "arrays" else f"{source.path / 'meta.json'}"
    return default_intrinsics(source.width, source.height), f"default ({DEFAULT_HFOV_DEG:g} deg horizontal FOV)"


def resolve_lens(source: FrameSource, camera: str | os.PathLike | None = None) -> Lens | None:
    """The lens to undistort the frames through: ``--camera``'s when given (None if it gives none), else the
    sequence's meta.json's."""
    return load_lens(camera) if camera is not None else source.lens


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
