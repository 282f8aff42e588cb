"""Training and evaluation inputs: windows of consecutive frames with their layouts.

Reads any sequence object with the `waresynth.dataset.Sequence` interface (``num_frames``,
``spec``, ``intrinsics``, ``rgb(i)``, ``frame(i)``, ``layouts(i)``, ``camera_positions()``),
warps images into the model's canonical view (`layouts.canonical.CanonicalView`, with the
sequence's intrinsics and each frame's camera-to-rack distance) and resamples ground truth to the
model's layout size (class-area mode). Each frame also gets its slot anchors (the canonical rows
of its slots' board edges) and the row head's target (a Gaussian bump at every visible board).
A window ending at frame t holds frames ``t-T+1 .. t``; before the sequence start the first
frame is repeated, as the reference implementation does. Augmentation is consistent over a
window: one colour jitter for all its frames and one horizontal flip of images, layouts,
visible columns and camera X together; anchors get a small jitter of their own; optionally
(``jpeg``) the window's frames pass through JPEG at one quality, as a compressing camera gives them.
"""

from __future__ import annotations

import io
import os
import re
from pathlib import Path
from typing import Any, Protocol

import numpy as np
import torch
import torch.nn.functional as F
from PIL import Image

from layouts import NUM_CLASSES, Intrinsics, LayoutSpec
from layouts.canonical import CanonicalView
from layouts.codecs import FrameLayouts
from layouts.errors import InputError
from network.preprocess import canonical_image, frame_camera, sequence_angles

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".webp")


#: width (standard deviation, canonical rows) of the row head's target bump at each board
ROW_SIGMA = 1.0
#: anchors used in training move uniformly by up to this many canonical rows (robustness to the row head)
ANCHOR_JITTER = 1.0


class SequenceLike(Protocol):
    name: str
    num_frames: int
    spec: LayoutSpec
    intrinsics: Intrinsics

    def rgb(self, i: int) -> np.ndarray: ...
    def frame(self, i: int) -> dict[str, Any]: ...
    def layouts(self, i: int) -> FrameLayouts: ...
    def camera_positions(self) -> np.ndarray: ...


def board_rows(seq: Any, i: int, view: CanonicalView, slots: int) -> tuple[np.ndarray, list[float]]:
    """Slot anchors ``(R,)`` (canonical rows of the slots' board edges, NaN = no slot) and every visible board's row."""
    rec = seq.frame(i)
    cam_y = float(rec["camera_position"][1])
    anchors = np.full(slots, np.nan, np.float32)
    for r, s in enumerate(rec.get("slots", [])[:slots]):
        anchors[r] = float(view.row_of(float(s["board_top_y"]) - cam_y))
    rows = [float(view.row_of(y - cam_y)) for y in _visible_board_ys(seq)]
    rows = rows or [float(a) for a in anchors if np.isfinite(a)]
    return anchors, rows


def _visible_board_ys(seq: Any) -> list[float]:
    """Board-top Y of every visible level (the sequence's ``visible_board_ys()``); [] if it has none."""
    fn = getattr(seq, "visible_board_ys", None)
    return [float(y) for y in fn()] if callable(fn) else []


def row_target(rows: list[float], height: int, sigma: float = ROW_SIGMA) -> np.ndarray:
    """float32 ``(height,)``: a Gaussian bump (peak 1) at each continuous canonical row in ``rows``."""
    centres = np.arange(height, dtype=np.float32) + 0.5
    t = np.zeros(height, np.float32)
    for r in rows:
        t = np.maximum(t, np.exp(-0.5 * ((centres - r) / sigma) ** 2))
    return t


def resize_image(rgb: np.ndarray, width: int, height: int) -> np.ndarray:
    """uint8 ``(H, W, 3)`` -> uint8 ``(height, width, 3)`` (antialiased bilinear)."""
    if rgb.ndim == 2:
        rgb = np.repeat(rgb[..., None], 3, axis=2)
    if rgb.ndim != 3 or rgb.shape[2] not in (3, 4):
        raise InputError(f"image must be (H, W, 3), got shape {rgb.shape}")
    rgb = np.ascontiguousarray(rgb[..., :3])
    if rgb.shape[:2] == (height, width):
        return rgb
    return np.asarray(Image.fromarray(rgb).resize((width, height), Image.BILINEAR))


