"""Each map box's colour: a robust mean of its front face's pixels over the frames that saw it.

Per frame (`BoxColours.add`), each lifted box's front face is sampled on a small grid of its
inner part (`FACE_X` of its width, `FACE_H` of its height, so edges, labels and the board above
stay out) and the median RGB of the points is kept with the box's slot and footprint in map X / Z.
A face point at metric ``X`` (about the camera), ``h`` above its board and ``dz`` behind the rack
front is where the canonical view (`layouts.canonical`) puts the front-plane offset
``(X, Y_board - h) * d / (d + dz)``: ``Y_board`` (metres below the optical axis) is the slot's
board row (the network's anchor, a canonical row) and ``d`` the camera-to-rack-front distance;
`layouts.canonical.CanonicalView.camera_homography` takes canonical pixels to the frame's pixels,
the camera's roll / pitch / yaw included. A box with another box of its slot in front of it is
not sampled (its face is hidden).

At the end (`BoxColours.paint`) every frame sample goes to the map box of its slot it overlaps
best (X-extent IoU >= `MIN_IOU`, depth ranges overlapping); a box's colour is the mean of its
samples within `OUTLIER_RGB` (or 2.5 median deviations) of their median. A run keeps every sample by
default; ``BoxColours(view, per_place=N)`` (a live run) keeps the newest N per place (slot, `PLACE_M` of map X
and of depth), so the samples are bounded by the map, not by the frames. Frames are kept only as
copies at most `SAMPLE_WIDTH` pixels wide (every k-th pixel) until their layouts come; the cost
per frame is that copy, one homography and one median over a few dozen pixels per box (about
1 ms for 15 boxes). Arrays in, arrays out: nothing here knows the network.
"""

from __future__ import annotations

from collections import deque

import numpy as np

from layouts.camera import Intrinsics
from layouts.canonical import CanonicalView
from layouts.errors import LayoutError
from stitching.lift import FrameReconstruction
from stitching.warehouse_map import WarehouseMap

SAMPLE_WIDTH = 192  #: frames are downsized by an integer factor to at most this many pixels wide
FACE_X = 0.6  #: share of a box's width sampled (centred)
FACE_H = (0.2, 0.8)  #: share of a box's height sampled (from its board up)
GRID = (7, 5)  #: sample points across x up the face
MIN_POINTS = 0.5  #: share of a face's points inside the frame to keep its sample
HIDDEN_OVERLAP = 0.5  #: a box is hidden when a box in front covers this share of its width
MIN_IOU = 0.3  #: X-extent IoU of a frame sample and a map box to count for it
OUTLIER_RGB = 16.0  #: samples this close (largest channel difference) to the median always count
PLACE_M = 0.25  #: a place, for a bounded sample history: this many metres of map X (face centre) and of depth
COMPACT_ROWS = 4096  #: a bounded history drops the older samples of its full places after this many new ones


