"""The camera's roll read from the images, so footage from an askew camera is levelled before the network.

The network is trained on a level camera (the generator's camera never rolls), and a small roll
costs a lot: on the held-out 128x128 scenes, 2 degrees take 5.3 points of top rack mIoU and 7.2
of top box, 5 degrees 24 and 30 (docs/network.md, *A rolled or pitched camera*). A rack row is full of
straight edges that are horizontal or vertical in a level image (the boards' fronts, the
uprights, the boxes' front faces), so the roll is the angle that turns the image's strong edges
back onto the axes.

`estimate_roll` reads one image: the magnitude-weighted histogram of its gradient orientations,
folded modulo 90 degrees (horizontal and vertical edges vote together), smoothed, and its peak
within ``max_deg``. Edges resampled at a slant bias their gradients toward the pixel axes
(~10 % of the angle), so the image is levelled by the first reading and read again: the
second reading is the residual, and the two add up (0.3 degrees or better on 95 % of the
held-out frames at 256x256).

`RollLeveller` carries a roll over a sequence: each frame is read after levelling it by the
roll so far (that levelling is the second reading's), and the readings are averaged with
weights decaying over ``tau`` frames, so a camera whose roll drifts slowly is followed and one
frame with few edges cannot tip it.
"""

from __future__ import annotations

import argparse
import math

import numpy as np
from PIL import Image
from scipy import ndimage

from layouts import Intrinsics
from layouts.canonical import FILL_RGB, MAX_ROLL_DEG
from layouts.errors import InputError

#: the largest roll `estimate_roll` looks for by default (degrees)
SEARCH_DEG = 15.0
#: frames over which `RollLeveller` averages its readings (weights exp(-frames ago / TAU))
TAU = 10.0
#: images are read at most this many pixels wide (angles do not depend on the scale)
READ_WIDTH = 320
_BIN_DEG = 0.1
_SMOOTH_DEG = 0.5
_STRONG_QUANTILE = 80.0


def tilt_frame(rgb: np.ndarray, intr: Intrinsics, pitch_deg: float = 0.0, yaw_deg: float = 0.0) -> np.ndarray:
    """``rgb`` (a level camera ``intr``'s) as the same camera tilted up ``pitch_deg`` / turned right ``yaw_deg`` shows it.

    A pure rotation, so one homography ``K R K^-1`` from the tilted camera's pixels to the level
    one's (``R = Ry(yaw) Rx(pitch)``); the uncovered parts take the canonical fill colour. For
    robustness checks (`benchmarks/roll_robustness.py --axis`).
    """
    t, y = math.radians(float(pitch_deg)), math.radians(float(yaw_deg))
    k = np.array([[intr.fx, 0.0, intr.cx], [0.0, intr.fy, intr.cy], [0.0, 0.0, 1.0]])
    rx = np.array([[1.0, 0.0, 0.0], [0.0, math.cos(t), -math.sin(t)], [0.0, math.sin(t), math.cos(t)]])
    ry = np.array([[math.cos(y), 0.0, math.sin(y)], [0.0, 1.0, 0.0], [-math.sin(y), 0.0, math.cos(y)]])
    h = k @ ry @ rx @ np.linalg.inv(k)
    coeffs = tuple(float(c) for c in (h / h[2, 2]).ravel()[:8])
    size = (rgb.shape[1], rgb.shape[0])
    im = Image.fromarray(np.ascontiguousarray(rgb)).transform(
        size, Image.PERSPECTIVE, coeffs, resample=Image.BILINEAR, fillcolor=FILL_RGB
    )
    return np.asarray(im)


def turn_frame(rgb: np.ndarray, roll_deg: float, cx: float, cy: float) -> np.ndarray:
    """``rgb`` as a camera rolled ``roll_deg`` would show it: turned counter-clockwise about ``(cx, cy)``.

    The corners the turn uncovers take the canonical fill colour (a real camera would see more of
    the scene there). For robustness checks of the levelling (`benchmarks/roll_robustness.py`).
    """
    im = Image.fromarray(np.ascontiguousarray(rgb)).rotate(
        float(roll_deg), resample=Image.BILINEAR, center=(float(cx), float(cy)), fillcolor=FILL_RGB
    )
    return np.asarray(im)


def _degrees(value: object, name: str, want: str) -> float:
    """``value`` (a number or its text) as a float within +-MAX_ROLL_DEG; else an InputError naming ``name``."""
    if isinstance(value, str):
        try:
            value = float(value)
        except ValueError:
            raise InputError(f"{name} must be {want}, got {value!r}") from None
    if isinstance(value, bool) or not isinstance(value, (int, float, np.floating)):
        raise InputError(f"{name} must be {want}, got {value!r}")
    if not (math.isfinite(value) and abs(value) <= MAX_ROLL_DEG):
        raise InputError(f"{name} must be within +-{MAX_ROLL_DEG:g} degrees, got {value!r}")
    return float(value)