def resample_layout(stack: np.ndarray, size: int) -> np.ndarray:
    """``(R, D, D)`` class ids -> ``(R, size, size)``: each target cell takes the class covering most of it.

    Ties go to the rarer class (box over shelf over background). Upsampling is nearest.
    """
    r, d, _ = stack.shape
    if d == size:
        return stack
    if d > size and d % size == 0:  # integer factor: count classes per block in numpy (fast)
        f = d // size
        blocks = stack.reshape(r, size, f, size, f)
        counts = np.stack([(blocks == c).sum((2, 4)) for c in range(NUM_CLASSES)], -1).astype(np.int32)
        return (counts * NUM_CLASSES + np.arange(NUM_CLASSES)).argmax(-1).astype(np.uint8)
    onehot = F.one_hot(torch.from_numpy(stack.astype(np.int64)), NUM_CLASSES).permute(0, 3, 1, 2).float()
    mode = "area" if size < d else "nearest"
    cover = F.interpolate(onehot, size=(size, size), mode=mode)
    cover += torch.arange(NUM_CLASSES, dtype=torch.float32).view(1, -1, 1, 1) * 1e-4
    return cover.argmax(1).numpy().astype(np.uint8)


def resample_columns(mask: np.ndarray, size: int) -> np.ndarray:
    """``(D,)`` bool per column -> ``(size,)``: a target column counts only if all it covers does.

    Upsampling is nearest.
    """
    d = mask.shape[0]
    if d == size:
        return mask
    m = torch.from_numpy(np.asarray(mask, np.float32)).view(1, 1, d)
    mode = "area" if size < d else "nearest"
    return (F.interpolate(m, size=size, mode=mode)[0, 0] >= 1 - 1e-6).numpy()


def check_spec_compatible(model_spec: LayoutSpec, data_spec: LayoutSpec, source: str) -> None:
    """Same slots and metric extents (the resolution may differ); else one-line error."""
    a = (model_spec.num_slots, model_spec.x_extent, model_spec.z_extent, model_spec.h_extent)
    b = (data_spec.num_slots, data_spec.x_extent, data_spec.z_extent, data_spec.h_extent)
    if not np.allclose(a, b):
        raise InputError(
            f"{source}: layout spec (R, x, z, h extents) {b} differs from the model's {a}; "
            "the model only predicts the layouts it was trained for"
        )


