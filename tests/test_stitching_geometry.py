"""Cuboid geometry: exact 3D IoU with yawed footprints, polygon clipping, oriented rectangles."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from stitching.geometry import Cuboid, clip_convex, iou_3d, min_area_rect, polygon_area


def test_iou_identical_disjoint_and_axis_aligned():
    a = Cuboid((0, 0, 0), (1, 1, 1))
    assert iou_3d(a, a) == pytest.approx(1.0)
    assert iou_3d(a, Cuboid((2, 0, 0), (1, 1, 1))) == 0.0
    assert iou_3d(a, Cuboid((0, 2, 0), (1, 1, 1))) == 0.0  # stacked, not overlapping in height
    # Half overlap along X: intersection 0.5, union 1.5.
    assert iou_3d(a, Cuboid((0.5, 0, 0), (1, 1, 1))) == pytest.approx(1 / 3)
    # Half overlap in height only.
    assert iou_3d(a, Cuboid((0, 0.5, 0), (1, 1, 1))) == pytest.approx(1 / 3)


def test_iou_yawed_footprint_is_exact():
    a = Cuboid((0, 0, 0), (1, 1, 1))
    b = Cuboid((0, 0, 0), (1, 1, 1), math.pi / 4)
    # Unit square and the same square turned 45 degrees: the octagon has area 2(sqrt2 - 1).
    inter = 2 * (math.sqrt(2) - 1)
    assert iou_3d(a, b) == pytest.approx(inter / (2 - inter), rel=1e-9)
    # A quarter turn of a square is the same cuboid.
    assert iou_3d(a, Cuboid((0, 0, 0), (1, 1, 1), math.pi / 2)) == pytest.approx(1.0)
    # Width and depth swapped with a quarter turn: the same cuboid.
    c = Cuboid((0.3, 0, 0.1), (0.6, 0.4, 0.3), 0.2)
    d = Cuboid((0.3, 0, 0.1), (0.3, 0.4, 0.6), 0.2 + math.pi / 2)
    assert iou_3d(c, d) == pytest.approx(1.0)


@settings(max_examples=40, deadline=None)
@given(
    st.floats(-0.5, 0.5),
    st.floats(-0.5, 0.5),
    st.floats(0.2, 1.0),
    st.floats(0.2, 1.0),
    st.floats(-math.pi, math.pi),
)
def test_clip_matches_monte_carlo(x, z, w, d, yaw):
    a = Cuboid((0, 0, 0), (0.8, 1, 0.6), 0.3)
    b = Cuboid((x, 0, z), (w, 1, d), yaw)
    area = polygon_area(clip_convex(a.footprint(), b.footprint()))
    rng = np.random.default_rng(0)
    pts = rng.uniform(-1.6, 1.6, (40000, 2))

    def inside(c, p):
        q = p - np.array([c.center[0], c.center[2]])
        cs, sn = math.cos(c.yaw), math.sin(c.yaw)
        u = q @ np.array([cs, sn])
        v = q @ np.array([-sn, cs])
        return (np.abs(u) <= c.size[0] / 2) & (np.abs(v) <= c.size[2] / 2)

    mc = (inside(a, pts) & inside(b, pts)).mean() * 3.2**2
    assert area == pytest.approx(mc, abs=0.03)


def test_min_area_rect_recovers_a_turned_rectangle():
    yaw = math.radians(10)
    c = Cuboid((1.0, 0, 0.5), (0.6, 1, 0.3), yaw)
    fp = c.footprint()
    # Dense points on the boundary.
    pts = np.vstack([fp[i] + t * (fp[(i + 1) % 4] - fp[i]) for i in range(4) for t in np.linspace(0, 1, 20)])
    cx, cz, w, d, ryaw = min_area_rect(pts)
    assert (cx, cz) == pytest.approx((1.0, 0.5), abs=1e-6)
    assert (w, d) == pytest.approx((0.6, 0.3), abs=1e-6)
    assert ryaw == pytest.approx(yaw, abs=1e-6)


def test_vote_offset_keeps_a_sudden_reversal_out():
    """Four frame edges agree on a jump 0.42 m back after steps of 0.2 m forward (a change of speed beyond
    max_speed_change), two on the constant-velocity step: the step wins; without the bound (a huge
    max_speed_change) the larger consensus would."""
    from stitching.shift import Edges, ShiftConfig, vote_offset

    def edges(xs, ws):
        n = len(xs)
        z = np.zeros(n)
        return Edges(
            np.zeros(n, int), np.array([0, 1] * (n // 2)), np.array(xs), np.array(ws), z + 0.4, z + 1.0, z + 0.3, z + 1
        )

    frame = edges([0.0, 0.5, 1.0, 1.5], [0.5, 0.5, 0.5, 0.5])
    # Map edges: the true offset is +0.2 (two frame edges match), a repeated pattern at -0.42 matches four.
    mapped = edges([0.2, 0.7, -0.42, 0.08, 0.58, 1.08], [0.5, 0.5, 0.5, 0.5, 0.5, 0.5])
    dx = 3.0 / 128
    off, _, _ = vote_offset(frame, mapped, 0.0, ShiftConfig(), dx, expected=0.2)
    assert abs(off - 0.2) < 0.02
    off_free, _, _ = vote_offset(frame, mapped, 0.0, ShiftConfig(max_speed_change=10.0), dx, expected=0.2)
    assert abs(off_free + 0.42) < 0.02
