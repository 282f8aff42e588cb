"""The camera's roll, pitch and yaw read from one image (`estimate_roll`, `estimate_tilt`).

A rack row is full of straight edges that are horizontal or vertical in a level image (the boards'
fronts, the uprights, the boxes' front faces), so the roll is the angle that turns the image's strong
edges back onto the axes. `estimate_roll` reads one image: the magnitude-weighted histogram of its
gradient orientations, folded modulo 90 degrees (horizontal and vertical edges vote together),
smoothed, and its peak within ``max_deg``. Edges resampled at a slant bias their gradients toward the
pixel axes (~10 % of the angle), so the image is levelled by the first reading and read again: the
second reading is the residual, and the two add up (0.3 degrees or better on 95 % of the held-out
frames at 256x256).

A pitch or a yaw does not turn the edges uniformly: lines along the row (the boards' and boxes'
front edges) converge toward a vanishing point when the camera is turned away from square to the
rack front, so near-horizontal edges slope in proportion to their height in the image,
``dy/dx = -tan(yaw) * y`` (normalised coordinates, to first order), and the vertical ones
(uprights, box sides) lean in proportion to their column when the camera is tilted,
``dx/dy = tan(pitch) * x``. `estimate_tilt` levels the image by the angles so far (the same
homography as the canonical warp), finds its straight edge segments (`_edge_segments`: fitted to
their pixels' positions, since a rendered edge's staircase has exactly level gradients between its
steps), fits those two lines through the segments' slopes by consensus (`_consensus_fit`: boxes
standing yawed on their shelves have edges that converge elsewhere), reads the roll as above, and
repeats once. It needs the intrinsics (the slopes are in normalised coordinates). Carried over a
sequence by `network.inference.roll.CameraLeveller`.
"""

from __future__ import annotations

import math

import numpy as np
from PIL import Image
from scipy import ndimage
from skimage.measure import label

from layouts import Intrinsics
from layouts.canonical import camera_rotation
from layouts.errors import InputError

#: the largest roll `estimate_roll` looks for by default (degrees)
SEARCH_DEG = 15.0
#: the largest pitch or yaw `estimate_tilt` reads (degrees)
TILT_SEARCH_DEG = 10.0
#: near-horizontal / near-vertical edges within this many degrees of the axis are fitted for a pitch / yaw
_SLOPE_WINDOW_DEG = 6.0
#: the smallest residual scale of the slope fits (normalised slope, ~0.2 deg)
_MIN_SLOPE_SCALE = 0.003
#: edge segments shorter than this many pixels are not fitted; edge pixels are above this gradient quantile
_MIN_SEGMENT = 8
_SEGMENT_QUANTILE = 70.0
#: the consensus of the slope fits: within this normalised slope (~0.5 deg) of a line through two of the
#: heaviest points, at least this far apart (normalised)
_CONSENSUS_TOL = 0.008
_CONSENSUS_POINTS = 60
_CONSENSUS_SPAN = 0.05
#: a frame whose orientation histogram peaks less than this over its mean shows no axis-aligned structure
#: (rack frames: 4 or more on the held-out sets; noise or blobs: ~1.1): its pitch and yaw are not read
MIN_STRUCTURE = 2.0
#: a smoothed Sobel magnitude below this (grey levels x 8 per pixel) is resampling noise, not an edge
_MIN_GRADIENT = 1.0
#: images are read at most this many pixels wide (angles do not depend on the scale)
READ_WIDTH = 320
_BIN_DEG = 0.1
_SMOOTH_DEG = 0.5
_STRONG_QUANTILE = 80.0


def perspective(img: Image.Image, h: np.ndarray, fill: object = 0, resample: int = Image.BILINEAR) -> Image.Image:
    """``img`` resampled (same size) by the homography ``h`` from output to input pixels."""
    coeffs = tuple(float(c) for c in (h / h[2, 2]).ravel()[:8])
    return img.transform(img.size, Image.PERSPECTIVE, coeffs, resample=resample, fillcolor=fill)


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