class WindowDataset(torch.utils.data.Dataset):
    """Windows of ``seq_len`` frames over sequences, as tensors ready for the model and losses.

    Item: ``images (T, 3, H, W)`` float, ``top``/``front`` ``(T, R, D, D)`` int64, ``visible``
    ``(T, D)`` bool, ``cam_x (T,)`` float metres, ``flipped`` bool.
    """

    def __init__(
        self,
        sequences: list[SequenceLike],
        *,
        seq_len: int,
        input_size: tuple[int, int],
        spec: LayoutSpec,
        augment: bool = False,
        seed: int = 0,
        max_stride: int = 1,
        jpeg: float = 0.0,
        jpeg_quality: tuple[int, int] = (30, 95),
    ) -> None:
        if not sequences:
            raise InputError("no sequences to read (is the split empty?)")
        self.sequences = sequences
        self.seq_len = seq_len
        self.width, self.height = input_size
        self.spec = spec
        self.view = CanonicalView(self.width, self.height, spec.x_extent)
        self.augment = augment
        self.seed = seed
        if not isinstance(max_stride, int) or max_stride < 1:
            raise InputError(f"max_stride must be a positive integer, got {max_stride!r}")
        self.max_stride = max_stride  #: with augment, windows skip up to max_stride - 1 frames between theirs
        check_jpeg(jpeg, jpeg_quality)
        lo, hi = jpeg_quality
        #: with augment, the share of windows whose frames pass through JPEG (one quality per window, drawn
        #: from ``jpeg_quality``) before the canonical warp, as a compressing camera or a video file gives them
        self.jpeg = float(jpeg)
        self.jpeg_quality = (lo, hi)
        self.epoch = 0
        self.index: list[tuple[int, int]] = []
        self._cam_x: list[np.ndarray] = []
        for si, seq in enumerate(sequences):
            check_spec_compatible(spec, seq.spec, str(getattr(seq, "root", seq.name)))
            pos = np.asarray(seq.camera_positions(), dtype=np.float64)
            if pos.shape != (seq.num_frames, 3):
                raise InputError(f"{seq.name}: camera positions have shape {pos.shape}, want ({seq.num_frames}, 3)")
            self._cam_x.append(pos[:, 0])
            self.index.extend((si, t) for t in range(seq.num_frames))

    def set_epoch(self, epoch: int) -> None:
        """Vary the augmentation per epoch while keeping runs reproducible."""
        self.epoch = epoch

    def __len__(self) -> int:
        return len(self.index)

    def frame_ids(self, t: int, stride: int = 1) -> list[int]:
        """The window ending at frame ``t``, frames ``stride`` apart (the first repeated at a sequence start)."""
        n = self.seq_len
        return [max(0, t - (n - 1 - k) * stride) for k in range(n)]

    def _frame(self, seq: SequenceLike, i: int, quality: int | None = None) -> dict[str, np.ndarray]:
        intr, dist = frame_camera(seq, i)
        rgb = seq.rgb(i) if quality is None else jpeg_round_trip(seq.rgb(i), quality)
        # a rotated camera is levelled by its recorded rotation: the layouts are the level camera's
        img = canonical_image(rgb, self.view, intr, dist, *sequence_angles(seq))
        lay = seq.layouts(i)
        d = self.spec.size
        anchors, rows = board_rows(seq, i, self.view, self.spec.num_slots)
        return {
            "images": img,
            "top": resample_layout(lay.top, d),
            "front": resample_layout(lay.front, d),
            "visible": np.ones(d, bool) if lay.visible is None else resample_columns(lay.visible, d),
            "anchors": anchors,
            "rows": row_target(rows, self.height),
        }

    def __getitem__(self, idx: int) -> dict[str, Any]:
        si, t = self.index[idx]
        seq = self.sequences[si]
        rng = np.random.default_rng([self.seed, self.epoch, idx]) if self.augment else None
        multi = rng is not None and self.max_stride > 1 and self.seq_len > 1
        stride = int(rng.integers(1, self.max_stride + 1)) if multi else 1
        ids = self.frame_ids(t, stride)
        quality = self._jpeg_quality(idx)
        frames = [self._frame(seq, i, quality) for i in ids]
        st = {k: np.stack([f[k] for f in frames]) for k in frames[0]}
        imgs = st["images"].astype(np.float32)
        top, front, vis, anchors = st["top"], st["front"], st["visible"], st["anchors"]
        cam_x = self._cam_x[si][ids].astype(np.float32)
        flipped = False
        if rng is not None:
            imgs = colour_jitter(imgs, rng)
            if rng.random() < 0.5:
                flipped = True
                imgs = imgs[:, :, ::-1]
                top, front, vis = top[..., ::-1], front[..., ::-1], vis[:, ::-1]
                cam_x = -cam_x
            anchors = anchors + rng.uniform(-ANCHOR_JITTER, ANCHOR_JITTER, size=anchors.shape).astype(np.float32)
        images = torch.from_numpy(np.ascontiguousarray(imgs)).div_(255.0).permute(0, 3, 1, 2).contiguous()
        return {
            "images": images,
            "top": torch.from_numpy(np.ascontiguousarray(top).astype(np.int64)),
            "front": torch.from_numpy(np.ascontiguousarray(front).astype(np.int64)),
            "visible": torch.from_numpy(np.ascontiguousarray(vis)),
            "cam_x": torch.from_numpy(np.ascontiguousarray(cam_x)),
            "anchors": torch.from_numpy(np.ascontiguousarray(anchors, dtype=np.float32)),
            "rows": torch.from_numpy(np.ascontiguousarray(st["rows"])),
            "flipped": flipped,
        }

    def _jpeg_quality(self, idx: int) -> int | None:
        """The JPEG quality item ``idx``'s frames go through this epoch, or None (no compression).

        Drawn from a stream of its own, so the windows, strides, jitter and flips are those of a run
        without it (same seed)."""
        if not self.augment or self.jpeg <= 0.0:
            return None
        return draw_jpeg_quality(np.random.default_rng([self.seed, self.epoch, idx, 1]), self.jpeg, self.jpeg_quality)


def jpeg_round_trip(rgb: np.ndarray, quality: int) -> np.ndarray:
    """``rgb`` (uint8 H x W x 3) as a baseline JPEG of ``quality`` (Pillow, 4:2:0 chroma) decodes it."""
    buf = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(rgb, dtype=np.uint8)).save(buf, format="JPEG", quality=quality, subsampling=2)
    buf.seek(0)
    with Image.open(buf) as im:
        return np.asarray(im.convert("RGB"))


