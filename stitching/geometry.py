"""Cuboids with a yawed footprint, and their exact 3D IoU.

Axes follow DESIGN.md (X right along the row, Y down, Z into the racks). A cuboid is
``center (x, y, z)``, ``size (w, h, d)`` and ``yaw``: its width axis points along
``(cos yaw, sin yaw)`` in ``(x, z)``; ``h`` is vertical. This is the same convention as the
generator's ``scene.json`` boxes.

3D IoU is exact for yawed footprints: the footprints are convex quadrilaterals, intersected by
Sutherland-Hodgman clipping, and the volume overlap is (footprint intersection area) x (overlap
of the vertical intervals).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Cuboid:
    """A box with a vertical axis and a yawed footprint (metres, radians)."""

    center: tuple[float, float, float]
    size: tuple[float, float, float]
    yaw: float = 0.0

    def footprint(self) -> np.ndarray:
        """(4, 2) corners in ``(x, z)``, counter-clockwise in the (x, z) plane."""
        return footprint_corners(self.center[0], self.center[2], self.size[0], self.size[2], self.yaw)

    @property
    def y_range(self) -> tuple[float, float]:
        """(min Y, max Y); Y points down, so min Y is the top face."""
        return self.center[1] - self.size[1] / 2, self.center[1] + self.size[1] / 2

    @property
    def volume(self) -> float:
        return float(self.size[0] * self.size[1] * self.size[2])

    def x_range(self) -> tuple[float, float]:
        """Extent of the footprint along X (axis-aligned bound)."""
        fp = self.footprint()
        return float(fp[:, 0].min()), float(fp[:, 0].max())

    def corners(self) -> np.ndarray:
        """(8, 3) corners: the footprint at the top face (min Y), then at the bottom face."""
        fp = self.footprint()
        y0, y1 = self.y_range
        top = np.column_stack([fp[:, 0], np.full(4, y0), fp[:, 1]])
        bot = np.column_stack([fp[:, 0], np.full(4, y1), fp[:, 1]])
        return np.vstack([top, bot])


def stacks_of(shelf: dict) -> list[Cuboid]:
    """A ``scene.json`` shelf's box stacks as world cuboids (the union of the boxes sharing ``stack_id``, a box
    without one a stack of its own), in ``stack_id`` order: the ground truth the maps are scored on."""
    groups: dict[str, list[dict]] = {}
    for b in shelf.get("boxes", []):
        groups.setdefault(str(b.get("stack_id", b.get("id"))), []).append(b)
    out = []
    for _, bs in sorted(groups.items()):
        y0 = min(b["center"][1] - b["size"][1] / 2 for b in bs)
        y1 = max(b["center"][1] + b["size"][1] / 2 for b in bs)
        b0 = bs[0]
        out.append(
            Cuboid(
                (float(b0["center"][0]), (y0 + y1) / 2, float(b0["center"][2])),
                (float(b0["size"][0]), y1 - y0, float(b0["size"][2])),
                float(b0.get("yaw", 0.0)),
            )
        )
    return out


def footprint_corners(cx: float, cz: float, w: float, d: float, yaw: float) -> np.ndarray:
    """Corners ``(4, 2)`` of a ``w x d`` rectangle at ``(cx, cz)`` whose width axis is ``(cos, sin) yaw``."""
    c, s = math.cos(yaw), math.sin(yaw)
    u = np.array([c, s]) * (w / 2)
    v = np.array([-s, c]) * (d / 2)
    ctr = np.array([cx, cz])
    return np.array([ctr - u - v, ctr + u - v, ctr + u + v, ctr - u + v])


def polygon_area(poly: np.ndarray) -> float:
    """Unsigned shoelace area of a simple polygon ``(N, 2)``."""
    if len(poly) < 3:
        return 0.0
    x, y = poly[:, 0], poly[:, 1]
    return 0.5 * abs(float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))))


def _ccw(poly: np.ndarray) -> np.ndarray:
    x, y = poly[:, 0], poly[:, 1]
    signed = float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))
    return poly if signed >= 0 else poly[::-1]


def clip_convex(subject: np.ndarray, clip: np.ndarray) -> np.ndarray:
    """Intersection of two convex polygons (Sutherland-Hodgman); ``(M, 2)``, maybe empty."""
    out = [tuple(p) for p in _ccw(np.asarray(subject, float))]
    clip = _ccw(np.asarray(clip, float))
    n = len(clip)
    for i in range(n):
        if not out:
            break
        ax, ay = clip[i]
        bx, by = clip[(i + 1) % n]
        ex, ey = bx - ax, by - ay

        def inside(p, ax=ax, ay=ay, ex=ex, ey=ey) -> bool:
            return ex * (p[1] - ay) - ey * (p[0] - ax) >= -1e-12

        def cross(p, q, ax=ax, ay=ay, ex=ex, ey=ey):
            # Intersection of segment p-q with the infinite clip edge line.
            dx, dy = q[0] - p[0], q[1] - p[1]
            den = ex * dy - ey * dx
            if abs(den) < 1e-18:
                return q
            t = (ex * (ay - p[1]) - ey * (ax - p[0])) / den
            return (p[0] + t * dx, p[1] + t * dy)

        inp = out
        out = []
        prev = inp[-1]
        for cur in inp:
            if inside(cur):
                if not inside(prev):
                    out.append(cross(prev, cur))
                out.append(cur)
            elif inside(prev):
                out.append(cross(prev, cur))
            prev = cur
    return np.array(out, float).reshape(-1, 2)


def footprint_intersection(a: Cuboid, b: Cuboid) -> float:
    """Area of the intersection of two footprints (exact for any yaw)."""
    fa, fb = a.footprint(), b.footprint()
    # Cheap reject on the axis-aligned bounds first.
    if fa[:, 0].max() <= fb[:, 0].min() or fb[:, 0].max() <= fa[:, 0].min():
        return 0.0
    if fa[:, 1].max() <= fb[:, 1].min() or fb[:, 1].max() <= fa[:, 1].min():
        return 0.0
    if a.yaw == 0.0 and b.yaw == 0.0:
        dx = min(fa[:, 0].max(), fb[:, 0].max()) - max(fa[:, 0].min(), fb[:, 0].min())
        dz = min(fa[:, 1].max(), fb[:, 1].max()) - max(fa[:, 1].min(), fb[:, 1].min())
        return float(max(dx, 0.0) * max(dz, 0.0))
    return polygon_area(clip_convex(fa, fb))


def iou_3d(a: Cuboid, b: Cuboid) -> float:
    """Exact 3D IoU of two vertical cuboids with yawed footprints."""
    ay0, ay1 = a.y_range
    by0, by1 = b.y_range
    dh = min(ay1, by1) - max(ay0, by0)
    if dh <= 0:
        return 0.0
    inter = footprint_intersection(a, b) * dh
    if inter <= 0:
        return 0.0
    union = a.volume + b.volume - inter
    return float(inter / union) if union > 0 else 0.0


def iou_matrix(pred: list[Cuboid], gt: list[Cuboid]) -> np.ndarray:
    """(len(pred), len(gt)) 3D IoU matrix."""
    m = np.zeros((len(pred), len(gt)))
    for i, p in enumerate(pred):
        for j, g in enumerate(gt):
            m[i, j] = iou_3d(p, g)
    return m


def min_area_rect(points: np.ndarray) -> tuple[float, float, float, float, float]:
    """Minimum-area enclosing rectangle of 2D points: ``(cx, cz, w, d, yaw)``, yaw in (-pi/4, pi/4].

    Rotating calipers over the convex hull edges; ``w`` is the extent along ``(cos, sin) yaw``.
    """
    from scipy.spatial import ConvexHull, QhullError

    pts = np.asarray(points, float)
    try:
        hull = pts[ConvexHull(pts).vertices]
    except (QhullError, ValueError):
        hull = pts
    edges = np.diff(np.vstack([hull, hull[:1]]), axis=0)
    angles = np.unique(np.mod(np.arctan2(edges[:, 1], edges[:, 0]), math.pi / 2))
    c, s = np.cos(angles), np.sin(angles)
    a = hull[:, 0][None, :] * c[:, None] + hull[:, 1][None, :] * s[:, None]  # along (c, s)
    b = -hull[:, 0][None, :] * s[:, None] + hull[:, 1][None, :] * c[:, None]  # along (-s, c)
    area = (a.max(1) - a.min(1)) * (b.max(1) - b.min(1))
    k = int(np.argmin(area))
    ang = float(angles[k])
    lo = np.array([a[k].min(), b[k].min()])
    hi = np.array([a[k].max(), b[k].max()])
    mid = (lo + hi) / 2
    c, s = math.cos(ang), math.sin(ang)
    cx, cz = mid[0] * c - mid[1] * s, mid[0] * s + mid[1] * c
    w, d = hi - lo
    if ang > math.pi / 4:
        ang -= math.pi / 2
        w, d = d, w
    return float(cx), float(cz), float(w), float(d), float(ang)
