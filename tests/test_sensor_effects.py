"""Sensor effects of the generator: sensor.supersample (area-sampled pixels) and sensor.motion_blur; labels unchanged."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from layouts.camera import Intrinsics
from layouts.errors import InputError
from layouts.spec import LayoutSpec
from waresynth.config import load_config
from waresynth.render import Renderer
from waresynth.scene_builder import build_scene

INTR = Intrinsics.from_fov(96, 64, 60.0)
QUIET = {"sensor": {"noise_sigma": [0.0, 0.0]}}


def _scene(seed: int = 2, config: dict | None = None):
    return build_scene(np.random.default_rng(seed), load_config(config), INTR, 3)


def test_config_checks_the_supersample_factor():
    assert load_config()["sensor"]["supersample"] == 1
    assert load_config({"sensor": {"supersample": 3}})["sensor"]["supersample"] == 3
    for bad in (0, 5, 1.5, [1, 2]):
        with pytest.raises(InputError, match="sensor.supersample"):
            load_config({"sensor": {"supersample": bad}})
    with pytest.raises(ValueError, match="supersample must be an integer in \\[1, 4\\]"):
        Renderer(_scene(), INTR, supersample=0)


@pytest.mark.parametrize("s", [2, 3])
def test_colours_are_the_means_of_the_sub_pixel_rays_and_labels_stay_point_sampled(s):
    scene = _scene(config=QUIET)
    pos = scene.camera.positions[1]
    plain = Renderer(scene, INTR).render(pos, np.random.default_rng(0))
    aa = Renderer(scene, INTR, supersample=s).render(pos, np.random.default_rng(0))
    fine = Renderer(scene, INTR.scaled(INTR.width * s, INTR.height * s)).render(pos, np.random.default_rng(0))
    # the sub-pixel grid lies inside each pixel: the s x s block of a render s times the size
    blocks = fine.rgb.astype(np.float32).reshape(INTR.height, s, INTR.width, s, 3)
    means, saturated = blocks.mean((1, 3)), (blocks == 255).any((1, 3))
    assert saturated.mean() < 0.1
    assert np.abs(aa.rgb - means)[~saturated].max() <= 1.0  # each fine pixel rounded once more
    # the pixel saturates after it sums its light (a highlight is not clipped ray by ray)
    assert (aa.rgb >= means - 1.0)[saturated].all()
    for name in ("depth_mm", "semantic", "instance"):
        np.testing.assert_array_equal(getattr(aa, name), getattr(plain, name))
    # and the blend is not the pixel-centre ray: edges and fine texture become sub-pixel mixtures
    assert np.abs(aa.rgb.astype(np.int16) - plain.rgb).max(-1).mean() > 2.0


def test_a_supersampled_dataset_keeps_the_default_labels_and_an_old_manifest_resumes(tmp_path):
    from waresynth.dataset import open_dataset
    from waresynth.generate import DatasetSettings, generate_dataset

    kw = dict(num_sequences=2, frames=3, image_size=(64, 48), spec=LayoutSpec(size=32), seed=4, progress=False)
    plain = open_dataset(generate_dataset(tmp_path / "plain", DatasetSettings(**kw)))
    aa = open_dataset(generate_dataset(tmp_path / "aa", DatasetSettings(config={"sensor": {"supersample": 2}}, **kw)))
    assert aa.config["sensor"]["supersample"] == 2
    from waresynth.preview import format_summary, summarise

    assert "each the mean colour of 2 x 2 rays" in format_summary(summarise(aa, progress=False))
    assert "area-sampled" not in format_summary(summarise(plain, progress=False))
    blur = generate_dataset(tmp_path / "blur", DatasetSettings(config={"sensor": {"motion_blur": [0.2, 0.6]}}, **kw))
    drawn = [sq.meta["camera"]["motion_blur"] for sq in open_dataset(blur).sequences()]
    assert all(0.2 <= b <= 0.6 for b in drawn) and drawn[0] != drawn[1]
    said = format_summary(summarise(open_dataset(blur), progress=False))
    assert f"motion-blurred: the shutter open {min(drawn):.2f} to {max(drawn):.2f} of a step" in said
    for a, b in zip(plain.sequences(), aa.sequences()):
        assert a.scene() == b.scene()
        for i in range(3):
            np.testing.assert_array_equal(a.depth(i), b.depth(i))
            np.testing.assert_array_equal(a.semantic(i), b.semantic(i))
            np.testing.assert_array_equal(a.layouts(i).top, b.layouts(i).top)
            assert not np.array_equal(a.rgb(i), b.rgb(i))
    # a dataset written before the key existed was point-sampled: it resumes as the default
    old = tmp_path / "old"
    shutil.copytree(tmp_path / "plain", old)
    manifest = json.loads((old / "manifest.json").read_text())
    del manifest["config"]["sensor"]["supersample"], manifest["config"]["sensor"]["motion_blur"]
    (old / "manifest.json").write_text(json.dumps(manifest))
    shutil.rmtree(old / "seq_00001")
    generate_dataset(old, DatasetSettings(**kw))
    np.testing.assert_array_equal(open_dataset(old).sequence("seq_00001").rgb(2), plain.sequence("seq_00001").rgb(2))
    with pytest.raises(InputError, match="different WareSynth dataset"):
        generate_dataset(old, DatasetSettings(config={"sensor": {"supersample": 2}}, **kw))


def test_a_yaw_reads_closer_on_supersampled_frames():
    """A point-sampled 3-degree yaw is a one-pixel step every ~20 columns, which the reading takes for
    level edges; area-sampled edges carry the slope."""
    from network.inference.angle_reading import estimate_tilt

    intr = Intrinsics.from_fov(128, 128, 60.0)
    cfg = load_config({"camera": {"yaw_deg": [3.0, 3.0]}})
    reads = {1: [], 2: []}
    for seed in range(12):
        scene = build_scene(np.random.default_rng(seed), cfg, intr, 3)
        for s in reads:
            rgb = (
                Renderer(scene, intr, supersample=s, noise_seed=seed)
                .render(scene.camera.positions[1], np.random.default_rng(0))
                .rgb
            )
            reads[s].append(estimate_tilt(rgb, intr)[0][2])
    point, area = abs(np.mean(reads[1]) - 3.0), abs(np.mean(reads[2]) - 3.0)
    assert area < 0.5 and area < point - 0.5


def test_generate_supersample_flag_sets_the_config_key(tmp_path, capsys):
    from mvracklay.cli import main
    from waresynth.dataset import open_dataset

    cfg = tmp_path / "yaw.json"
    cfg.write_text(json.dumps({"camera": {"yaw_deg": [2.0, 2.0]}}))
    args = ["generate", str(tmp_path / "d"), "--sequences", "1", "--frames", "2", "--size", "32", "--no-progress"]
    assert main([*args, "--config", str(cfg), "--supersample", "3"]) == 0
    ds = open_dataset(tmp_path / "d")
    assert ds.config["sensor"]["supersample"] == 3 and ds.config["camera"]["yaw_deg"] == [2.0, 2.0]
    with pytest.raises(SystemExit):
        main([*args, "--supersample", "5"])
    assert "invalid choice: 5" in capsys.readouterr().err
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"sensor": {"gain": 50}}))
    assert main([*args, "--config", str(bad), "--supersample", "2"]) == 2
    assert f"{bad}: sensor.gain" in capsys.readouterr().err


def test_motion_blur_smears_along_the_row_about_the_frames_position():
    intr = Intrinsics.from_fov(128, 96, 60.0)
    blurred = build_scene(
        np.random.default_rng(1),
        load_config({**QUIET, "sensor": {"noise_sigma": [0, 0], "motion_blur": [1.0, 1.0]}}),
        intr,
        3,
    )
    sharp = build_scene(np.random.default_rng(1), load_config(QUIET), intr, 3)
    assert blurred.to_dict() == sharp.to_dict() and blurred.sensor["motion_blur"] == 1.0
    assert sharp.sensor["motion_blur"] == 0.0
    r = Renderer(blurred, intr)
    travel = np.array([blurred.camera.step, 0.0, 0.0])
    assert r.motion_samples(None) == 1 and r.motion_samples(np.zeros(3)) == 1
    assert r.motion_samples(travel * 1e-4) == 2 and r.motion_samples(travel * 100) == 16
    assert 4 <= r.motion_samples(travel) <= 8  # a step is ~3-7 pixels of the rack front here
    pos = blurred.camera.positions[1]
    a = r.render(pos, np.random.default_rng(0))
    b = r.render(pos, np.random.default_rng(0), motion=travel)
    for name in ("depth_mm", "semantic", "instance"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    ga, gb = (f.rgb.astype(float).mean(-1) for f in (a, b))

    def grad(img, axis):
        return np.abs(np.diff(img, axis=axis)).mean()

    assert grad(gb, 1) < 0.85 * grad(ga, 1)  # smeared along the row (image x) ...
    assert grad(gb, 0) > 0.85 * grad(ga, 0)  # ... much less across it
    # centred on the frame's position: the sharp view fits best unshifted
    err = {d: np.abs(np.roll(ga, d, 1) - gb)[:, 8:-8].mean() for d in range(-4, 5)}
    assert min(err, key=err.get) == 0
    with pytest.raises(InputError, match="sensor.motion_blur"):
        load_config({"sensor": {"motion_blur": [0.0, 1.5]}})
