"""A rolled, pitched or yawed camera: levelled in the canonical warp, its angles read from rack images (`network.inference.roll`)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from layouts import Intrinsics, LayoutError
from layouts.canonical import FILL_RGB, CanonicalView
from layouts.errors import InputError
from mvracklay.cli import main
from network.inference import angle_reading
from network.inference import roll as roll_mod
from network.inference.angle_reading import estimate_roll, estimate_tilt
from network.inference.roll import (
    CameraLeveller,
    angle_warnings,
    check_angle,
    resolve_angles,
    roll_warning,
    tilt_frame,
    turn_frame,
)
from waresynth.dataset import open_dataset

VIEW = CanonicalView(96, 96, 3.0)


def _pattern(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Front-plane stripes: red changes every 0.25 m along X, green every 0.2 m along Y."""
    r = np.where(np.floor(x / 0.25) % 2 == 0, 220, 30)
    g = np.where(np.floor(y / 0.2) % 2 == 0, 200, 40)
    return np.stack(np.broadcast_arrays(r, g, np.full_like(r, 90)), -1).astype(np.uint8)


def _rolled_render(
    intr: Intrinsics, distance: float, roll_deg: float, pitch_deg: float = 0.0, yaw_deg: float = 0.0
) -> np.ndarray:
    """What a camera rolled ``roll_deg`` (content turned counter-clockwise), pitched ``pitch_deg`` (tilted
    up) and yawed ``yaw_deg`` (turned right) sees of the stripes on the front plane ``distance`` ahead of it."""
    u = (np.arange(intr.width) + 0.5 - intr.cx) / intr.fx
    v = (np.arange(intr.height) + 0.5 - intr.cy) / intr.fy
    xr, yr = np.meshgrid(u, v)
    c, s = math.cos(math.radians(roll_deg)), math.sin(math.radians(roll_deg))
    x, y = c * xr - s * yr, s * xr + c * yr  # turned back about the optical axis
    c, s = math.cos(math.radians(pitch_deg)), math.sin(math.radians(pitch_deg))
    y, z = c * y - s, s * y + c  # the ray (x, y, 1) tilted up
    c, s = math.cos(math.radians(yaw_deg)), math.sin(math.radians(yaw_deg))
    x, z = c * x + s * z, c * z - s * x  # then turned right: the level camera's ray
    return _pattern(x / z * distance, y / z * distance)


def _canonical_truth(view: CanonicalView) -> tuple[np.ndarray, np.ndarray]:
    m = view.metres_per_pixel
    x = (np.arange(view.width) + 0.5 - view.width / 2) * m
    y = (np.arange(view.height) + 0.5 - view.height / 2) * m
    far_x = np.abs(x / 0.25 - np.round(x / 0.25)) * 0.25 > 1.5 * m
    far_y = np.abs(y / 0.2 - np.round(y / 0.2)) * 0.2 > 1.5 * m
    return _pattern(x[None, :], y[:, None]), far_y[:, None] & far_x[None, :]


@pytest.mark.parametrize(
    "intr, roll, pitch, yaw",
    [
        (Intrinsics.from_fov(160, 160, 70.0), 7.0, 0.0, 0.0),
        (Intrinsics.from_fov(200, 150, 75.0), -12.0, 0.0, 0.0),
        (Intrinsics(300.0, 330.0, 150.0, 110.0, 320, 240), 4.0, 0.0, 0.0),  # off-centre, non-square pixels
        (Intrinsics.from_fov(160, 160, 70.0), 0.0, 6.0, 0.0),  # tilted up: a homography
        (Intrinsics(300.0, 330.0, 150.0, 110.0, 320, 240), -3.0, -5.0, 0.0),
        (Intrinsics.from_fov(160, 160, 70.0), 0.0, 0.0, 8.0),  # turned right
        (Intrinsics(300.0, 330.0, 150.0, 110.0, 320, 240), 2.0, 4.0, -6.0),  # all three
    ],
)
def test_a_rotated_camera_is_levelled_onto_the_canonical_pixels(intr, roll, pitch, yaw):
    img = _rolled_render(intr, 2.6, roll, pitch, yaw)
    got = VIEW.warp(img, intr, 2.6, roll_deg=roll, pitch_deg=pitch, yaw_deg=yaw)
    want, far = _canonical_truth(VIEW)
    valid = VIEW.valid_mask(intr, 2.6, roll_deg=roll, pitch_deg=pitch, yaw_deg=yaw)
    inner = valid & far
    assert inner.sum() > 1000
    assert np.abs(got[inner].astype(int) - want[inner].astype(int)).max() <= 2
    assert (got[~valid] == FILL_RGB).all()
    # the same image warped as if level puts the stripes elsewhere
    level = VIEW.warp(img, intr, 2.6)
    assert np.abs(level[inner].astype(int) - want[inner].astype(int)).max() > 100