class BoxColours:
    """Collects front-face colour samples frame by frame and paints them onto a map's boxes; ``per_place``:
    samples kept per place (None: all of them; N: the newest N, for endless streams)."""

    def __init__(self, view: CanonicalView, per_place: int | None = None) -> None:
        if per_place is not None and (isinstance(per_place, bool) or not isinstance(per_place, int) or per_place < 1):
            raise LayoutError(f"BoxColours per_place must be None or an integer >= 1, got {per_place!r}")
        self.view, self.per_place = view, per_place
        self._frames: deque[tuple[np.ndarray, int, tuple[int, int]]] = deque()
        self._rows: list[np.ndarray] = []  # (K, 8): slot, x0, x1, z0, z1 (map), r, g, b
        self._new = 0  # samples added since the last `_compact`

    def keep(self, rgb: np.ndarray) -> None:
        """Hold frame ``rgb`` (uint8 ``(H, W, 3)``) downsized until its reconstruction comes to `add`."""
        rgb = np.asarray(rgb)
        h, w = rgb.shape[:2]
        k = max(1, -(-w // SAMPLE_WIDTH))
        # every k-th pixel, the middle one of each k x k block (a strided copy: a filter costs 30x more on HD frames)
        self._frames.append((np.array(rgb[k // 2 :: k, k // 2 :: k, :3], np.uint8), k, (w, h)))

    def add(
        self,
        rec: FrameReconstruction,
        camera_x: float,
        anchors: np.ndarray,
        intr: Intrinsics,
        distance: float,
        angles: tuple[float, float, float] = (0.0, 0.0, 0.0),
    ) -> int:
        """Sample the oldest kept frame's boxes (``rec``, its reconstruction; ``camera_x``, its camera X in the
        map; ``anchors``, its slots' canonical board rows, NaN = no slot); returns the number of boxes sampled."""
        small, k, (w, h) = self._frames.popleft()
        if (intr.width, intr.height) != (w, h):
            intr = intr.scaled(w, h)
        rows = frame_samples(rec, small, k, self.view, intr, distance, np.asarray(anchors, float), angles)
        if len(rows):
            rows[:, 1:3] += camera_x
            self._rows.append(rows)
            self._new += len(rows)
            if self.per_place is not None and self._new >= COMPACT_ROWS:
                self._compact()
        return len(rows)

    def _compact(self) -> None:
        """Keep the newest ``per_place`` samples of each place (in their order): at most ``per_place`` times the places seen."""
        rows = self.samples()
        self._new = 0
        key = np.stack(
            [rows[:, 0], np.floor((rows[:, 1] + rows[:, 2]) / (2 * PLACE_M)), np.floor(rows[:, 3] / PLACE_M)]
        )
        _, place = np.unique(key, axis=1, return_inverse=True)
        place = place.reshape(-1)
        order = np.argsort(place, kind="stable")  # each place's samples in their order
        count = np.bincount(place)
        pos = np.empty(len(rows), int)
        pos[order] = np.arange(len(rows)) - (np.cumsum(count) - count)[place[order]]
        newer = count[place] - 1 - pos  # samples of its place after each
        self._rows = [rows[newer < self.per_place]]

    def samples(self) -> np.ndarray:
        """All samples so far, ``(N, 8)``: slot, map x0, x1, z0, z1, r, g, b."""
        return np.concatenate(self._rows) if self._rows else np.zeros((0, 8))

    def paint(self, wmap: WarehouseMap) -> int:
        """Set ``colour`` on every box of ``wmap`` that has samples; returns how many were painted."""
        colours = assign_colours(wmap, self.samples())
        for b in wmap.boxes():
            b.colour = colours.get(b.id)
        return len(colours)


def frame_samples(
    rec: FrameReconstruction,
    rgb: np.ndarray,
    k: int,
    view: CanonicalView,
    intr: Intrinsics,
    distance: float,
    anchors: np.ndarray,
    angles: tuple[float, float, float] = (0.0, 0.0, 0.0),
) -> np.ndarray:
    """``(K, 8)`` rows (slot, x0, x1, z0, z1 about the camera, median r, g, b) for one frame's visible box faces.

    ``rgb``: the frame downsized ``k`` times (pixel j stands for full-size pixels ``[jk, (j+1)k)``); ``intr``: the
    full-size camera. All boxes at once: one homography, one median."""
    if not rec.boxes:
        return np.zeros((0, 8))
    a = np.array([(b.slot, b.x0, b.x1, b.z0, b.z1, b.height) for b in rec.boxes], float)
    slot = a[:, 0].astype(int)
    anchor = np.asarray(anchors, float)[np.minimum(slot, len(anchors) - 1)]
    keep = (slot < len(anchors)) & np.isfinite(anchor) & ~_hidden(a)
    a, slot, anchor = a[keep], slot[keep], anchor[keep]
    if not len(a):
        return np.zeros((0, 8))
    z_front = np.array([rec.shelves[r].z_range[0] for r in slot])
    scale = distance / (distance + np.maximum(0.0, a[:, 3] - z_front))
    fx = (np.arange(GRID[0]) + 0.5) / GRID[0] - 0.5
    fh = FACE_H[0] + (np.arange(GRID[1]) + 0.5) / GRID[1] * (FACE_H[1] - FACE_H[0])
    x = ((a[:, 1] + a[:, 2]) / 2)[:, None, None] + fx[None, None, :] * FACE_X * (a[:, 2] - a[:, 1])[:, None, None]
    y = view.y_of(anchor)[:, None, None] - fh[None, :, None] * a[:, 5][:, None, None]
    x, y = np.broadcast_arrays(x * scale[:, None, None], y * scale[:, None, None])
    mpp = view.metres_per_pixel
    pts = np.stack([x.ravel() / mpp + view.width / 2, y.ravel() / mpp + view.height / 2, np.ones(x.size)])
    p = view.camera_homography(intr, distance, *angles) @ pts
    with np.errstate(divide="ignore", invalid="ignore"):
        u, v = np.floor(p[0] / p[2] / k), np.floor(p[1] / p[2] / k)
    inside = (u >= 0) & (u < rgb.shape[1]) & (v >= 0) & (v < rgb.shape[0]) & (p[2] > 0)
    u, v = np.where(inside, u, 0).astype(int), np.where(inside, v, 0).astype(int)
    pix = np.where(inside[:, None], rgb[v, u].astype(float), np.nan).reshape(len(a), -1, 3)
    inside = inside.reshape(len(a), -1)
    seen = inside.mean(axis=1) >= MIN_POINTS
    if not seen.any():
        return np.zeros((0, 8))
    colour = np.nanmedian(pix[seen], axis=1)
    return np.concatenate([a[seen, :5], colour], axis=1)


def _hidden(a: np.ndarray) -> np.ndarray:
    """Per box (rows slot, x0, x1, z0, z1, ...): another box of its slot stands wholly in front of it over
    `HIDDEN_OVERLAP` of its width."""
    slot, x0, x1, z0, z1 = a[:, :5].T
    front = (slot[:, None] == slot[None, :]) & (z1[None, :] <= z0[:, None] + 1e-6)
    np.fill_diagonal(front, False)
    overlap = np.minimum(x1[:, None], x1[None, :]) - np.maximum(x0[:, None], x0[None, :])
    return (front & (overlap >= HIDDEN_OVERLAP * np.maximum(x1 - x0, 1e-9)[:, None])).any(axis=1)


def assign_colours(wmap: WarehouseMap, samples: np.ndarray) -> dict[str, tuple[int, int, int]]:
    """Map box id -> robust mean colour of the ``(N, 8)`` samples that fall on it (see the module docstring)."""
    boxes = [(s.slot, b) for s in wmap.shelves() for b in s.boxes]
    if not boxes or not len(samples):
        return {}
    slot = np.array([s for s, _ in boxes])
    xr = np.array([b.cuboid.x_range() for _, b in boxes])
    fp = [b.cuboid.footprint() for _, b in boxes]
    zr = np.array([(f[:, 1].min(), f[:, 1].max()) for f in fp])
    inter = np.minimum(samples[:, None, 2], xr[None, :, 1]) - np.maximum(samples[:, None, 1], xr[None, :, 0])
    union = np.maximum(samples[:, None, 2], xr[None, :, 1]) - np.minimum(samples[:, None, 1], xr[None, :, 0])
    iou = np.clip(inter, 0, None) / np.maximum(union, 1e-9)
    deep = np.minimum(samples[:, None, 4], zr[None, :, 1]) - np.maximum(samples[:, None, 3], zr[None, :, 0]) > 0
    iou[(samples[:, None, 0] != slot[None, :]) | ~deep] = 0.0
    best = iou.argmax(axis=1)
    ok = iou[np.arange(len(samples)), best] >= MIN_IOU
    out = {}
    for j, (_, b) in enumerate(boxes):
        rgb = samples[ok & (best == j), 5:8]
        if len(rgb):
            out[b.id] = robust_mean(rgb)
    return out


def robust_mean(rgb: np.ndarray) -> tuple[int, int, int]:
    """Mean of the ``(N, 3)`` colours near their median (outliers: a frame's wrong box or a hidden face)."""
    med = np.median(rgb, axis=0)
    dev = np.abs(rgb - med).max(axis=1)
    kept = rgb[dev <= max(OUTLIER_RGB, 2.5 * float(np.median(dev)))]
    r, g, b = (int(c) for c in np.clip(np.rint(kept.mean(axis=0)), 0, 255))
    return r, g, b
