"""A generated camera turned by camera.roll_deg / pitch_deg / yaw_deg: rendering, records, and its use."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from layouts.camera import Intrinsics
from layouts.canonical import CanonicalView, camera_rotation
from layouts.errors import InputError
from layouts.spec import LayoutSpec
from waresynth.config import load_config
from waresynth.render import Renderer
from waresynth.scene_builder import build_scene

INTR = Intrinsics.from_fov(96, 72, 60.0)


def turned_config(roll: float = 0.0, pitch: float = 0.0, yaw: float = 0.0) -> dict:
    return {"camera": {"roll_deg": [roll, roll], "pitch_deg": [pitch, pitch], "yaw_deg": [yaw, yaw]}}


def render_pair(angles: tuple[float, float, float], seed: int = 3):
    """The same scene's frame 1 seen by a level camera and by one turned by ``angles``."""
    level = build_scene(np.random.default_rng(seed), load_config(), INTR, 3)
    turned = build_scene(np.random.default_rng(seed), load_config(turned_config(*angles)), INTR, 3)
    frames = [
        Renderer(s, INTR, exact=True).render(s.camera.positions[1], np.random.default_rng(0)) for s in (level, turned)
    ]
    return level, turned, frames[0], frames[1]


def level_pixels(angles: tuple[float, float, float]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For each pixel of the turned camera, the level camera's pixel on the same ray (row, column, inside)."""
    h = INTR.matrix @ camera_rotation(*angles) @ np.linalg.inv(INTR.matrix)
    v, u = np.mgrid[0 : INTR.height, 0 : INTR.width] + 0.5
    p = h @ np.stack([u.ravel(), v.ravel(), np.ones(u.size)])
    lu, lv = p[0] / p[2], p[1] / p[2]
    inside = (lu >= 0) & (lu < INTR.width) & (lv >= 0) & (lv < INTR.height)
    return np.floor(lv).astype(int).clip(0, INTR.height - 1), np.floor(lu).astype(int).clip(0, INTR.width - 1), inside


def test_config_checks_the_camera_angles():
    assert load_config()["camera"]["yaw_deg"] == [0.0, 0.0]
    with pytest.raises(InputError, match=r"camera.yaw_deg must lie in \[-45, 45\]"):
        load_config({"camera": {"yaw_deg": [0, 60]}})
    with pytest.raises(InputError, match="camera.pitch_deg must be \\[low, high\\]"):
        load_config({"camera": {"pitch_deg": 3}})


def test_a_turned_camera_keeps_the_level_seeds_scene():
    level = build_scene(np.random.default_rng(5), load_config(), INTR, 4)
    turned = build_scene(np.random.default_rng(5), load_config(turned_config(1.5, -2.0, 3.0)), INTR, 4)
    assert level.camera.angles == (0.0, 0.0, 0.0)
    assert turned.camera.angles == (1.5, -2.0, 3.0)
    assert turned.to_dict() == level.to_dict()
    np.testing.assert_array_equal(turned.camera.positions, level.camera.positions)
    ranged = build_scene(np.random.default_rng(5), load_config({"camera": {"yaw_deg": [-4.0, 4.0]}}), INTR, 4)
    assert -4.0 <= ranged.camera.yaw_deg <= 4.0 and ranged.camera.yaw_deg != 0.0


@pytest.mark.parametrize("angles", [(0.0, 0.0, 4.0), (6.0, 0.0, 0.0), (0.0, 4.0, 0.0), (2.0, -3.0, 3.0)])
def test_a_turned_render_is_the_level_view_seen_through_the_rotation(angles):
    level, turned, fl, ft = render_pair(angles)
    assert not np.array_equal(fl.semantic, ft.semantic)
    lv, lu, inside = level_pixels(angles)
    agree = (fl.semantic[lv, lu] == ft.semantic.ravel())[inside].mean()
    assert agree > 0.92  # the rest: pixels on edges, sampled at the nearest level pixel
    # the opposite turn does not explain the render: the test sees which way the camera turned
    lv2, lu2, inside2 = level_pixels(tuple(-a for a in angles))
    assert (fl.semantic[lv2, lu2] == ft.semantic.ravel())[inside2].mean() < agree - 0.2
    # depth is along the turned camera's axis; as the level camera measures it, it is the level depth
    same = inside & (fl.instance[lv, lu] == ft.instance.ravel()) & (ft.depth_mm.ravel() > 0)
    forward = INTR.level_depth(ft.depth_mm / 1000.0, turned.camera.rotation).ravel()
    err = np.abs(forward - fl.depth_mm[lv, lu] / 1000.0)[same]
    assert np.median(err) < 0.01
    if angles[1] or angles[2]:  # a pitch or a yaw turns the axis the depth is measured along (a roll does not)
        raw = np.abs(ft.depth_mm.ravel() / 1000.0 - fl.depth_mm[lv, lu] / 1000.0)[same]
        assert np.median(raw) > 0.03


def test_level_depth_of_a_level_camera_is_its_depth():
    depth = np.random.default_rng(0).uniform(0, 5, (INTR.height, INTR.width)).astype(np.float32)
    np.testing.assert_allclose(INTR.level_depth(depth, np.eye(3)), depth)
    with pytest.raises(Exception, match="does not match"):
        INTR.level_depth(depth[:10], np.eye(3))


@pytest.fixture(scope="module")
def turned_dataset(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """The same 2 sequences x 5 frames (seed 11) from a level camera and one yawed 4 degrees."""
    from waresynth.generate import DatasetSettings, generate_dataset

    root = tmp_path_factory.mktemp("turned")
    kw = dict(num_sequences=2, frames=5, image_size=(96, 96), spec=LayoutSpec(size=32), seed=11, progress=False)
    level = generate_dataset(root / "level", DatasetSettings(**kw))
    turned = generate_dataset(root / "yaw4", DatasetSettings(config=turned_config(yaw=4.0), **kw))
    return level, turned


def test_the_dataset_records_the_rotation(turned_dataset):
    from waresynth.dataset import open_dataset

    level, turned = (open_dataset(p).sequences() for p in turned_dataset)
    assert level[0].camera_angles == (0.0, 0.0, 0.0)
    assert turned[0].camera_angles == (0.0, 0.0, 4.0)
    assert turned[0].meta["camera"]["yaw_deg"] == 4.0
    for a, b in zip(level, turned):
        assert a.scene() == b.scene()
        np.testing.assert_array_equal(a.layouts(2).top, b.layouts(2).top)
        assert not np.array_equal(a.rgb(2), b.rgb(2))
        # the turned camera's depth, as a level camera measures it, matches the level one's where both see
        d = b.level_depth(2)
        both = (d > 0) & (a.depth(2) > 0) & (a.semantic(2) == b.semantic(2))
        assert np.median(np.abs(d - a.depth(2))[both]) < np.median(np.abs(b.depth(2) - a.depth(2))[both]) + 1e-6
        np.testing.assert_array_equal(a.level_depth(2), a.depth(2))


def test_a_manifest_from_before_the_rotation_still_resumes(turned_dataset, tmp_path):
    import shutil

    from waresynth.generate import DatasetSettings, generate_dataset

    copy = tmp_path / "old"
    shutil.copytree(turned_dataset[0], copy)
    manifest = json.loads((copy / "manifest.json").read_text())
    for k in ("roll_deg", "pitch_deg", "yaw_deg"):
        del manifest["config"]["camera"][k]
    (copy / "manifest.json").write_text(json.dumps(manifest))
    shutil.rmtree(copy / "seq_00001")
    kw = dict(num_sequences=2, frames=5, image_size=(96, 96), spec=LayoutSpec(size=32), seed=11, progress=False)
    generate_dataset(copy, DatasetSettings(**kw))  # accepted as the same dataset: its camera was level
    assert (copy / "seq_00001" / "meta.json").is_file()
    with pytest.raises(InputError, match="different WareSynth dataset"):
        generate_dataset(copy, DatasetSettings(config=turned_config(yaw=1.0), **kw))


def test_training_windows_are_levelled_by_the_recorded_rotation(turned_dataset):
    from network.data import WindowDataset
    from network.preprocess import canonical_image, sequence_angles
    from waresynth.dataset import open_dataset

    view = CanonicalView(64, 64, 3.0)
    level, turned = (open_dataset(p).sequences()[0] for p in turned_dataset)
    assert sequence_angles(turned) == (0.0, 0.0, 4.0) and sequence_angles(object()) == (0.0, 0.0, 0.0)
    ds = WindowDataset([turned], seq_len=1, input_size=(64, 64), spec=LayoutSpec(size=32))
    got = ds._frame(turned, 2)["images"].astype(float)
    ref = canonical_image(level.rgb(2), view, level.intrinsics, level.frame(2)["distance"]).astype(float)
    raw = canonical_image(turned.rgb(2), view, turned.intrinsics, turned.frame(2)["distance"]).astype(float)
    valid = view.valid_mask(turned.intrinsics, turned.frame(2)["distance"], 0.0, 0.0, 4.0)
    assert np.abs(got - ref)[valid].mean() < 0.5 * np.abs(raw - ref)[valid].mean()


def test_the_rotation_is_the_default_for_generated_sequences_only(turned_dataset):
    from tiny_net import tiny_config

    from network.inference.predictor import Predictor, sequence_camera
    from network.inference.roll import resolve_angles
    from network.model.net import MVRackLay
    from waresynth.dataset import open_dataset

    assert resolve_angles(None, None, None, (1.0, 0.0, 4.0)) == (1.0, 0.0, 4.0)
    assert resolve_angles(None, "auto", "0", (1.0, 0.0, 4.0)) == (1.0, "auto", 0.0)
    assert resolve_angles(None, None, None, None) == ("auto", "auto", "auto")
    turned = open_dataset(turned_dataset[1]).sequences()[0]
    model = MVRackLay(tiny_config(turned.spec))
    pred = Predictor(model, sequence_camera(turned))
    assert (pred.roll, pred.pitch, pred.yaw) == (None, None, 4.0)
    assert pred.leveller is not None and pred.leveller.angles(0, turned.rgb(0))[2] == 4.0
    assert Predictor(model, sequence_camera(turned), yaw=0).leveller is None
    level = open_dataset(turned_dataset[0]).sequences()[0]
    assert Predictor(model, sequence_camera(level)).leveller is None


def test_commands_level_a_generated_sequence_by_its_record(turned_dataset, tiny_checkpoint, tmp_path, capsys):
    from mvracklay.cli import main
    from mvracklay.frames import open_source

    assert open_source(turned_dataset[1] / "seq_00000").camera_angles == (0.0, 0.0, 4.0)
    out = tmp_path / "eval.json"
    args = ["evaluate", "--checkpoint", str(tiny_checkpoint), "--data", str(turned_dataset[1]), "--split", "all"]
    assert main([*args, "--json-out", str(out), "--quiet", "--threads", "1"]) == 0
    res = json.loads(out.read_text())
    assert res["recorded_angles"] == [[0.0, 0.0, 4.0]] * 2 and res["yaw"] is None
    assert res["yaws"] == [4.0] * 10 and set(res["rolls"]) == {0.0}
    assert "camera yaw levelled as recorded (4 deg)" in capsys.readouterr().out
    assert main([*args, "--json-out", str(out), "--quiet", "--threads", "1", "--yaw", "0"]) == 0
    assert json.loads(out.read_text())["yaws"] == []
    assert "camera yaw taken as level (recorded 4 deg)" in capsys.readouterr().out
    base = ["--checkpoint", str(tiny_checkpoint), "--quiet", "--no-rrd", "--threads", "1", "--max-frames", "3"]
    assert main(["run", str(turned_dataset[1] / "seq_00000"), "--out", str(tmp_path / "run"), *base]) == 0
    meta = json.loads((tmp_path / "run" / "warehouse.json").read_text())["meta"]
    assert (meta["camera_yaw_deg"], meta["camera_yaw_source"]) == (4.0, "recorded")
    assert meta["camera_roll_source"] == meta["camera_pitch_source"] == "level"


def test_what_reads_depth_as_a_level_camera_refuses_a_turned_one(turned_dataset, capsys):
    from mvracklay.cli import main
    from waresynth.dataset import open_dataset, require_level_camera

    turned = open_dataset(turned_dataset[1]).sequences()[0]
    with pytest.raises(InputError, match="camera is turned .* 0 / 0 / 4 deg"):
        require_level_camera(turned, "the test")
    require_level_camera(open_dataset(turned_dataset[0]).sequences()[0], "the test")
    assert main(["evaluate-baseline", "--data", str(turned_dataset[1]), "--split", "all", "--quiet"]) != 0
    assert "depth-projection baseline needs a level camera's images" in capsys.readouterr().err


def test_inspect_says_the_camera_is_turned(turned_dataset):
    from waresynth.dataset import open_dataset
    from waresynth.preview import format_summary, summarise

    turned = summarise(open_dataset(turned_dataset[1]), max_frames=2, progress=False)
    assert turned["camera_angles"] == {"roll": [0.0, 0.0], "pitch": [0.0, 0.0], "yaw": [4.0, 4.0]}
    assert "turned: yaw 4 deg" in format_summary(turned)
    assert "camera       turned" not in format_summary(
        summarise(open_dataset(turned_dataset[0]), max_frames=2, progress=False)
    )


def test_a_racklay_export_carries_the_rotation(turned_dataset, tmp_path):
    from waresynth.exporters.racklay import export_racklay, load_racklay_export

    out = export_racklay(turned_dataset[1], tmp_path / "rl", progress=False)
    seqs = load_racklay_export(out).sequences()
    assert seqs[0].camera_angles == (0.0, 0.0, 4.0)


def test_the_roll_of_a_point_sampled_render_is_read():
    """The renderer samples each pixel at its centre: a rolled edge is a staircase whose gradients are
    level between its steps, which the orientation histogram alone reads as level (~0.4 of 5 degrees)."""
    from network.inference.angle_reading import _orientation_peak, estimate_roll, estimate_tilt

    intr = Intrinsics.from_fov(128, 128, 60.0)
    rolls, tilt_rolls, histogram = [], [], []
    for seed in range(4):
        scene = build_scene(np.random.default_rng(seed), load_config(turned_config(roll=5.0)), intr, 3)
        rgb = Renderer(scene, intr).render(scene.camera.positions[1], np.random.default_rng(0)).rgb
        rolls.append(estimate_roll(rgb)[0])
        tilt_rolls.append(estimate_tilt(rgb, intr)[0][0])
        grey = rgb.astype(np.float32).mean(-1)
        gy, gx = np.gradient(grey)
        strong = np.hypot(gx, gy) > np.percentile(np.hypot(gx, gy), 80)
        histogram.append(_orientation_peak(gx[strong], gy[strong], np.hypot(gx, gy)[strong], 15.0)[0])
    assert abs(np.mean(histogram)) < 2.0  # what the edges' orientations alone say: the staircases look level
    assert abs(np.mean(rolls) - 5.0) < 0.5 and abs(np.mean(tilt_rolls) - 5.0) < 0.8