def test_roll_zero_is_the_separable_warp_and_bad_rolls_are_refused():
    intr = Intrinsics.from_fov(128, 96, 60.0)
    img = np.random.default_rng(0).integers(0, 256, (96, 128, 3), dtype=np.uint8)
    assert np.array_equal(VIEW.warp(img, intr, 2.6, roll_deg=0.0), VIEW.warp(img, intr, 2.6))
    for bad in (float("nan"), 50.0, True, "3"):
        with pytest.raises(LayoutError, match="roll"):
            VIEW.warp(img, intr, 2.6, roll_deg=bad)


def _frames(tiny_dataset: Path, n: int = 4) -> tuple[list[np.ndarray], Intrinsics]:
    seq = open_dataset(tiny_dataset).sequences()[0]
    return [seq.rgb(i) for i in range(n)], seq.intrinsics


def _turn(rgb: np.ndarray, deg: float, intr: Intrinsics) -> np.ndarray:
    return turn_frame(rgb, deg, intr.cx, intr.cy)


def test_turned_frames_are_what_the_rolled_warp_levels(tiny_dataset):
    """`turn_frame` (the benchmarks' rolled camera) turns the way the warp's roll convention undoes."""
    (rgb, *_), intr = _frames(tiny_dataset, 1)
    view = CanonicalView(64, 64, 3.0)
    level = view.warp(rgb, intr, 2.6).astype(int)
    back = view.warp(_turn(rgb, 6.0, intr), intr, 2.6, roll_deg=6.0).astype(int)
    wrong = view.warp(_turn(rgb, 6.0, intr), intr, 2.6, roll_deg=-6.0).astype(int)
    inside = view.valid_mask(intr, 2.6, roll_deg=6.0)
    inside[:8], inside[-8:], inside[:, :8], inside[:, -8:] = False, False, False, False
    assert np.median(np.abs(back - level)[inside]) <= 3
    assert np.abs(back - level)[inside].mean() < 0.5 * np.abs(wrong - level)[inside].mean()


@pytest.mark.parametrize("axis", ["pitch", "yaw"])
def test_tilted_frames_are_what_the_pitched_or_yawed_warp_levels(tiny_dataset, axis):
    """`tilt_frame` (the benchmark's pitched / yawed camera) turns the way the warp's convention undoes."""
    (rgb, *_), intr = _frames(tiny_dataset, 1)
    view = CanonicalView(64, 64, 3.0)
    level = view.warp(rgb, intr, 2.6).astype(int)
    tilted = tilt_frame(rgb, intr, **{f"{axis}_deg": 6.0})
    back = view.warp(tilted, intr, 2.6, **{f"{axis}_deg": 6.0}).astype(int)
    wrong = view.warp(tilted, intr, 2.6, **{f"{axis}_deg": -6.0}).astype(int)
    inside = view.valid_mask(intr, 2.6, **{f"{axis}_deg": 6.0}) & view.valid_mask(intr, 2.6, **{f"{axis}_deg": -6.0})
    inside[:8], inside[-8:], inside[:, :8], inside[:, -8:] = False, False, False, False
    assert inside.sum() > 1000
    assert np.median(np.abs(back - level)[inside]) <= 3
    assert np.abs(back - level)[inside].mean() < 0.5 * np.abs(wrong - level)[inside].mean()
    assert (tilt_frame(rgb, intr) == rgb).mean() > 0.99  # no tilt: the frame itself


@pytest.mark.parametrize("deg", [-9.0, -2.5, 0.0, 1.0, 4.0])
def test_the_roll_of_a_rendered_rack_frame_is_read(tiny_dataset, deg):
    frames, intr = _frames(tiny_dataset)
    got = []
    for rgb in frames:
        roll, strength = estimate_roll(_turn(rgb, deg, intr) if deg else rgb)
        assert abs(roll - deg) < 1.0, (roll, deg)  # one 128x128 frame; a sequence averages its frames
        assert strength > 2.0
        got.append(roll)
    assert abs(np.mean(got) - deg) < 0.6


def test_no_edges_reads_level_with_no_strength():
    got, strength = estimate_roll(np.full((64, 80, 3), 90, np.uint8))
    assert got == 0.0 and strength == 0.0
    with pytest.raises(InputError, match="uint8"):
        estimate_roll(np.zeros((64, 80, 3), np.float32))
    with pytest.raises(InputError, match="max_deg"):
        estimate_roll(np.zeros((64, 80, 3), np.uint8), max_deg=60)