def check_pitch(pitch: object, name: str = "pitch") -> float:
    """A known camera pitch (degrees, optical axis tilted up > 0) as a float; else an InputError naming ``name``."""
    return _degrees(pitch, name, "a number of degrees")


def check_roll(roll: object, name: str = "roll") -> float | str | None:
    """``None`` / ``"auto"`` / a finite number of degrees within +-MAX_ROLL_DEG (as a float); else an InputError."""
    if roll is None or roll == "auto":
        return roll  # type: ignore[return-value]
    return _degrees(roll, name, "'auto' or a number of degrees")


def _grey(rgb: np.ndarray) -> np.ndarray:
    """uint8 ``(H, W, 3)`` (or ``(H, W)``) -> float32 grey, at most READ_WIDTH wide."""
    rgb = np.asarray(rgb)
    if rgb.dtype != np.uint8 or rgb.ndim not in (2, 3) or (rgb.ndim == 3 and rgb.shape[2] not in (3, 4)):
        raise InputError(f"image must be uint8 (H, W, 3), got {rgb.dtype} {rgb.shape}")
    if rgb.ndim == 3:
        rgb = rgb[..., :3]
    img = Image.fromarray(np.ascontiguousarray(rgb)).convert("L")
    if img.width > READ_WIDTH:
        img = img.resize((READ_WIDTH, max(1, round(img.height * READ_WIDTH / img.width))), Image.BILINEAR)
    return np.asarray(img, np.float32)


def _read(grey: np.ndarray, valid: np.ndarray, max_deg: float) -> tuple[float, float]:
    """One reading: (roll in degrees, peak strength over the histogram's mean; 0 = nothing to read)."""
    g = ndimage.gaussian_filter(grey, 1.0)
    gx, gy = ndimage.sobel(g, 1), ndimage.sobel(g, 0)
    mag = np.hypot(gx, gy)[valid]
    if mag.size < 16 or not mag.max() > 0:
        return 0.0, 0.0
    strong = mag >= np.percentile(mag, _STRONG_QUANTILE)
    mag = mag[strong]
    # folded orientation in [-45, 45): 0 for a horizontal or vertical edge
    a = (np.degrees(np.arctan2(gy[valid][strong], gx[valid][strong])) + 45.0) % 90.0 - 45.0
    nb = round(90.0 / _BIN_DEG)
    hist, edges = np.histogram(a, bins=nb, range=(-45.0, 45.0), weights=mag)
    hist = ndimage.gaussian_filter1d(hist, _SMOOTH_DEG / _BIN_DEG, mode="wrap")
    centres = 0.5 * (edges[:-1] + edges[1:])
    inside = np.flatnonzero(np.abs(centres) <= max_deg)
    k = int(inside[np.argmax(hist[inside])])
    y0, y1, y2 = hist[(k - 1) % nb], hist[k], hist[(k + 1) % nb]
    den = y0 - 2.0 * y1 + y2
    peak = centres[k] + (0.5 * (y0 - y2) / den * _BIN_DEG if den < 0 else 0.0)
    strength = float(y1 / max(hist.mean(), 1e-12))
    # gradients (image y down) turn clockwise when the content turns counter-clockwise as displayed
    return -float(peak), strength


