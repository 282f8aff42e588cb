"""The canonical view puts front-plane points on the same canonical pixel whatever the camera."""

from __future__ import annotations

import numpy as np
import pytest

from layouts import Intrinsics, LayoutError, LayoutSpec
from layouts.canonical import FILL_RGB, CanonicalView

VIEW = CanonicalView(128, 128, 3.0)


def _stripes(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """A front-plane pattern: red changes every 0.25 m along X, green every 0.2 m along Y."""
    r = np.where(np.floor(x / 0.25) % 2 == 0, 220, 30)
    g = np.where(np.floor(y / 0.2) % 2 == 0, 200, 40)
    return np.stack(np.broadcast_arrays(r, g, np.full_like(r, 90)), -1).astype(np.uint8)


def _render(intr: Intrinsics, distance: float) -> np.ndarray:
    """What camera ``intr`` sees of the pattern on a plane ``distance`` ahead (pixel centres)."""
    u = np.arange(intr.width) + 0.5
    v = np.arange(intr.height) + 0.5
    x = (u - intr.cx) * distance / intr.fx
    y = (v - intr.cy) * distance / intr.fy
    return _stripes(x[None, :], y[:, None])


def _truth(view: CanonicalView) -> np.ndarray:
    m = view.metres_per_pixel
    x = (np.arange(view.width) + 0.5 - view.width / 2) * m
    y = (np.arange(view.height) + 0.5 - view.height / 2) * m
    return _stripes(x[None, :], y[:, None])


@pytest.mark.parametrize(
    "intr, distance",
    [
        (Intrinsics.from_fov(128, 128, 60.0), 2.6),  # the training camera: nearly the identity
        (Intrinsics.from_fov(640, 480, 75.0), 2.4),  # wider, larger, not square
        (Intrinsics(300.0, 320.0, 150.0, 130.0, 320, 240), 3.1),  # off-centre principal point, non-square pixels
    ],
)
def test_front_plane_points_land_on_their_canonical_pixel(intr, distance):
    got = VIEW.warp(_render(intr, distance), intr, distance)
    want = _truth(VIEW)
    valid = VIEW.valid_mask(intr, distance)
    assert valid.mean() > 0.5
    # away from stripe edges (where resampling blends) every seen pixel has the pattern's colour
    m = VIEW.metres_per_pixel
    x = (np.arange(128) + 0.5 - 64) * m
    y = (np.arange(128) + 0.5 - 64) * m
    far_x = np.abs(x / 0.25 - np.round(x / 0.25)) * 0.25 > 1.5 * m
    far_y = np.abs(y / 0.2 - np.round(y / 0.2)) * 0.2 > 1.5 * m
    inner = valid & far_y[:, None] & far_x[None, :]
    assert inner.sum() > 2000
    assert np.abs(got[inner].astype(int) - want[inner].astype(int)).max() <= 2
    assert (got[~valid] == FILL_RGB).all()  # what the camera does not see is the fill colour


def test_distance_sets_the_scale_and_rows_follow_heights():
    intr = Intrinsics.from_fov(128, 128, 60.0)
    near, far = VIEW.valid_mask(intr, 2.3), VIEW.valid_mask(intr, 2.9)
    assert not near[64, 0] and near[64, 64] and far.all()  # closer: narrower view, padded sides
    # a point 0.5 m below the optical axis: canonical row from its height alone
    assert VIEW.row_of(0.5) == pytest.approx(64 + 0.5 / VIEW.metres_per_pixel)
    assert VIEW.y_of(VIEW.row_of(-1.2)) == pytest.approx(-1.2)
    u, v = VIEW.source_coords(intr, 2.6)
    assert u.shape == (128,) and v.shape == (128,)
    assert VIEW.source_scale(intr, 2.6) == pytest.approx(1.0, abs=0.01)  # 60 deg at 2.6 m sees 3.0 m


def test_fine_sources_are_filtered_before_sampling():
    intr = Intrinsics.from_fov(1024, 1024, 60.0)
    checker = ((np.indices((1024, 1024)).sum(0) % 2) * 255).astype(np.uint8)
    out = VIEW.warp(np.repeat(checker[..., None], 3, 2), intr, 2.6)
    assert out.std() < 8 and abs(float(out.mean()) - 127.5) < 8  # grey, not aliased stripes


def test_bad_inputs_are_one_line_errors():
    intr = Intrinsics.from_fov(64, 64, 60.0)
    img = np.zeros((64, 64, 3), np.uint8)
    for d in (0.0, -1.0, float("nan"), float("inf")):
        with pytest.raises(LayoutError, match="distance"):
            VIEW.warp(img, intr, d)
    with pytest.raises(LayoutError, match="uint8"):
        VIEW.warp(img.astype(np.float32), intr, 2.6)
    with pytest.raises(LayoutError, match="width"):
        CanonicalView(0, 128, 3.0)
    with pytest.raises(LayoutError, match="x_extent"):
        CanonicalView(128, 128, -3.0)
    # a model's canonical view follows its layouts' X extent
    spec = LayoutSpec(x_extent=4.0)
    assert CanonicalView(128, 96, spec.x_extent).metres_per_pixel == pytest.approx(4.0 / 128)