def test_leveller_follows_the_frames_and_reads_each_once(tiny_dataset, monkeypatch):
    frames, intr = _frames(tiny_dataset)
    calls = []
    real = angle_reading.estimate_roll

    def counted(rgb, max_deg, prior_deg=0.0):
        calls.append(prior_deg)
        return real(rgb, max_deg, prior_deg)

    monkeypatch.setattr(angle_reading, "estimate_roll", counted)
    lev = CameraLeveller("auto")
    turned = [_turn(f, 3.0, intr) for f in frames]
    got = [lev.angles(i, f)[0] for i, f in enumerate(turned)]
    assert lev.angles(len(turned) - 1, turned[-1])[0] == got[-1]  # asked again: not read again
    assert (
        len(calls) == len(turned) and calls[0] == 0.0 and abs(calls[-1] - 3.0) < 0.5
    )  # read levelled by the roll so far
    assert all(abs(g - 3.0) < 0.5 for g in got) and lev.rolls == got
    fixed = CameraLeveller(-2.0)
    assert [fixed.angles(i, f)[0] for i, f in enumerate(frames)] == [-2.0] * len(frames)
    assert len(calls) == len(turned)  # a known roll reads nothing


@pytest.mark.parametrize("roll, pitch, yaw", [(0.0, 0.0, 3.0), (0.0, 4.0, -3.0), (2.0, -3.0, 5.0)])
def test_the_yaw_of_a_stepped_edge_is_read_from_its_position_not_its_gradients(roll, pitch, yaw):
    """Stripes rendered without antialiasing: their edges are staircases whose gradients are exactly
    level between the steps, so only fitting each edge's pixel positions reads the convergence."""
    intr = Intrinsics.from_fov(128, 128, 60.0)
    img = _rolled_render(intr, 2.7, roll, pitch, yaw)
    got, strength = estimate_tilt(img, intr, read=(False, False, True))
    assert abs(got[2] - yaw) < 0.3 and got[0] == 0.0 and got[1] == 0.0  # only the yaw is read
    assert strength[2] > 0 and strength[0] == strength[1] == 0.0


@pytest.mark.parametrize("pitch, yaw", [(0.0, 0.0), (0.0, 4.0), (0.0, -4.0), (4.0, 0.0), (-4.0, 0.0), (3.0, -3.0)])
def test_the_pitch_and_yaw_of_rendered_rack_frames_are_read_over_a_sequence(tiny_dataset, pitch, yaw):
    seqs = open_dataset(tiny_dataset).sequences()[:2]  # the third shows its uprights only near the centre
    for seq in seqs:
        intr = seq.intrinsics
        lev = CameraLeveller("auto", "auto", "auto")
        for i in range(seq.num_frames):
            got = lev.angles(i, tilt_frame(seq.rgb(i), intr, pitch, yaw), intr)
        assert abs(got[0]) < 0.5 and abs(got[1] - pitch) < 1.0 and abs(got[2] - yaw) < 1.0, (seq.name, got)
        assert set(lev.read_angles()) == {"roll", "pitch", "yaw"} and len(lev.yaws) == seq.num_frames


def test_the_leveller_reads_only_what_is_not_given(tiny_dataset, monkeypatch):
    frames, intr = _frames(tiny_dataset)
    priors = []
    real = angle_reading.estimate_tilt

    def counted(rgb, intr, prior, read, max_deg):
        priors.append((prior, read))
        return real(rgb, intr, prior, read, max_deg)

    monkeypatch.setattr(angle_reading, "estimate_tilt", counted)
    lev = CameraLeveller(1.5, -2.0, "auto")
    got = [lev.angles(i, tilt_frame(f, intr, yaw_deg=4.0), intr) for i, f in enumerate(frames)]
    assert all(g[:2] == (1.5, -2.0) for g in got) and abs(got[-1][2] - 4.0) < 1.5
    assert len(priors) == len(frames) and all(r == (False, False, True) for _, r in priors)
    assert priors[0][0] == (1.5, -2.0, 0.0) and priors[-1][0][2] == got[-2][2]  # levelled by the yaw so far
    assert lev.read_angles() == {"yaw": [g[2] for g in got]}
    assert lev.angles(len(frames) - 1, frames[-1], intr) == got[-1] and len(priors) == len(frames)
    with pytest.raises(InputError, match="intrinsics"):
        CameraLeveller(0.0, "auto").angles(0, frames[0])
    fixed = CameraLeveller(0.0, 3.0, -1.0)
    assert [fixed.angles(i, f) for i, f in enumerate(frames)] == [(0.0, 3.0, -1.0)] * len(frames)
    assert fixed.read_angles() == {} and len(priors) == len(frames)  # known angles read nothing