def _turned(grey: np.ndarray, roll_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """``grey`` levelled by ``roll_deg`` about its centre, and the mask of pixels that came from inside it."""
    img = Image.fromarray(grey)
    levelled = np.asarray(img.rotate(-roll_deg, resample=Image.BILINEAR), np.float32)
    inside = np.asarray(Image.fromarray(np.full(grey.shape, 255, np.uint8)).rotate(-roll_deg), bool)
    return levelled, ndimage.binary_erosion(inside, iterations=3)


def estimate_roll(rgb: np.ndarray, max_deg: float = SEARCH_DEG, prior_deg: float = 0.0) -> tuple[float, float]:
    """The roll of one uint8 RGB image (degrees, content turned counter-clockwise as displayed) and its strength.

    ``prior_deg``: a roll already known roughly (the sequence's so far): the image is levelled by it
    and read once (the residual), instead of read, levelled and read again. The strength is the
    histogram's peak over its mean (1 = no preferred orientation; rack images give ~5-20).
    The rotation is about the image centre; a principal point off the centre moves the image,
    not the edges' angles.
    """
    if not (isinstance(max_deg, (int, float)) and 0 < max_deg < 45):
        raise InputError(f"max_deg must be a number of degrees in (0, 45), got {max_deg!r}")
    grey = _grey(rgb)
    roll = float(prior_deg)
    if roll == 0.0:
        valid = np.ones(grey.shape, bool)
        valid[:2], valid[-2:], valid[:, :2], valid[:, -2:] = False, False, False, False
        roll, _ = _read(grey, valid, max_deg)
    levelled, valid = _turned(grey, roll)
    residual, strength = _read(levelled, valid, max_deg)
    return float(np.clip(roll + residual, -max_deg, max_deg)), strength


class RollLeveller:
    """The roll for each frame of a sequence: known (a number of degrees) or read from the images (``"auto"``).

    ``roll(i, rgb)`` returns frame ``i``'s roll in degrees; with ``"auto"`` each new frame is read
    (levelled by the roll so far first) and the readings are averaged with weights
    ``strength * exp(-frames ago / tau)``. Asking again for the last frame returns its roll
    without reading it twice. ``rolls`` lists the rolls given, frame by frame.
    """

    def __init__(self, roll: float | str, tau: float = TAU, max_deg: float = SEARCH_DEG) -> None:
        roll = check_roll(roll)
        if roll is None:
            raise InputError("roll must be 'auto' or a number of degrees, got None")
        if not (isinstance(tau, (int, float)) and math.isfinite(tau) and tau > 0):
            raise InputError(f"tau must be a positive number of frames, got {tau!r}")
        self.auto = roll == "auto"
        self.fixed = 0.0 if self.auto else float(roll)
        self.decay = math.exp(-1.0 / tau)
        self.max_deg = max_deg
        self._sum = 0.0
        self._weight = 0.0
        self._last: tuple[int, float] | None = None
        self.rolls: list[float] = []

    @property
    def current(self) -> float:
        """The roll so far (degrees; 0 before any reading)."""
        return self._sum / self._weight if self._weight > 0 else self.fixed

    def roll(self, i: int, rgb: np.ndarray) -> float:
        if self._last is not None and self._last[0] == i:
            return self._last[1]
        if self.auto:
            reading, strength = estimate_roll(rgb, self.max_deg, prior_deg=self.current)
            self._sum = self.decay * self._sum + strength * reading
            self._weight = self.decay * self._weight + strength
        r = self.current
        self._last = (i, r)
        self.rolls.append(r)
        return r


ROLL_HELP = (
    "the camera's roll about its optical axis, levelled before the network: 'auto' reads it from the frames "
    "(the edges of boards, uprights and boxes), a number gives it in degrees (the image turned counter-clockwise), "
    "0 takes the camera as level. Default: 0 for a generated sequence (its camera is level), auto for other footage"
)


PITCH_HELP = (
    "the camera's known pitch in degrees (optical axis tilted up > 0, down < 0; e.g. from its mount or an IMU), "
    "levelled before the network; not read from the frames. Default 0"
)


def add_roll_option(p: argparse.ArgumentParser, prefix: str = "") -> None:
    """``--roll auto|DEG`` (None unless given: `resolve_roll` picks the source's default) and ``--pitch DEG``."""
    p.add_argument("--roll", default=None, metavar="auto|DEG", help=prefix + ROLL_HELP)
    p.add_argument("--pitch", default=0.0, metavar="DEG", help=prefix + PITCH_HELP)


def resolve_roll(roll: object, level: bool, name: str = "--roll") -> float | str:
    """The roll to use: ``roll`` if given, else 0 for a source whose camera is known to be ``level``, else "auto"."""
    roll = check_roll(roll, name)
    if roll is None:
        return 0.0 if level else "auto"
    return roll


def describe_rolls(rolls: list[float]) -> str:
    """One line on the rolls a `RollLeveller` gave, e.g. for a command's summary."""
    if not rolls:
        return "camera roll: no frames"
    r = np.asarray(rolls)
    return f"camera roll read from the frames: {np.median(r):+.1f} deg (frames {r.min():+.1f} to {r.max():+.1f})"


def roll_warning(rolls: list[float], max_deg: float = SEARCH_DEG) -> str:
    """A warning when the rolls read reach the search's limit (the camera may be rolled further); "" otherwise."""
    if rolls and max(abs(r) for r in rolls) >= max_deg - 0.05:
        return (
            f"the camera roll read reaches the limit of the search (+-{max_deg:g} deg): the camera may be rolled "
            "further or the frames show few straight edges; pass --roll DEG if you know it"
        )
    return ""
