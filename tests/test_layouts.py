"""The layouts contract: spec, conversion, rasterising, codecs and metrics."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from layouts import BOX, SHELF, Intrinsics, LayoutError, LayoutSpec
from layouts.codecs import (
    FrameLayouts,
    LayoutFolder,
    from_racklay,
    load_frame,
    load_native,
    load_racklay,
    save_frame,
    save_native,
    save_racklay,
    to_racklay,
)
from layouts.fileio import load_npy, npz_bytes
from layouts.metrics import LayoutMetrics, format_table
from layouts.raster import fill_rect

SPEC = LayoutSpec(num_slots=2, size=10, x_extent=1.0, z_extent=2.0, h_extent=1.0)


def test_spec_validation_and_json_round_trip():
    s = LayoutSpec()
    assert LayoutSpec.from_json(s.to_json()) == s
    assert s.shape == (3, 128, 128)
    with pytest.raises(LayoutError, match="size"):
        LayoutSpec(size=0)
    with pytest.raises(LayoutError, match="x_extent"):
        LayoutSpec(x_extent=float("nan"))
    with pytest.raises(LayoutError, match="unknown layout spec keys"):
        LayoutSpec.from_dict({"size": 8, "bogus": 1})
    with pytest.raises(LayoutError, match="version"):
        LayoutSpec.from_dict({"version": 99})
    with pytest.raises(LayoutError, match="not valid JSON"):
        LayoutSpec.from_json("{", source="x.json")


def test_pixel_metre_conversion_axes():
    # Column 0 is the left (-X); pixel centres sit at c + 0.5.
    assert SPEC.col_to_x(0.5) == pytest.approx(-0.45)
    assert SPEC.x_to_col(0.0) == pytest.approx(5.0)
    # Top: row 0 is the far side (+Z); front: row 0 is the top of the window.
    assert SPEC.row_to_a("top", 0.0) == pytest.approx(1.0)
    assert SPEC.row_to_a("top", 10.0) == pytest.approx(-1.0)
    assert SPEC.row_to_a("front", 10.0) == pytest.approx(0.0)
    assert SPEC.row_to_a("front", 0.0) == pytest.approx(1.0)
    assert SPEC.pixel_size("top") == (0.1, 0.2)
    with pytest.raises(LayoutError, match="view"):
        SPEC.pixel_size("side")


@given(st.floats(-5, 5), st.floats(-5, 5), st.sampled_from(["top", "front"]))
def test_conversion_round_trip(x, a, view):
    u, v = SPEC.to_pixels(view, x, a)
    x2, a2 = SPEC.to_metres(view, u, v)
    assert x2 == pytest.approx(x, abs=1e-9) and a2 == pytest.approx(a, abs=1e-9)


def test_fill_rect_axis_aligned_exact_cells():
    slot = np.zeros((10, 10), np.uint8)
    # x in [-0.2, 0.2) -> columns whose centres are -0.15..0.15: 3..6; h in [0, 0.3) -> rows 7..9.
    n = fill_rect(slot, SPEC, "front", centre=(0.0, 0.15), size=(0.4, 0.3), value=BOX)
    assert n == 12
    rows, cols = np.nonzero(slot)
    assert set(cols) == {3, 4, 5, 6} and set(rows) == {7, 8, 9}


def test_fill_rect_shared_edge_claims_each_pixel_once():
    a = np.zeros((10, 10), np.uint8)
    b = np.zeros((10, 10), np.uint8)
    fill_rect(a, SPEC, "top", (-0.25, 0.0), (0.5, 2.0), 1)
    fill_rect(b, SPEC, "top", (0.25, 0.0), (0.5, 2.0), 1)
    assert not (a & b).any() and (a | b).all()


def test_fill_rect_yaw_quarter_turn_swaps_axes_and_clips():
    spec = LayoutSpec(num_slots=1, size=64, x_extent=2.0, z_extent=2.0, h_extent=1.0)
    s0 = np.zeros((64, 64), np.uint8)
    s1 = np.zeros((64, 64), np.uint8)
    fill_rect(s0, spec, "top", (0.1, 0.05), (0.8, 0.4), 2)
    fill_rect(s1, spec, "top", (0.1, 0.05), (0.4, 0.8), 2, yaw=math.pi / 2)
    assert abs(int(s0.sum()) - int(s1.sum())) <= 2 * 2 * 20  # same area up to edge pixels
    assert np.ptp(np.nonzero(s0)[1]) > np.ptp(np.nonzero(s0)[0])
    assert np.ptp(np.nonzero(s1)[1]) > np.ptp(np.nonzero(s1)[0])
    # Mostly outside the extent: only the inside part is painted, no error.
    s2 = np.zeros((64, 64), np.uint8)
    assert fill_rect(s2, spec, "top", (1.0, 0.0), (0.5, 0.5), 1, yaw=0.3) > 0
    assert fill_rect(s2, spec, "top", (9.0, 0.0), (0.5, 0.5), 1) == 0


@settings(max_examples=50, deadline=None)
@given(st.floats(0.05, 0.6), st.floats(0.05, 0.6), st.floats(-math.pi, math.pi))
def test_fill_rect_area_converges(w, l, yaw):
    spec = LayoutSpec(num_slots=1, size=256, x_extent=2.0, z_extent=2.0, h_extent=1.0)
    slot = np.zeros((256, 256), np.uint8)
    n = fill_rect(slot, spec, "top", (0.0, 0.0), (w, l), 1, yaw=yaw)
    px = 2.0 / 256
    expected = w * l / px**2
    perimeter_pixels = 2 * (w + l) / px
    assert abs(n - expected) <= perimeter_pixels + 4


def test_native_and_frame_codecs(tmp_path):
    rng = np.random.default_rng(0)
    top = rng.integers(0, 3, SPEC.shape, dtype=np.uint8)
    front = rng.integers(0, 3, SPEC.shape, dtype=np.uint8)
    save_native(tmp_path / "t.npy", top)
    assert np.array_equal(load_native(tmp_path / "t.npy", SPEC), top)
    vis = np.arange(10) < 7
    save_frame(tmp_path / "000000.npz", FrameLayouts(top, front, vis))
    f = load_frame(tmp_path / "000000.npz", SPEC)
    assert np.array_equal(f.top, top) and np.array_equal(f.front, front) and np.array_equal(f.visible, vis)
    # Same arrays -> same bytes.
    assert npz_bytes(top=top, front=front) == npz_bytes(front=front, top=top)
    with pytest.raises(LayoutError, match="does not match the layout spec"):
        load_native(tmp_path / "t.npy", LayoutSpec(num_slots=3, size=10))
    np.save(tmp_path / "bad.npy", top.astype(np.int32))
    with pytest.raises(LayoutError, match="dtype must be uint8"):
        load_native(tmp_path / "bad.npy")
    np.save(tmp_path / "big.npy", np.full(SPEC.shape, 7, np.uint8))
    with pytest.raises(LayoutError, match="class ids"):
        load_native(tmp_path / "big.npy")


def test_pickled_npy_is_refused_and_not_executed(tmp_path):

    marker = tmp_path / "pwned"

    class Evil:
        def __reduce__(self):
            return (open, (str(marker), "w"))

    arr = np.empty(1, dtype=object)
    arr[0] = Evil()
    with open(tmp_path / "evil.npy", "wb") as f:
        np.lib.format.write_array(f, arr, allow_pickle=True)
    with pytest.raises(LayoutError, match="pickled"):
        load_npy(tmp_path / "evil.npy")
    assert not marker.exists()
    (tmp_path / "trunc.npy").write_bytes(b"\x93NUMPY\x01\x00")
    with pytest.raises(LayoutError, match="trunc.npy"):
        load_npy(tmp_path / "trunc.npy")
    with pytest.raises(LayoutError, match="file not found"):
        load_npy(tmp_path / "missing.npy")


def test_racklay_codec(tmp_path):
    arr = np.array([[[0, 1], [2, 1]]], np.uint8)
    assert to_racklay(arr).tolist() == [[[0, 115], [255, 115]]]
    assert np.array_equal(from_racklay(to_racklay(arr)), arr)
    save_racklay(tmp_path / "r.npy", arr)
    assert np.array_equal(np.load(tmp_path / "r.npy"), to_racklay(arr))
    assert np.array_equal(load_racklay(tmp_path / "r.npy"), arr)
    with pytest.raises(LayoutError, match="0, 115 or 255"):
        from_racklay(np.array([[[0, 114]]], np.uint8))


def test_layout_folder(tmp_path):
    folder = LayoutFolder.create(tmp_path / "lay", SPEC)
    z = np.zeros(SPEC.shape, np.uint8)
    folder.write(3, FrameLayouts(z, z))
    folder.write(1, FrameLayouts(z, z + 1))
    assert folder.indices() == [1, 3]
    assert LayoutFolder(tmp_path / "lay").read(1).front.max() == 1
    with pytest.raises(LayoutError, match="different layout spec"):
        LayoutFolder.create(tmp_path / "lay", LayoutSpec())
    with pytest.raises(LayoutError, match="shape"):
        folder.write(4, FrameLayouts(np.zeros((3, 10, 10), np.uint8), np.zeros((3, 10, 10), np.uint8)))
    with pytest.raises(LayoutError, match="not found"):
        LayoutFolder(tmp_path / "nope")


def test_metrics_hand_computed():
    gt = np.zeros((2, 2, 4), np.uint8)  # R=2 slots of 2x4 (shape check is only R,D,D-like)
    gt = np.zeros((2, 4, 4), np.uint8)
    pred = np.zeros((2, 4, 4), np.uint8)
    # Slot 0: gt shelf 8 px, pred shelf 6 of them + 2 extra -> tp 6, fp 2, fn 2.
    gt[0, :2, :] = SHELF
    pred[0, :2, :3] = SHELF
    pred[0, 2, :2] = SHELF
    # Slot 0 box: gt 2 px, predicted none -> IoU 0, precision skipped.
    gt[0, 3, :2] = BOX
    # Slot 1: empty gt; pred 1 box px -> box IoU 0, precision 0; shelf both empty -> skipped.
    pred[1, 0, 0] = BOX
    m = LayoutMetrics()
    m.update(pred, gt, "top")
    r = m.result()["top"]
    assert r["rack"]["miou"] == pytest.approx(6 / 10)
    assert r["rack"]["map"] == pytest.approx(6 / 8)
    assert r["rack"]["pairs_iou"] == 1
    assert r["box"]["miou"] == pytest.approx(0.0)
    assert r["box"]["pairs_iou"] == 2 and r["box"]["pairs_precision"] == 1
    assert r["box"]["map"] == pytest.approx(0.0)
    assert r["box"]["pooled_iou"] == pytest.approx(0 / 3)
    assert math.isnan(m.result()["front"]["rack"]["miou"])
    assert "mIoU" in format_table(m.result())


def test_metrics_valid_columns_and_pooling():
    gt = np.zeros((1, 4, 4), np.uint8)
    pred = np.zeros((1, 4, 4), np.uint8)
    gt[0, :, :] = SHELF
    pred[0, :, :2] = SHELF  # right half missed
    m_all, m_vis = LayoutMetrics(), LayoutMetrics()
    m_all.update(pred, gt, "front")
    m_vis.update(pred, gt, "front", valid=np.array([True, True, False, False]))
    assert m_all.result()["front"]["rack"]["miou"] == pytest.approx(0.5)
    assert m_vis.result()["front"]["rack"]["miou"] == pytest.approx(1.0)
    # Pooled differs from per-pair mean when pairs differ in size.
    m = LayoutMetrics()
    big = np.zeros((2, 1, 4, 4), np.uint8)
    big[0, 0] = SHELF
    pb = big.copy()
    small = np.zeros((2, 1, 4, 4), np.uint8)
    small[1, 0, 0, 0] = SHELF
    pred2 = np.concatenate([pb[:1], np.zeros((1, 1, 4, 4), np.uint8)])
    gt2 = np.concatenate([big[:1], small[1:]])
    m.update(pred2, gt2, "top")
    r = m.result()["top"]["rack"]
    assert r["miou"] == pytest.approx(0.5)
    assert r["pooled_iou"] == pytest.approx(16 / 17)
    with pytest.raises(LayoutError, match="differs"):
        m.update(pred2, gt2[:1], "top")


def test_intrinsics_and_visible_columns():
    k = Intrinsics.from_fov(256, 256, 60.0)
    assert k.hfov_deg == pytest.approx(60.0)
    spec = LayoutSpec()
    vis = k.visible_columns(spec, 2.6)
    assert vis.mean() == pytest.approx(1.0, abs=0.02)
    near = k.visible_columns(spec, 1.5)
    assert near.sum() < vis.sum() and near[spec.size // 2] and not near[0]
    assert Intrinsics.from_dict(k.to_dict()) == k
    with pytest.raises(LayoutError, match="lack"):
        Intrinsics.from_dict({"fx": 1})
    with pytest.raises(LayoutError, match="focal"):
        Intrinsics(0, 1, 0, 0, 10, 10)
    pix = k.project(np.array([[0.0, 0.0, 2.0], [1.0, 0.0, 2.0]]))
    assert pix[0].tolist() == [128.0, 128.0] and pix[1, 0] > 128


def test_atomic_write_gives_normal_permissions_and_leaves_no_temp(tmp_path):
    import os
    import stat

    from layouts.fileio import atomic_write_json, load_json

    atomic_write_json(tmp_path / "a.json", {"b": 1, "a": 2})
    assert load_json(tmp_path / "a.json") == {"a": 2, "b": 1}
    assert (tmp_path / "a.json").read_text().startswith('{\n  "a": 2')
    mode = stat.S_IMODE(os.stat(tmp_path / "a.json").st_mode)
    assert mode & 0o044 == 0o044 & ~_current_umask()
    assert [p.name for p in tmp_path.iterdir()] == ["a.json"]


def _current_umask() -> int:
    import os

    m = os.umask(0)
    os.umask(m)
    return m