def _sobel(grey: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Sobel gradients (x, y) of ``grey`` after a Gaussian of 1 pixel."""
    g = ndimage.gaussian_filter(grey, 1.0)
    return ndimage.sobel(g, 1), ndimage.sobel(g, 0)


def _gradients(
    gx: np.ndarray, gy: np.ndarray, mag: np.ndarray, valid: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """The strongest fifth of the gradients (magnitude ``mag``) inside ``valid``: (gx, gy, mag); None if flat."""
    inside = mag[valid]
    if inside.size < 16 or not inside.max() > _MIN_GRADIENT:
        return None
    strong = valid & (mag >= np.percentile(inside, _STRONG_QUANTILE))
    return gx[strong], gy[strong], mag[strong]


def _orientation_peak(gx: np.ndarray, gy: np.ndarray, mag: np.ndarray, max_deg: float) -> tuple[float, float]:
    """The roll the gradients show (degrees) and the histogram peak's strength (over its mean)."""
    # folded orientation in [-45, 45): 0 for a horizontal or vertical edge
    a = (np.degrees(np.arctan2(gy, gx)) + 45.0) % 90.0 - 45.0
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


def _reading(
    grey: np.ndarray, valid: np.ndarray, camera: tuple[float, ...], max_deg: float, gate: float = 0.0
) -> tuple[float, float, tuple[float, ...], tuple[float, ...]] | None:
    """One reading: (roll in degrees, the histogram peak's strength over its mean, the horizontal and the
    vertical segment lines of `_segment_fits`); None when the image is flat or its peak is under ``gate``.

    The roll is the orientation histogram's plus what the straight edges' positions show it missed
    (`_intercept_roll`). ``camera``: (fx, fy, cx, cy) in pixels."""
    gx, gy = _sobel(grey)
    mag = np.hypot(gx, gy)
    grads = _gradients(gx, gy, mag, valid)
    if grads is None:
        return None
    roll, strength = _orientation_peak(*grads, max_deg)
    if strength < gate:
        return None
    hline, vline = _segment_fits(gx, gy, mag, valid, roll, camera)
    return roll + _intercept_roll(hline, vline), strength, hline, vline


def _read(grey: np.ndarray, valid: np.ndarray, max_deg: float) -> tuple[float, float]:
    """One roll reading (degrees) and its strength (0 = nothing to read): square pixels about the image
    centre, so no intrinsics are needed."""
    h, w = grey.shape
    got = _reading(grey, valid, (float(w), float(w), w / 2, h / 2), max_deg)
    if got is None:
        return 0.0, 0.0
    return float(np.clip(got[0], -max_deg, max_deg)), got[1]


def _line_fit(s: np.ndarray, x: np.ndarray, w: np.ndarray) -> tuple[float, float, float, float]:
    """Robust weighted fit ``s = a + b x`` (Tukey's biweight): (a, b, b's and a's inverse variances; 0 = too few points)."""
    if s.size < 3:
        return 0.0, 0.0, 0.0, 0.0
    a = b = 0.0
    ww, sigma = w, 1.0
    for it in range(6):
        r = s - a - b * x
        sigma = max(1.4826 * float(np.median(np.abs(r))), _MIN_SLOPE_SCALE) if it else 1.0  # first: plain LS
        ww = w * np.clip(1.0 - (r / (4.0 * sigma)) ** 2, 0.0, None) ** 2
        sw = np.sqrt(ww)
        (a, b), *_ = np.linalg.lstsq(np.stack([sw, sw * x], 1), sw * s, rcond=None)
    if not ww.sum() > 0:
        return 0.0, 0.0, 0.0, 0.0
    n = float(np.count_nonzero(ww))
    mean = float(np.average(x, weights=ww))
    spread = float((ww * (x - mean) ** 2).sum() / ww.sum())
    return float(a), float(b), n * spread / sigma**2, n / (sigma**2 * (1.0 + mean**2 / max(spread, 1e-12)))


def _consensus_fit(s: np.ndarray, x: np.ndarray, w: np.ndarray) -> tuple[float, float, float, float]:
    """`_line_fit` over the largest consensus: the line through two points that the most weight lies within
    _CONSENSUS_TOL of (pairs among the _CONSENSUS_POINTS heaviest points), refitted on those points.

    A frame's edges are few (tens of segments) and a yawed box's edges converge elsewhere, so a
    least-squares start is pulled off; the consensus keeps only the edges that agree.
    """
    if s.size < 3:
        return 0.0, 0.0, 0.0, 0.0
    top = np.argsort(-w, kind="stable")[:_CONSENSUS_POINTS]
    i, j = np.triu_indices(top.size, 1)
    i, j = top[i], top[j]
    apart = np.abs(x[j] - x[i]) > _CONSENSUS_SPAN
    if not apart.any():
        return _line_fit(s, x, w)
    i, j = i[apart], j[apart]
    b = (s[j] - s[i]) / (x[j] - x[i])
    a = s[i] - b * x[i]
    inside = np.abs(s[None, :] - a[:, None] - b[:, None] * x[None, :]) < _CONSENSUS_TOL
    best = inside[int(np.argmax(inside @ w))]
    return _line_fit(s[best], x[best], w[best])


def _edge_segments(
    along: np.ndarray, across: np.ndarray, valid: np.ndarray, threshold: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Straight near-horizontal edges from the gradients ``along`` (x) and ``across`` (y) them.

    Edge pixels are the strong ``across`` maxima along each column (sub-pixel by a parabola); they
    are linked into 8-connected segments (one gradient sign each), and each segment's line is
    fitted to its pixel positions, so a rendered edge's staircase (exactly level gradients between
    its steps) still gives its true slope. Returns each segment's mean column, mean row, slope
    (rows per column) and length in columns; segments shorter than _MIN_SEGMENT or not straight are dropped.
    """
    mag = np.abs(across)
    above, below = np.roll(mag, 1, 0), np.roll(mag, -1, 0)
    peak = valid & (mag >= threshold) & (mag >= above) & (mag > below) & (np.abs(along) < mag)
    lab = label(peak & (across > 0), connectivity=2)
    neg = label(peak & (across < 0), connectivity=2)
    lab = np.where(neg > 0, neg + lab.max(), lab)
    rows, cols = np.nonzero(lab)
    empty = np.zeros(0)
    if rows.size == 0:
        return empty, empty, empty, empty
    ids = lab[rows, cols]
    y0, y1, y2 = above[rows, cols], mag[rows, cols], below[rows, cols]
    den = y0 - 2.0 * y1 + y2
    r = rows + np.clip(0.5 * (y0 - y2) / np.where(den < 0, den, -np.inf), -0.5, 0.5)
    n = int(lab.max()) + 1
    w = np.bincount(ids, y1, n)
    mx = np.bincount(ids, y1 * cols, n) / np.maximum(w, 1e-12)
    my = np.bincount(ids, y1 * r, n) / np.maximum(w, 1e-12)
    dx, dy = cols - mx[ids], r - my[ids]
    slope = np.bincount(ids, y1 * dx * dy, n) / np.maximum(np.bincount(ids, y1 * dx * dx, n), 1e-12)
    misfit = np.bincount(ids, y1 * (dy - slope[ids] * dx) ** 2, n) / np.maximum(w, 1e-12)
    span = np.bincount(ids, None, n)  # one peak per column and sign: the pixel count is about the length
    keep = (span >= _MIN_SEGMENT) & (misfit < 0.5)
    keep[0] = False
    return mx[keep], my[keep], slope[keep], span[keep].astype(float)


def _level(grey: np.ndarray, intr: Intrinsics, angles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``grey`` as the same camera turned level (`layouts.canonical.camera_rotation`), and the mask it covers
    (eroded past the reach of the gradients' smoothing, so the uncovered border reads as no edge)."""
    k = intr.matrix
    h = k @ camera_rotation(*(float(a) for a in angles)).T @ np.linalg.inv(k)
    levelled = perspective(Image.fromarray(grey), h)
    inside = np.asarray(perspective(Image.fromarray(np.full(grey.shape, 255, np.uint8)), h, 0, Image.NEAREST)) > 0
    return np.asarray(levelled, np.float32), ndimage.binary_erosion(inside, iterations=5)


def _read_tilt(grey: np.ndarray, valid: np.ndarray, intr: Intrinsics, max_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """One reading of a nearly level image: (roll, pitch, yaw) residuals in degrees and their strengths."""
    # a frame without a preferred edge orientation is not a view of racks: nothing to read
    got = _reading(grey, valid, (intr.fx, intr.fy, intr.cx, intr.cy), max_deg, MIN_STRUCTURE)
    if got is None:
        return np.zeros(3), np.zeros(3)
    roll, roll_strength, (_, yaw_slope, yaw_strength, _), (_, pitch_slope, pitch_strength, _) = got
    angles = np.array([roll, math.degrees(math.atan(pitch_slope)), -math.degrees(math.atan(yaw_slope))])
    return angles, np.array([roll_strength, pitch_strength, yaw_strength])


def _segment_fits(
    gx: np.ndarray, gy: np.ndarray, mag: np.ndarray, valid: np.ndarray, roll: float, camera: tuple[float, ...]
) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """The straight edges' two consensus lines, `_consensus_fit` each: the near-horizontal segments' normalised
    slope against their height (intercept: the roll left after ``roll``; slope: the yaw) and the
    near-vertical ones' against their column (intercept: minus that roll; slope: the pitch).
    ``camera``: (fx, fy, cx, cy) in pixels."""
    fx, fy, cx, cy = camera
    threshold = float(np.percentile(mag[valid], _SEGMENT_QUANTILE))
    t = math.tan(math.radians(roll))
    window = math.tan(math.radians(_SLOPE_WINDOW_DEG))
    # near-horizontal edges: normalised slope dy/dx (the roll's share taken out) against their height y
    _, row, sh, length = _edge_segments(gx, gy, valid, threshold)
    y, sh = (row + 0.5 - cy) / fy, sh * fx / fy + t
    # near-vertical edges, transposed: dx/dy against their column x
    _, col, sv, vlength = _edge_segments(gy.T, gx.T, valid.T, threshold)
    x, sv = (col + 0.5 - cx) / fx, sv * fy / fx - t
    h, v = np.abs(sh) < window, np.abs(sv) < window
    # weighed by length (a longer segment's slope is surer, but one long box edge must not outvote the boards)
    return _consensus_fit(sh[h], y[h], length[h]), _consensus_fit(sv[v], x[v], vlength[v])


def _intercept_roll(hline: tuple[float, ...], vline: tuple[float, ...]) -> float:
    """The roll (degrees) the segment lines' intercepts show, each weighed by its inverse variance.

    The orientation histogram reads a point-sampled edge (a staircase whose gradients are exactly
    level between its steps, as the renderer draws it) as level: held-out frames rendered 5 degrees
    rolled read 0.35. The segments' slopes, fitted to their pixels' positions, are not pulled so:
    their line's slope at the principal point (the intercept) is the roll the histogram missed.
    """
    (ah, _, _, ah_s), (av, _, _, av_s) = hline, vline
    if not ah_s + av_s > 0:
        return 0.0
    return math.degrees(math.atan((-ah * ah_s + av * av_s) / (ah_s + av_s)))


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


def estimate_tilt(
    rgb: np.ndarray,
    intr: Intrinsics,
    prior: tuple[float, float, float] = (0.0, 0.0, 0.0),
    read: tuple[bool, bool, bool] = (True, True, True),
    max_deg: float = SEARCH_DEG,
) -> tuple[np.ndarray, np.ndarray]:
    """The (roll, pitch, yaw) of one uint8 RGB image of camera ``intr`` (degrees) and each one's strength.

    ``prior``: the angles known so far (the sequence's): the image is levelled by them and read
    once, instead of read, levelled and read again. ``read``: which angles to read; the others stay
    at the prior. The strengths weigh readings against each other: the roll's is its histogram
    peak over the mean, a pitch's or yaw's the inverse variance of its slope (0 = nothing to read).
    Pitch and yaw are read within +-TILT_SEARCH_DEG.
    """
    if not (isinstance(max_deg, (int, float)) and 0 < max_deg < 45):
        raise InputError(f"max_deg must be a number of degrees in (0, 45), got {max_deg!r}")
    grey = _grey(rgb)
    intr = intr.scaled(grey.shape[1], grey.shape[0])
    angles = np.asarray(prior, float).copy()
    if angles.shape != (3,):
        raise InputError(f"prior must be (roll, pitch, yaw) in degrees, got {prior!r}")
    mask = np.asarray(read, bool)
    limits = np.array([max_deg, TILT_SEARCH_DEG, TILT_SEARCH_DEG])
    strengths = np.zeros(3)
    for _ in range(1 if angles.any() else 2):
        levelled, valid = _level(grey, intr, angles)
        step, strengths = _read_tilt(levelled, valid, intr, max_deg)
        angles = np.where(mask, np.clip(angles + step, -limits, limits), angles)
    return angles, np.where(mask, strengths, 0.0)