def check_jpeg(share: float, quality: tuple[int, int], flags: tuple[str, str] = ("jpeg", "jpeg_quality")) -> None:
    """One line naming ``flags`` unless ``share`` is a probability and ``quality`` a range 1 <= LOW <= HIGH <= 95."""
    if not (isinstance(share, (int, float)) and 0.0 <= share <= 1.0):  # NaN and infinities fail the range too
        raise InputError(f"{flags[0]} must be a probability in [0, 1], got {share!r}")
    try:
        lo, hi = quality
    except (TypeError, ValueError):
        lo, hi = None, None  # not a pair: refused below with what was given
    if not (isinstance(lo, int) and isinstance(hi, int) and 1 <= lo <= hi <= 95):
        raise InputError(f"{flags[1]} needs two integers 1 <= LOW <= HIGH <= 95, got {quality!r}")


class CompressedSequence:
    """A sequence whose frames come through JPEG at one ``quality``, as a compressing camera delivers them;
    everything else (ground truth, cameras, files) is the wrapped sequence's."""

    def __init__(self, seq: Any, quality: int) -> None:
        self._seq = seq
        self.jpeg_quality = int(quality)

    def rgb(self, i: int) -> np.ndarray:
        return jpeg_round_trip(self._seq.rgb(i), self.jpeg_quality)

    def __getattr__(self, name: str) -> Any:
        if name == "_seq":  # not set yet (copy / unpickle): no recursion
            raise AttributeError(name)
        return getattr(self._seq, name)


def compress_share(seqs: list[Any], share: float, quality: tuple[int, int], seed: int) -> list[Any]:
    """``seqs`` with a share ``share`` of them wrapped in `CompressedSequence`, each at one quality from
    ``quality`` (LOW..HIGH): what the depth-head fits see with ``--jpeg``. Sequence k draws from its own
    stream ``[seed, k, 1]``, so the draws do not depend on how many sequences follow."""
    check_jpeg(share, quality)
    if share <= 0.0:
        return list(seqs)
    out: list[Any] = []
    for k, seq in enumerate(seqs):
        q = draw_jpeg_quality(np.random.default_rng([seed, k, 1]), share, quality)
        out.append(seq if q is None else CompressedSequence(seq, q))
    return out


def draw_jpeg_quality(rng: np.random.Generator, share: float, quality: tuple[int, int]) -> int | None:
    """With probability ``share`` a JPEG quality from ``quality`` (LOW..HIGH), else None: one item's draw
    (a training window's, a fit's sequence's), from a stream of its own."""
    if rng.random() >= share:
        return None
    return int(rng.integers(quality[0], quality[1] + 1))


def colour_jitter(imgs: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """One random brightness / contrast / saturation / channel-gain change for all frames (float 0..255)."""
    b = rng.uniform(0.7, 1.3)
    c = rng.uniform(0.7, 1.3)
    s = rng.uniform(0.6, 1.4)
    gain = rng.uniform(0.9, 1.1, size=3).astype(np.float32)
    x = imgs * b
    mean = x.mean(axis=(1, 2, 3), keepdims=True)
    x = (x - mean) * c + mean
    grey = x.mean(axis=3, keepdims=True)
    x = (x - grey) * s + grey
    x = x * gain
    return np.clip(x, 0.0, 255.0).astype(np.float32)


class ImageFolderSequence:
    """Any folder of images, in natural name order, as a sequence without ground truth."""

    def __init__(self, folder: str | os.PathLike) -> None:
        self.root = Path(folder)
        if not self.root.is_dir():
            raise InputError(f"{self.root}: image folder not found")
        key = lambda p: [int(s) if s.isdigit() else s for s in re.split(r"(\d+)", p.name)]  # noqa: E731
        self.paths = sorted((p for p in self.root.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES), key=key)
        if not self.paths:
            raise InputError(f"{self.root}: no images ({', '.join(IMAGE_SUFFIXES)}) found")
        self.name = self.root.name
        self.num_frames = len(self.paths)

    def rgb(self, i: int) -> np.ndarray:
        p = self.paths[i]
        try:
            with Image.open(p) as im:
                from layouts.images import rgb8  # 16-bit, palette, alpha: converted faithfully or refused

                return rgb8(im, p)
        except (OSError, ValueError) as e:
            if isinstance(e, InputError):
                raise
            raise InputError(f"{p}: not a readable image ({e})") from None

    def image_size(self) -> tuple[int, int]:
        h, w = self.rgb(0).shape[:2]
        return w, h