def test_the_predictor_reads_the_start_ahead_when_it_reads_a_yaw(tiny_dataset, tiny_checkpoint, monkeypatch):
    from network.checkpoint import load_model
    from network.inference.predictor import Predictor

    seq = open_dataset(tiny_dataset).sequences()[1]
    intr = seq.intrinsics
    frames = [tilt_frame(seq.rgb(i), intr, yaw_deg=4.0) for i in range(seq.num_frames)]
    calls = []
    real = angle_reading.estimate_tilt

    def counted(rgb, intr, prior, read, max_deg):
        calls.append(prior[2])
        return real(rgb, intr, prior, read, max_deg)

    monkeypatch.setattr(angle_reading, "estimate_tilt", counted)
    model, _ = load_model(tiny_checkpoint)
    pred = Predictor(model, lambda i: (intr, 2.7), roll=0.0, pitch=0.0, yaw="auto")
    outs = list(pred.stream(frames))
    n = len(frames)
    assert len(outs) == n and n <= roll_mod.PRIME_FRAMES
    assert len(calls) == 2 * n and calls[0] == 0.0  # all read ahead, then each read again as it comes
    assert abs(calls[n] - 4.0) < 1.0  # the first frame is levelled by what the start showed
    assert len(pred.leveller.yaws) == n and abs(pred.leveller.yaws[0] - 4.0) < 1.0
    rolls = []
    real_roll = angle_reading.estimate_roll
    monkeypatch.setattr(
        angle_reading, "estimate_roll", lambda rgb, m, prior_deg: rolls.append(1) or real_roll(rgb, m, prior_deg)
    )
    list(Predictor(model, lambda i: (intr, 2.7), roll="auto", pitch=0.0, yaw=0.0).stream(frames))
    assert len(rolls) == n  # a roll alone is read frame by frame, nothing ahead


def test_a_flat_or_noisy_image_reads_nothing_and_a_yaw_at_the_limit_is_warned_about():
    intr = Intrinsics.from_fov(80, 64, 60.0)
    got, strength = estimate_tilt(np.full((64, 80, 3), 90, np.uint8), intr, prior=(0.0, 1.0, 2.0))
    assert got.tolist() == [0.0, 1.0, 2.0] and strength.tolist() == [0.0, 0.0, 0.0]
    with pytest.raises(InputError, match="prior"):
        estimate_tilt(np.full((64, 80, 3), 90, np.uint8), intr, prior=(0.0, 1.0))
    rng = np.random.default_rng(0)
    for img in (rng.integers(0, 256, (64, 80, 3), dtype=np.uint8), np.full((64, 80, 3), 90, np.uint8)):
        lev = CameraLeveller("auto", "auto", "auto")
        lev.prime([(img, intr)] * 3)
        assert lev.angles(0, img, intr) == (0.0, 0.0, 0.0)  # noise has edges but no structure: nothing read
        alone = CameraLeveller("auto")
        assert alone.angles(0, img) == (0.0, 0.0, 0.0)
    assert angle_warnings({"roll": [1.0], "yaw": [2.0, -3.0]}) == []
    said = angle_warnings({"roll": [1.0], "yaw": [2.0, 10.0]})
    assert len(said) == 1 and "yaw" in said[0] and "--yaw DEG" in said[0]
    # frames too small to read a pitch or yaw surely: said once, naming what was read
    assert angle_warnings({"roll": [1.0], "yaw": [2.0]}, width=256) == []
    assert angle_warnings({"roll": [1.0]}, width=128) == []
    said = angle_warnings({"pitch": [0.5], "yaw": [2.0]}, width=128)
    assert len(said) == 1 and "128 px wide" in said[0] and "--pitch DEG and --yaw DEG" in said[0]


def test_roll_arguments_are_checked():
    assert check_angle("auto") == "auto" and check_angle("2.5") == 2.5 and check_angle(None) is None
    assert resolve_angles(None, None, None, (0.0, 0.0, 0.0)) == (0.0, 0.0, 0.0)
    assert resolve_angles(None, None, None, None) == ("auto", "auto", "auto")
    assert resolve_angles("-3", "auto", 1, (0.0, 0.0, 0.0)) == (-3.0, "auto", 1.0)
    with pytest.raises(InputError, match="--pitch"):
        resolve_angles(None, "up", None, (0.0, 0.0, 0.0))
    for bad, msg in (("abc", "'auto' or a number"), (60, "within"), (float("inf"), "within"), (True, "number")):
        with pytest.raises(InputError, match=msg):
            check_angle(bad, "--roll")
    for bad in ("level", 50, float("nan"), True):
        with pytest.raises(InputError, match="--yaw"):
            check_angle(bad, "--yaw")
    with pytest.raises(InputError, match="tau"):
        CameraLeveller("auto", tau=0)
    assert roll_warning([0.5, -2.0]) == "" and roll_warning([]) == ""
    assert "limit" in roll_warning([3.0, 15.0]) and "limit" in roll_warning([-14.99])


