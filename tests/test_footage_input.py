"""Real footage read right or refused clearly: phone photos' EXIF orientation, cut videos, camera files that
cannot describe the frames, videos and single images given to `predict` and `run`."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from layouts.errors import InputError
from mvracklay.camera import load_camera, load_lens, parse_camera_option
from mvracklay.cli import main
from mvracklay.frames import open_source

ORIENTATION = 0x0112


def _rgb(tiny_dataset: Path, n: int) -> list[np.ndarray]:
    """The first ``n`` RGB frames of the tiny dataset's first sequence (128x128)."""
    paths = sorted((tiny_dataset / "seq_00000" / "rgb").glob("*.png"))[:n]
    return [np.asarray(Image.open(p).convert("RGB")) for p in paths]


def _jpeg(path: Path, upright: np.ndarray, orientation: int) -> None:
    """Store ``upright`` as a camera does: the sensor's image, with the EXIF tag that turns it upright."""
    stored = Image.fromarray(upright)
    if orientation == 6:  # shown turned 90 degrees clockwise: the sensor's image is the upright one turned back
        stored = stored.transpose(Image.Transpose.ROTATE_90)
    exif = Image.Exif()
    exif[ORIENTATION] = orientation
    stored.save(path, quality=95, exif=exif)


def _video(path: Path, frames: list[np.ndarray], **options: str) -> Path:
    import av

    with av.open(str(path), "w", options=options) as container:
        stream = container.add_stream("libx264", rate=10)
        stream.height, stream.width = frames[0].shape[:2]
        stream.pix_fmt = "yuv420p"
        for rgb in frames:
            for packet in stream.encode(av.VideoFrame.from_ndarray(rgb, format="rgb24")):
                container.mux(packet)
        for packet in stream.encode():
            container.mux(packet)
    return path


def _cut(path: Path, share: float = 0.6) -> Path:
    cut = path.with_name(f"cut_{path.name}")
    data = path.read_bytes()
    cut.write_bytes(data[: int(len(data) * share)])
    return cut


def _warnings(err: str) -> list[str]:
    return [line for line in err.splitlines() if "warning:" in line]


# --- phone photos -------------------------------------------------------------------------------------------


def test_photos_are_read_upright_whatever_their_exif_orientation(tiny_dataset: Path, tmp_path: Path):
    frames = [rgb[16:112] for rgb in _rgb(tiny_dataset, 3)]  # 128 wide, 96 high: a turn shows
    folder = tmp_path / "phone"
    folder.mkdir()
    for i, (rgb, o) in enumerate(zip(frames, (6, 1, 6))):
        _jpeg(folder / f"IMG_{i}.jpg", rgb, o)
    assert Image.open(folder / "IMG_0.jpg").size == (96, 128)  # stored on its side
    src = open_source(folder)
    assert (src.width, src.height) == (128, 96)
    got = list(src.frames())
    assert [g.shape for g in got] == [(96, 128, 3)] * 3
    for g, want in zip(got, frames):
        assert np.abs(g.astype(int) - want).mean() < 4  # upright (JPEG's loss only)


def test_a_folder_mixing_portrait_and_landscape_names_the_odd_photo(tiny_dataset: Path, tmp_path: Path):
    rgb = _rgb(tiny_dataset, 1)[0][16:112]
    folder = tmp_path / "mixed"
    folder.mkdir()
    _jpeg(folder / "a.jpg", rgb, 1)
    Image.fromarray(rgb).save(folder / "b.jpg", exif=_exif(6))  # landscape pixels, shown as portrait
    with pytest.raises(InputError, match=r"b\.jpg: 96x128 upright .*EXIF.* first image \(a\.jpg\) is 128x96"):
        open_source(folder)


def _exif(orientation: int) -> Image.Exif:
    exif = Image.Exif()
    exif[ORIENTATION] = orientation
    return exif


# --- cut videos ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize("name, options", [("walk.mp4", {"movflags": "faststart"}), ("walk.mkv", {})])
def test_a_cut_video_warns_how_many_frames_it_lost(tiny_dataset: Path, tmp_path: Path, capsys, name, options):
    frames = _rgb(tiny_dataset, 8) * 3  # 24 frames
    whole = _video(tmp_path / name, frames, **options)
    src = open_source(whole)
    assert len(list(src.frames())) == 24 and not src.warnings  # a whole file: nothing to say
    cut = _cut(whole)
    src = open_source(cut)
    n = len(list(src.frames()))
    assert 0 < n < 24
    said = _warnings(capsys.readouterr().err)
    assert said == [f"mvracklay: warning: decoded {n} of 24 frames announced by {cut}: the file looks cut"]
    assert src.warnings == [said[0].removeprefix("mvracklay: warning: ")]
    assert len(list(src.frames(max_frames=2))) == 2 and len(src.warnings) == 1  # stopped early: not cut


def test_a_cut_mp4_without_its_index_fails_clearly(tiny_dataset: Path, tmp_path: Path):
    cut = _cut(_video(tmp_path / "walk.mp4", _rgb(tiny_dataset, 8)))  # the index (moov) at the end: cut off
    with pytest.raises(InputError, match="cut_walk.mp4: not a readable video"):
        open_source(cut)


