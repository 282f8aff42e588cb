"""Lens distortion: the Brown-Conrady model (OpenCV's k1, k2, p1, p2, k3) and images resampled through it.

Everything else in the toolkit takes a pinhole camera (`layouts.Intrinsics`). Footage from a real lens
bends straight edges (boards, uprights) by a few pixels toward the image's corners; `undistort_image`
resamples such a frame to the pinhole image of the same intrinsics, and `distort_image` does the
reverse (a rendered frame as a lens would have shown it, for measuring what distortion costs).

Coordinates are normalised: ``x = (u - cx) / fx``, ``y = (v - cy) / fy`` with ``u, v`` continuous pixel
coordinates (pixel centres at k + 0.5, as everywhere in the toolkit).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from functools import lru_cache
from typing import Any

import numpy as np
from PIL import Image

from layouts.camera import Intrinsics
from layouts.errors import LayoutError

LENS_KEYS = ("k1", "k2", "p1", "p2", "k3")
_LIMIT = 2.0
"""Largest magnitude accepted for a coefficient (OpenCV calibrations of ordinary lenses stay well inside)."""
FRAME_MAX_WIDTH = 640
"""`undistort_frame` shrinks wider frames to this first: the canonical view (at most 256 px) and the
angle reading (at most 320 px) need no more, and the resampling costs per output pixel."""
_TILE = 16
"""Output tile side (pixels) over which the resampling map is taken as bilinear (error far below a pixel)."""


@dataclass(frozen=True)
class Lens:
    """Radial (k1, k2, k3) and tangential (p1, p2) distortion, OpenCV's convention and order."""

    k1: float = 0.0
    k2: float = 0.0
    p1: float = 0.0
    p2: float = 0.0
    k3: float = 0.0

    def __post_init__(self) -> None:
        for name in LENS_KEYS:
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float, np.floating, np.integer)) or not math.isfinite(v):
                raise LayoutError(f"lens {name} must be a finite number, got {v!r}")
            if abs(v) > _LIMIT:
                raise LayoutError(f"lens {name} = {v} is beyond +-{_LIMIT:g}: not an OpenCV-style coefficient")
            object.__setattr__(self, name, float(v))

    @classmethod
    def from_dict(cls, d: dict[str, Any], where: str = "lens") -> Lens | None:
        """The lens of a camera record holding any of k1, k2, p1, p2, k3 (None when it holds none)."""
        if not any(k in d for k in LENS_KEYS):
            return None
        try:
            return cls(**{k: d.get(k, 0.0) for k in LENS_KEYS})
        except LayoutError as e:
            raise LayoutError(f"{where}: {e}") from None

    def to_dict(self) -> dict[str, float]:
        return asdict(self)

    @property
    def is_pinhole(self) -> bool:
        return not any(getattr(self, k) for k in LENS_KEYS)

    def _terms(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The radial factor and the tangential offsets at normalised pinhole coordinates ``x, y``."""
        r2 = x * x + y * y
        radial = 1.0 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3))
        dx = 2.0 * self.p1 * x * y + self.p2 * (r2 + 2.0 * x * x)
        dy = self.p1 * (r2 + 2.0 * y * y) + 2.0 * self.p2 * x * y
        return radial, dx, dy

    def distort(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Normalised pinhole coordinates -> where the lens images them (normalised)."""
        radial, dx, dy = self._terms(x, y)
        return x * radial + dx, y * radial + dy

    def undistort(self, xd: np.ndarray, yd: np.ndarray, iterations: int = 20) -> tuple[np.ndarray, np.ndarray]:
        """The inverse of `distort` by fixed-point iteration (OpenCV's method; converges for ordinary lenses)."""
        x, y = np.array(xd, dtype=np.float64), np.array(yd, dtype=np.float64)
        for _ in range(iterations):
            radial, dx, dy = self._terms(x, y)
            x, y = (xd - dx) / radial, (yd - dy) / radial
        return x, y


def _tile_corners(intr: Intrinsics) -> tuple[np.ndarray, np.ndarray, list[tuple[int, int, int, int]]]:
    """Output tile boxes and the continuous pixel coordinates of every tile-grid node."""
    xs = np.unique(np.r_[np.arange(0, intr.width, _TILE), intr.width]).astype(np.float64)
    ys = np.unique(np.r_[np.arange(0, intr.height, _TILE), intr.height]).astype(np.float64)
    boxes = [(int(x0), int(y0), int(x1), int(y1)) for y0, y1 in zip(ys[:-1], ys[1:]) for x0, x1 in zip(xs[:-1], xs[1:])]
    return xs, ys, boxes


@lru_cache(maxsize=8)
def _mesh(
    src: Intrinsics, out: Intrinsics, lens: Lens, to_pinhole: bool
) -> list[tuple[tuple[int, int, int, int], tuple]]:
    """PIL MESH data: each tile of ``out``'s image and the quad of ``src``'s image its corners sample
    (NW, SW, SE, NE)."""
    xs, ys, boxes = _tile_corners(out)
    # PIL evaluates a tile's quad at output pixel (i, j) itself and samples the source at continuous
    # coordinates, so the node at X carries the source point of output position X + 0.5 (pixel centres)
    gx, gy = np.meshgrid((xs + 0.5 - out.cx) / out.fx, (ys + 0.5 - out.cy) / out.fy)
    # a pinhole output pixel samples the lens's image where the lens put it; a lens pixel, the reverse
    sx, sy = lens.distort(gx, gy) if to_pinhole else lens.undistort(gx, gy)
    su, sv = sx * src.fx + src.cx, sy * src.fy + src.cy
    col = {int(x): i for i, x in enumerate(xs)}
    row = {int(y): j for j, y in enumerate(ys)}
    mesh = []
    for x0, y0, x1, y1 in boxes:
        i0, i1, j0, j1 = col[x0], col[x1], row[y0], row[y1]
        quad = tuple(float(c) for j, i in ((j0, i0), (j1, i0), (j1, i1), (j0, i1)) for c in (su[j, i], sv[j, i]))
        mesh.append(((x0, y0, x1, y1), quad))
    return mesh


def _resample(
    rgb: np.ndarray, intr: Intrinsics, lens: Lens, to_pinhole: bool, fill: tuple[int, int, int], out: Intrinsics | None
) -> np.ndarray:
    rgb = np.asarray(rgb)
    if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8:
        raise LayoutError(f"image must be uint8 (H, W, 3), got {rgb.dtype} {rgb.shape}")
    if rgb.shape[:2] != (intr.height, intr.width):
        intr = intr.scaled(rgb.shape[1], rgb.shape[0])
    out = intr if out is None else out
    if lens.is_pinhole and out == intr:
        return rgb
    img = Image.fromarray(rgb).transform(
        (out.width, out.height), Image.MESH, _mesh(intr, out, lens, to_pinhole), resample=Image.BILINEAR, fillcolor=fill
    )
    return np.asarray(img)


def undistort_image(
    rgb: np.ndarray, intr: Intrinsics, lens: Lens, fill: tuple[int, int, int] = (0, 0, 0)
) -> np.ndarray:
    """A frame from a lens with these intrinsics -> the pinhole camera's image (same size and intrinsics).

    Bilinear; pinhole pixels the lens did not see (the corners, for a pincushion lens) take ``fill``.
    """
    return _resample(rgb, intr, lens, True, fill, None)


def distort_image(
    rgb: np.ndarray,
    intr: Intrinsics,
    lens: Lens,
    fill: tuple[int, int, int] = (0, 0, 0),
    out: Intrinsics | None = None,
) -> np.ndarray:
    """A pinhole image of camera ``intr`` -> as a lens with intrinsics ``out`` (default ``intr``) at the same
    pose shows it; pixels beyond the pinhole image take ``fill``."""
    return _resample(rgb, intr, lens, False, fill, out)


def covering_intrinsics(intr: Intrinsics, lens: Lens) -> Intrinsics:
    """``intr`` with both focal lengths scaled by the least factor >= 1 for which every pixel of the lens's
    image falls inside pinhole camera ``intr``'s image (a barrel lens sees wider than its pinhole: without
    the zoom, `distort_image` leaves its border unfilled)."""

    def fits(s: float) -> bool:
        out = Intrinsics(intr.fx * s, intr.fy * s, intr.cx, intr.cy, intr.width, intr.height)
        u = np.r_[
            np.linspace(0, out.width, 257), np.zeros(257), np.full(257, out.width), np.linspace(0, out.width, 257)
        ]
        v = np.r_[
            np.zeros(257), np.linspace(0, out.height, 257), np.linspace(0, out.height, 257), np.full(257, out.height)
        ]
        x, y = lens.undistort((u - out.cx) / out.fx, (v - out.cy) / out.fy)
        su, sv = x * intr.fx + intr.cx, y * intr.fy + intr.cy
        return bool(np.all((su >= 0) & (su <= intr.width) & (sv >= 0) & (sv <= intr.height)))

    if fits(1.0):
        return intr
    lo, hi = 1.0, 1.0
    while not fits(hi):
        lo, hi = hi, hi * 1.25
        if hi > 4.0:
            raise LayoutError(f"lens {lens.to_dict()}: sees more than 4x the pinhole image; not an ordinary lens")
    for _ in range(30):
        mid = 0.5 * (lo + hi)
        lo, hi = (lo, mid) if fits(mid) else (mid, hi)
    s = hi
    return Intrinsics(intr.fx * s, intr.fy * s, intr.cx, intr.cy, intr.width, intr.height)


def undistort_frame(
    rgb: np.ndarray, intr: Intrinsics, lens: Lens, fill: tuple[int, int, int], max_width: int = FRAME_MAX_WIDTH
) -> np.ndarray:
    """`undistort_image` for the pipeline: a frame wider than ``max_width`` is first shrunk to it (antialiased,
    aspect kept), so the result may be smaller than the frame; its intrinsics are ``intr`` scaled to it, as
    every consumer derives them (`Intrinsics.scaled`)."""
    rgb = np.asarray(rgb)
    if rgb.ndim == 3 and rgb.shape[1] > max_width:
        h = max(1, round(rgb.shape[0] * max_width / rgb.shape[1]))
        rgb = np.asarray(Image.fromarray(rgb).resize((max_width, h), Image.BILINEAR, reducing_gap=None))
    return undistort_image(rgb, intr, lens, fill)