def test_run_reads_the_roll_of_image_footage_and_takes_a_sequence_as_level(tiny_dataset, tiny_checkpoint, tmp_path):
    seq_dir = tiny_dataset / "seq_00000"
    frames, intr = _frames(tiny_dataset, 5)
    folder = tmp_path / "frames"
    folder.mkdir()
    for i, f in enumerate(frames):
        Image.fromarray(_turn(f, 4.0, intr)).save(folder / f"f{i}.png")
    base = ["--checkpoint", str(tiny_checkpoint), "--quiet", "--no-rrd", "--threads", "1"]
    assert main(["run", str(folder), "--out", str(tmp_path / "a"), *base]) == 0
    meta = json.loads((tmp_path / "a" / "warehouse.json").read_text())["meta"]
    assert meta["camera_roll_source"] == "read" and abs(meta["camera_roll_deg"] - 4.0) < 0.5
    assert meta["camera_pitch_source"] == meta["camera_yaw_source"] == "read"  # footage: all three read
    assert abs(meta["camera_pitch_deg"]) < 2.0 and abs(meta["camera_yaw_deg"]) < 1.5
    assert main(["run", str(seq_dir), "--out", str(tmp_path / "b"), "--max-frames", "3", *base]) == 0
    meta = json.loads((tmp_path / "b" / "warehouse.json").read_text())["meta"]
    assert meta["camera_roll_source"] == "level" and meta["camera_roll_deg"] == 0.0
    c = ["run", str(seq_dir), "--out", str(tmp_path / "c"), "--max-frames", "3", "--roll", "1.5", "--pitch", "-2"]
    assert main([*c, *base]) == 0
    meta = json.loads((tmp_path / "c" / "warehouse.json").read_text())["meta"]
    assert meta["camera_roll_source"] == "given" and meta["camera_roll_deg"] == 1.5
    assert meta["camera_pitch_deg"] == -2.0 and meta["camera_pitch_source"] == "given"
    assert meta["camera_yaw_source"] == "level" and meta["camera_yaw_deg"] == 0.0


def test_run_reads_the_yaw_of_image_footage(tiny_dataset, tiny_checkpoint, tmp_path, capsys):
    seq = open_dataset(tiny_dataset).sequences()[0]
    folder = tmp_path / "frames"
    folder.mkdir()
    for i in range(seq.num_frames):
        Image.fromarray(tilt_frame(seq.rgb(i), seq.intrinsics, yaw_deg=-4.0)).save(folder / f"f{i}.png")
    cam = tmp_path / "camera.json"
    cam.write_text(json.dumps(seq.intrinsics.to_dict()))
    args = ["run", str(folder), "--out", str(tmp_path / "a"), "--camera", str(cam), "--roll", "0", "--pitch", "0"]
    assert main([*args, "--checkpoint", str(tiny_checkpoint), "--quiet", "--no-rrd", "--threads", "1"]) == 0
    meta = json.loads((tmp_path / "a" / "warehouse.json").read_text())["meta"]
    assert meta["camera_yaw_source"] == "read" and abs(meta["camera_yaw_deg"] + 4.0) < 1.0
    assert meta["camera_roll_source"] == "level" and meta["camera_pitch_source"] == "level"
    assert "camera yaw read from the frames" in capsys.readouterr().out


def test_a_bad_roll_pitch_or_yaw_option_fails_in_one_line(tiny_dataset, tiny_checkpoint, tmp_path, capsys):
    seq_dir = tiny_dataset / "seq_00000"
    for cmd in (
        ["run", str(seq_dir), "--out", str(tmp_path / "r")],
        ["predict", str(seq_dir), "--out", str(tmp_path / "p")],
        ["evaluate", "--data", str(tiny_dataset)],
    ):
        for opt in ("--roll", "--pitch", "--yaw"):
            assert main([*cmd, "--checkpoint", str(tiny_checkpoint), opt, "sideways"]) != 0
            err = capsys.readouterr().err.strip().splitlines()
            assert len(err) == 1 and opt in err[0] and "sideways" in err[0]
        assert not (tmp_path / "r").exists() and not (tmp_path / "p").exists()
