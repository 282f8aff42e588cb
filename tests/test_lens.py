"""Lens distortion (layouts.lens): the OpenCV model, images resampled through it, footage undistorted by `run`."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from layouts.camera import Intrinsics
from layouts.canonical import FILL_RGB
from layouts.errors import InputError, LayoutError
from layouts.lens import Lens, covering_intrinsics, distort_image, undistort_image
from mvracklay.camera import load_lens, resolve_lens
from mvracklay.frames import open_source

INTR = Intrinsics(300.0, 280.0, 120.3, 131.7, 256, 240)
BARREL = Lens(k1=-0.15, k2=0.03, p1=0.001, p2=-0.002)


def test_the_model_is_opencvs():
    x, y = np.array([0.3]), np.array([-0.2])
    xd, yd = Lens(k1=-0.2, k2=0.05, k3=0.01).distort(x, y)
    r2 = 0.13
    radial = 1 - 0.2 * r2 + 0.05 * r2**2 + 0.01 * r2**3
    assert np.allclose([xd[0], yd[0]], [0.3 * radial, -0.2 * radial])
    xd, yd = Lens(p1=0.01, p2=-0.02).distort(x, y)
    assert np.allclose(xd, 0.3 + 2 * 0.01 * 0.3 * -0.2 - 0.02 * (r2 + 2 * 0.09))
    assert np.allclose(yd, -0.2 + 0.01 * (r2 + 2 * 0.04) + 2 * -0.02 * 0.3 * -0.2)


@given(st.floats(-0.6, 0.6), st.floats(-0.45, 0.45), st.floats(-0.3, 0.1), st.floats(-0.05, 0.05))
def test_undistort_inverts_distort(x, y, k1, p1):
    lens = Lens(k1=k1, k2=0.02, p1=p1, p2=-p1 / 2)
    xu, yu = lens.undistort(*lens.distort(np.array(x), np.array(y)))
    assert abs(float(xu) - x) < 1e-6 and abs(float(yu) - y) < 1e-6


def test_lens_checks_its_coefficients():
    with pytest.raises(LayoutError, match="k1 must be a finite number"):
        Lens(k1=float("nan"))
    with pytest.raises(LayoutError, match="p2 = 5.0 is beyond"):
        Lens(p2=5.0)
    assert Lens.from_dict({"fx": 1.0}) is None and Lens.from_dict({"k2": 0.1}) == Lens(k2=0.1)
    with pytest.raises(LayoutError, match="cam.json: lens k1"):
        Lens.from_dict({"k1": "x"}, "cam.json")


def _ramp(intr: Intrinsics) -> np.ndarray:
    yy, xx = np.mgrid[0 : intr.height, 0 : intr.width]
    return np.stack([xx, yy, yy], -1).astype(np.uint8)


def test_undistorted_pixels_sample_where_the_lens_put_them():
    out = undistort_image(_ramp(INTR), INTR, BARREL).astype(float)
    yy, xx = np.mgrid[0 : INTR.height, 0 : INTR.width]
    sx, sy = BARREL.distort((xx + 0.5 - INTR.cx) / INTR.fx, (yy + 0.5 - INTR.cy) / INTR.fy)
    su, sv = sx * INTR.fx + INTR.cx - 0.5, sy * INTR.fy + INTR.cy - 0.5  # pixel index coordinates
    inside = (su > 1) & (su < INTR.width - 2) & (sv > 1) & (sv < INTR.height - 2)
    assert inside.mean() > 0.8
    # bilinear on a ramp: exact up to the 8-bit rounding (0.5) and the tiles' bilinear map (< 0.15)
    assert np.abs(out[..., 0] - su)[inside].max() < 0.65 and np.abs(out[..., 1] - sv)[inside].max() < 0.65
    assert abs((out[..., 0] - su)[inside].mean()) < 0.05  # no half-pixel shift
    img = _ramp(INTR)
    assert np.array_equal(undistort_image(img, INTR, Lens()), img)


def test_a_straight_board_bent_by_the_lens_is_straight_again():
    img = np.full((INTR.height, INTR.width, 3), 200, np.uint8)
    img[30:34] = 20  # a dark horizontal edge near the top, as a shelf board
    bent = distort_image(img, INTR, BARREL, fill=(200, 200, 200))

    def edge_rows(a: np.ndarray) -> np.ndarray:
        dark = a[..., 0] < 110
        return np.array([np.flatnonzero(dark[:, c]).mean() for c in range(20, INTR.width - 20, 10)])

    assert np.ptp(edge_rows(bent)) >= 2.0  # the lens bends it by pixels
    assert np.ptp(edge_rows(undistort_image(bent, INTR, BARREL))) < 0.6


def test_covering_intrinsics_zoom_a_barrel_lens_until_no_fill_is_left():
    pure = np.full((INTR.height, INTR.width, 3), 90, np.uint8)
    cover = covering_intrinsics(INTR, BARREL)
    assert cover.fx / INTR.fx == pytest.approx(cover.fy / INTR.fy) and cover.fx > INTR.fx * 1.02
    assert (distort_image(pure, INTR, BARREL, fill=(0, 0, 0)) == 0).all(-1).any()  # unzoomed: fill at the border
    assert not (distort_image(pure, INTR, BARREL, fill=(0, 0, 0), out=cover) == 0).all(-1).any()
    assert covering_intrinsics(INTR, Lens(k1=0.1)) == INTR  # a pincushion sees inside its pinhole


def test_run_undistorts_footage_through_the_camera_files_lens(tiny_dataset: Path, tmp_path: Path):
    seq = tiny_dataset / "seq_00000"
    src = open_source(seq)
    intr = src.intrinsics
    cam = tmp_path / "cam.json"
    cam.write_text(json.dumps({**intr.to_dict(), "k1": -0.2, "p1": 0.002}))
    lens = load_lens(cam)
    assert lens == Lens(k1=-0.2, p1=0.002) and resolve_lens(src, cam) == lens and resolve_lens(src) is None
    raw = next(src.frames(1))
    got = next(src.frames(1, undistort=(intr, lens)))
    assert np.array_equal(got, undistort_image(raw, intr, lens, FILL_RGB)) and not np.array_equal(got, raw)
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({**intr.to_dict(), "k1": 9}))
    with pytest.raises(InputError, match=r"bad.json: k1: Input should be less than or equal to 2 \(got 9\)"):
        load_lens(bad)


def test_a_sequence_whose_record_gives_a_lens_is_undistorted_unasked(tiny_dataset: Path, tmp_path: Path):
    import shutil

    seq = tmp_path / "seq"
    shutil.copytree(tiny_dataset / "seq_00000", seq)
    meta = json.loads((seq / "meta.json").read_text())
    meta["intrinsics"]["k1"] = -0.2  # as a calibrated camera's record gives it
    (seq / "meta.json").write_text(json.dumps(meta))
    src = open_source(seq)
    assert src.lens == Lens(k1=-0.2) and resolve_lens(src) == Lens(k1=-0.2)  # run undistorts it unasked
    assert open_source(tiny_dataset / "seq_00000").lens is None


def test_predict_takes_the_lens_beside_its_intrinsics(tiny_dataset: Path, tiny_checkpoint: Path, tmp_path: Path):
    from mvracklay.camera import parse_camera_option
    from mvracklay.cli import main

    seq = tiny_dataset / "seq_00000"
    intr = open_source(seq).intrinsics
    cam = tmp_path / "cam.json"
    cam.write_text(json.dumps({"intrinsics": {**intr.to_dict(), "k1": -0.1}}))
    assert parse_camera_option(str(cam), 128, 128) == (intr, Lens(k1=-0.1))
    assert parse_camera_option("100,100,64,64", 128, 128)[1] is None
    out = tmp_path / "lay"
    argv = ["predict", str(seq), "--checkpoint", str(tiny_checkpoint), "--out", str(out), "--camera", str(cam)]
    assert main([*argv, "--threads", "1", "--quiet"]) == 0
    assert len(list(out.glob("*.npz"))) == 8
    cam.write_text(json.dumps({**intr.to_dict(), "k3": float("inf")}))
    with pytest.raises(InputError, match="--camera .*cam.json: k3: Input should be a finite number"):
        parse_camera_option(str(cam), 128, 128)


def test_bench_lens_prints_a_cost_per_frame_size():
    script = Path(__file__).resolve().parents[1] / "benchmarks" / "bench_lens.py"
    done = subprocess.run([sys.executable, str(script), "--repeats", "1"], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    lines = [line for line in done.stdout.splitlines() if "ms per frame" in line]
    assert [line.split(":")[0] for line in lines] == ["256x256", "640x360", "1280x720", "1920x1080"]
    assert "ms per frame, 640x360 out" in lines[-1]  # 1080p shrunk to 640 first
    bad = subprocess.run([sys.executable, str(script), "--repeats", "0"], capture_output=True, text=True)
    assert bad.returncode != 0 and "--repeats" in bad.stderr


def test_undistort_frame_shrinks_wide_footage_first():
    from PIL import Image

    from layouts.lens import FRAME_MAX_WIDTH, undistort_frame

    wide = Intrinsics.from_fov(1280, 720, 60.0)
    rgb = np.random.default_rng(1).integers(0, 256, (720, 1280, 3), dtype=np.uint8)
    got = undistort_frame(rgb, wide, BARREL, FILL_RGB)
    assert got.shape == (360, FRAME_MAX_WIDTH, 3)
    small = np.asarray(Image.fromarray(rgb).resize((640, 360), Image.BILINEAR, reducing_gap=None))
    assert np.array_equal(got, undistort_image(small, wide.scaled(640, 360), BARREL, FILL_RGB))
    img = _ramp(INTR)
    assert np.array_equal(undistort_frame(img, INTR, BARREL, FILL_RGB), undistort_image(img, INTR, BARREL, FILL_RGB))