def test_run_on_a_cut_video_reports_it_among_its_warnings(tiny_dataset: Path, tiny_checkpoint: Path, tmp_path, capsys):
    cut = _cut(_video(tmp_path / "walk.mkv", _rgb(tiny_dataset, 8) * 2))
    argv = ["run", str(cut), "--out", str(tmp_path / "o"), "--checkpoint", str(tiny_checkpoint)]
    assert main([*argv, "--quiet", "--no-rrd", "--threads", "1"]) == 0
    said = [w for w in _warnings(capsys.readouterr().err) if "looks cut" in w]
    assert len(said) == 1 and said[0].startswith("mvracklay run: warning: decoded ") and "of 16 frames" in said[0]


# --- camera files -------------------------------------------------------------------------------------------

INTR = {"fx": 110.85, "fy": 110.85, "cx": 64.0, "cy": 64.0, "width": 128, "height": 128}


def _cam(tmp_path: Path, d: object) -> Path:
    cam = tmp_path / "cam.json"
    cam.write_text(json.dumps(d))
    return cam


def test_a_camera_of_the_same_aspect_is_scaled_another_refused(tmp_path: Path):
    double = {k: v * 2 for k, v in INTR.items()}
    assert load_camera(_cam(tmp_path, double), 128, 128).fx == pytest.approx(110.85)
    wide = {**INTR, "cx": 960.0, "cy": 540.0, "width": 1920, "height": 1080}
    with pytest.raises(InputError, match=r"--camera .*cam.json: its image is 1920x1080 .* the frames 128x128"):
        load_camera(_cam(tmp_path, wide), 128, 128)


@pytest.mark.parametrize(
    "record, needle",
    [
        ({**INTR, "cx": 3200.0}, r"cx = 3200 is outside the image \(128 pixels wide\)"),
        ({**INTR, "cy": -5.0}, r"cy = -5 is outside the image \(128 pixels high\)"),
        ({**INTR, "focal": 3.0, "k4": 0.1}, r"unknown keys 'focal', 'k4' \(known: fx, .*k3, and \"intrinsics\""),
        ({"intrinsics": {**INTR, "skew": 0}}, r"cam.json \"intrinsics\": unknown key 'skew'"),
        ({"intrinsics": {**INTR, "k1": -0.1}, "k1": -0.2}, r"k1 given both inside \"intrinsics\" and beside it"),
        ({"intrinsics": [1, 2]}, r"\"intrinsics\" must be a JSON object"),
    ],
)
def test_camera_files_that_cannot_be_meant_are_refused(tmp_path: Path, record: dict, needle: str):
    cam = _cam(tmp_path, record)
    with pytest.raises(InputError, match=needle):
        load_camera(cam, 128, 128)
    with pytest.raises(InputError, match=needle):  # predict reads camera files the same way
        parse_camera_option(str(cam), 128, 128)


def test_distortion_beside_nested_intrinsics_is_taken(tmp_path: Path):
    cam = _cam(tmp_path, {"intrinsics": {**INTR, "k1": -0.1}, "k2": 0.02, "p1": 0.001})
    lens = load_lens(cam)
    assert (lens.k1, lens.k2, lens.p1) == (-0.1, 0.02, 0.001)
    assert parse_camera_option(str(cam), 128, 128)[1] == lens


def test_run_refuses_a_camera_file_in_one_line(tiny_dataset: Path, tiny_checkpoint: Path, tmp_path: Path, capsys):
    cam = _cam(tmp_path, {**INTR, "cx": 3200.0})
    argv = ["run", str(tiny_dataset / "seq_00000"), "--out", str(tmp_path / "o"), "--camera", str(cam)]
    assert main([*argv, "--checkpoint", str(tiny_checkpoint), "--quiet"]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and "cam.json: cx = 3200 is outside the image" in lines[0]
    assert not (tmp_path / "o").exists()


# --- predict takes run's inputs; single images ----------------------------------------------------------------


def test_predict_takes_a_video(tiny_dataset: Path, tiny_checkpoint: Path, tmp_path: Path):
    video = _video(tmp_path / "walk.mp4", _rgb(tiny_dataset, 6))
    out = tmp_path / "lay"
    argv = ["predict", str(video), "--checkpoint", str(tiny_checkpoint), "--out", str(out)]
    assert main([*argv, "--quiet", "--threads", "1"]) == 0
    assert len(list(out.glob("*.npz"))) == 6


@pytest.mark.parametrize("command", ["predict", "run"])
def test_one_image_gives_one_view_and_says_so(tiny_dataset, tiny_checkpoint, tmp_path, capsys, command):
    image = tmp_path / "one" / "shot.png"
    image.parent.mkdir()
    Image.fromarray(_rgb(tiny_dataset, 1)[0]).save(image)
    for i, given in enumerate((image, image.parent)):  # the image itself, or the folder holding it
        out = tmp_path / f"{command}{i}"
        argv = [command, str(given), "--checkpoint", str(tiny_checkpoint), "--out", str(out), "--threads", "1"]
        assert main([*argv, "--quiet", *(["--no-rrd"] if command == "run" else [])]) == 0
        said = _warnings(capsys.readouterr().err)
        hint = [w for w in said if "one frame gives one view" in w]
        assert len(hint) == 1 and hint[0].startswith(f"mvracklay {command}: warning: {given}: ")
        assert "without the motion the map needs" in hint[0] and "one rack span" in hint[0]
        done = out / ("000000.npz" if command == "predict" else "warehouse.json")
        assert done.is_file()
