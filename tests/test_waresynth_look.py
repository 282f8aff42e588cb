"""WareSynth's look (`waresynth.look`): light level, white balance, signal-dependent noise, tone curve, vignetting,
lens, compression and the wider textures; neutral by default, deterministic, in range, and checked."""

from __future__ import annotations

import json

import numpy as np
import pytest

from layouts.camera import Intrinsics
from layouts.errors import InputError
from layouts.lens import Lens, undistort_image
from layouts.spec import LayoutSpec
from waresynth.config import CONFIGS_DIR, load_config, shipped_configs
from waresynth.look import SensorLook, draw_look, temperature_gains
from waresynth.render import Renderer
from waresynth.scene_builder import build_scene

INTR = Intrinsics.from_fov(64, 48, 60.0)
QUIET = {"noise_sigma": [0.0, 0.0]}
#: one config per effect (the sensor's Gaussian noise off, so what differs is the effect's)
EFFECTS = {
    "level": {"lighting": {"level": [0.3, 0.6]}},
    "extra_lights": {"lighting": {"extra_lights": [2, 3], "falloff": [0.02, 0.08]}},
    "white_balance": {"lighting": {"colour_temperature": [3000, 4000]}, "sensor": {"white_balance_jitter": 0.1}},
    "exposure": {"sensor": {"exposure_ev": [-1.0, 1.0], "auto_exposure": [0.2, 0.9]}},
    "shot_read_noise": {"sensor": {"shot_noise": [0.5, 2.0], "read_noise": [1.0, 3.0]}},
    "gamma": {"sensor": {"gamma": [1.2, 2.0]}},
    "vignetting": {"sensor": {"vignetting": [0.2, 0.6]}},
    "lens": {"sensor": {"lens_k1": [-0.2, -0.05], "lens_k2": [-0.02, 0.02]}},
    "jpeg": {"sensor": {"compression": ["jpeg"], "jpeg_quality": [20, 90], "jpeg_subsampling": ["4:4:4", "4:2:0"]}},
    "h264": {"sensor": {"compression": ["h264"], "h264_quality": [15, 40], "h264_blur": [0.4, 1.0]}},
    "h264_stream": {"sensor": {"compression": ["h264_stream"], "stream_mbps": [1.0, 4.0]}},
    "h265_stream": {"sensor": {"compression": ["h265_stream"], "stream_mbps": [1.0, 4.0]}},
    "textures": {
        "boxes": {"textures": ["wrap", "printed", "stained"]},
        "floor": {"textures": ["lines", "stained"]},
        "wall": {"textures": ["stained"]},
        "rack": {"textures": ["stained"], "board_textures": ["plain", "stained", "noise"]},
    },
}


def _cfg(extra: dict | None = None) -> dict:
    extra = json.loads(json.dumps(extra or {}))
    extra.setdefault("sensor", {}).update(QUIET)
    return load_config(extra)


def _render(cfg: dict, seed: int, intr: Intrinsics = INTR, frame: int = 1):
    scene = build_scene(np.random.default_rng(seed), cfg, intr, 3)
    return scene, Renderer(scene, intr, noise_seed=seed).render(
        scene.camera.positions[frame], np.random.default_rng(seed)
    )


def test_the_default_look_is_neutral_and_draws_nothing():
    cfg = load_config()
    rng = np.random.default_rng(3)
    scene = build_scene(rng, cfg, INTR, 3)
    assert scene.look == {} and "look" not in scene.to_dict()
    after = rng.random()  # the look drew nothing after the motion blur
    rng2 = np.random.default_rng(3)
    build_scene(rng2, {**cfg, "lighting": {**cfg["lighting"], "level": [1.0, 1.0]}}, INTR, 3)
    assert rng2.random() == after
    assert draw_look(np.random.default_rng(0), cfg, INTR, np.zeros(3)) == {}
    assert temperature_gains(6500.0) == (1.0, 1.0, 1.0)
    r, g, b = temperature_gains(3000.0)
    assert r > g > b and abs((r + g + b) / 3 - 1.0) < 1e-9


@pytest.mark.parametrize("effect", sorted(EFFECTS))
def test_each_effect_is_deterministic_and_changes_with_the_seed(effect):
    cfg = _cfg(EFFECTS[effect])
    a_scene, a = _render(cfg, 5)
    _, b = _render(cfg, 5)
    _, c = _render(cfg, 6)
    np.testing.assert_array_equal(a.rgb, b.rgb)
    assert not np.array_equal(a.rgb, c.rgb)
    _, plain = _render(_cfg(), 5)
    assert not np.array_equal(a.rgb, plain.rgb)  # the effect shows
    if effect not in ("lens", "textures"):  # the look is drawn last: the same scene, the same labels
        assert {k: v for k, v in a_scene.to_dict().items() if k != "look"} == build_scene(
            np.random.default_rng(5), _cfg(), INTR, 3
        ).to_dict()
        np.testing.assert_array_equal(a.semantic, plain.semantic)
        np.testing.assert_array_equal(a.depth_mm, plain.depth_mm)


def test_the_light_level_scales_the_mean_brightness_and_auto_exposure_undoes_it():
    _, bright = _render(_cfg(), 2)
    _, dim = _render(_cfg({"lighting": {"level": [0.25, 0.25]}}), 2)
    _, exposed = _render(_cfg({"lighting": {"level": [0.25, 0.25]}, "sensor": {"auto_exposure": [1.0, 1.0]}}), 2)
    ratio = dim.rgb.mean() / bright.rgb.mean()
    assert 0.2 < ratio < 0.3
    assert abs(exposed.rgb.astype(float) - bright.rgb).mean() < 1.0
    _, stop = _render(_cfg({"sensor": {"exposure_ev": [-1.0, -1.0]}}), 2)
    assert 0.45 < stop.rgb.mean() / bright.rgb.mean() < 0.55
    _, lit = _render(_cfg({"lighting": {"extra_lights": [3, 3]}}), 2)
    assert lit.rgb.mean() > bright.rgb.mean() + 5


def test_shot_noise_grows_with_the_signal_and_read_noise_does_not():
    n = INTR.width * INTR.height
    for shot, read, grows in ((2.0, 0.0, True), (0.0, 3.0, False)):
        look = SensorLook({"shot_noise": shot, "read_noise": read}, INTR, 1.0, seed=1)
        var = {}
        for level in (20.0, 200.0):
            cols = [np.full(n, level + 0.5, np.float32) for _ in range(3)]
            look.linear(cols, np.random.default_rng(0))
            var[level] = float(np.var(np.concatenate(cols)))
        if grows:
            assert 8.0 < var[200.0] / var[20.0] < 12.0 and abs(var[20.0] - 2.0 * 20.0) < 8.0
        else:
            assert abs(var[200.0] / var[20.0] - 1.0) < 0.1 and abs(var[20.0] - 9.0) < 1.5
    # the camera's gain amplifies it: var = g k s
    look = SensorLook({"shot_noise": 2.0, "ev": 1.0}, INTR, 1.0, seed=1)
    cols = [np.full(n, 50.5, np.float32) for _ in range(3)]
    look.linear(cols, np.random.default_rng(0))
    assert 160 < np.var(np.concatenate(cols)) < 240


def test_the_tone_curve_and_vignetting_act_in_linear_light():
    n = INTR.width * INTR.height
    cols = [np.full(n, 64.5, np.float32) for _ in range(3)]
    SensorLook({"gamma": 2.0}, INTR, 1.0, seed=0).linear(cols, np.random.default_rng(0))
    assert np.allclose(cols[0], 255 * (64 / 255) ** 0.5 + 0.5, atol=1e-3)
    cols = [np.full(n, 100.5, np.float32) for _ in range(3)]
    SensorLook({"vignetting": 0.5}, INTR, 1.0, seed=0).linear(cols, np.random.default_rng(0))
    img = cols[1].reshape(INTR.height, INTR.width)
    assert abs(img[0, 0] - 50.5) < 2.0 and abs(img[INTR.height // 2, INTR.width // 2] - 100.5) < 1.0


def _blockiness(img: np.ndarray) -> float:
    """Mean step across 8-pixel block edges over the mean step inside blocks (1: no blocks)."""
    g = np.abs(np.diff(img.astype(np.float32).mean(-1), axis=1))
    edge = g[:, 7::8].mean()
    inner = np.delete(g, np.s_[7::8], axis=1).mean()
    return float(edge / inner)


def test_compression_quality_shows_as_artefacts():
    intr = Intrinsics.from_fov(128, 96, 60.0)
    _, plain = _render(_cfg(), 4, intr)
    err = {}
    for q in (10, 95):
        _, f = _render(_cfg({"sensor": {"compression": ["jpeg"], "jpeg_quality": [q, q]}}), 4, intr)
        err[q] = np.abs(f.rgb.astype(float) - plain.rgb).mean()
        if q == 10:
            assert _blockiness(f.rgb) > _blockiness(plain.rgb) + 0.3
    assert err[10] > 3 * err[95] and err[95] < 4.0  # 4:2:0 chroma costs colour edges even at 95
    _, h = _render(
        _cfg({"sensor": {"compression": ["h264"], "h264_quality": [30, 30], "h264_blur": [1.0, 1.0]}}), 4, intr
    )
    grad = [np.abs(np.diff(x.rgb.astype(float), axis=1)).mean() for x in (plain, h)]
    assert grad[1] < 0.8 * grad[0]  # the stand-in's blur and 4:2:0 chroma soften the frame


@pytest.mark.parametrize("codec", ["h264_stream", "h265_stream"])
def test_a_streamed_sequence_shows_its_bit_rate_and_its_frames_depend_on_the_ones_before(codec):
    """H.264 / H.265 through PyAV: the frames of a sequence go through one stream in order (each after the
    first predicted from the ones before), a lower bit rate costs more, and the same frames give the same bytes."""
    intr = Intrinsics.from_fov(128, 96, 60.0)
    scene = build_scene(np.random.default_rng(4), _cfg(), intr, 3)
    plain = Renderer(scene, intr, noise_seed=4)
    clean = [plain.render(p, np.random.default_rng(k)).rgb for k, p in enumerate(scene.camera.positions)]
    err, runs = {}, []
    for mbps in (1.0, 8.0, 8.0):
        look = {"compression": codec, "stream_mbps": mbps}
        sensor = SensorLook(look, intr, 1.0, 4)
        runs.append([sensor.compress(f.copy(), np.random.default_rng(0)) for f in clean])
        err[mbps] = np.mean([np.abs(a.astype(float) - b).mean() for a, b in zip(runs[-1], clean)])
    for a, b in zip(runs[1], runs[2]):
        np.testing.assert_array_equal(a, b)  # the same frames, the same bytes
    assert err[1.0] > 1.3 * err[8.0] > 0
    alone = SensorLook({"compression": codec, "stream_mbps": 8.0}, intr, 1.0, 4).compress(clean[2].copy(), None)
    assert not np.array_equal(alone, runs[1][2])  # in the stream it was predicted from frames 0 and 1
    assert all(f.shape == clean[0].shape and f.dtype == np.uint8 for f in runs[0])


def test_the_wide_look_streams_a_share_of_its_sequences_at_phone_and_robot_rates():
    cfg = load_config("wide_look")
    assert {"h264_stream", "h265_stream"} <= set(cfg["sensor"]["compression"])
    assert cfg["sensor"]["stream_mbps"] == [1, 8]
    looks = [draw_look(np.random.default_rng(s), cfg, INTR, np.zeros(3)) for s in range(60)]
    streamed = [lk for lk in looks if lk.get("compression", "none").endswith("_stream")]
    assert 10 < len(streamed) < 50 and all(1 <= lk["stream_mbps"] <= 8 for lk in streamed)


def test_a_lens_is_recorded_and_undistorting_the_frame_gives_the_pinhole_view(tmp_path):
    from waresynth.dataset import open_dataset
    from waresynth.generate import DatasetSettings, generate_dataset

    intr = Intrinsics.from_fov(128, 96, 60.0)
    lens_cfg = _cfg({"sensor": {"lens_k1": [-0.2, -0.2], "lens_k2": [0.01, 0.01]}})
    scene, bent = _render(lens_cfg, 3, intr)
    _, straight = _render(_cfg(), 3, intr)
    assert scene.look == {"lens_k1": -0.2, "lens_k2": 0.01}
    # every image is the lens's: pinhole pixel p shows what the lens's pixel at distort(p) shows (the convention
    # of layouts.lens.undistort_image), here read back nearest so the labels compare exactly
    lens = Lens(k1=-0.2, k2=0.01)
    u, v = np.meshgrid(np.arange(intr.width) + 0.5, np.arange(intr.height) + 0.5)
    xd, yd = lens.distort((u - intr.cx) / intr.fx, (v - intr.cy) / intr.fy)
    cu = np.clip(np.floor(xd * intr.fx + intr.cx), 0, intr.width - 1).astype(int)
    cv = np.clip(np.floor(yd * intr.fy + intr.cy), 0, intr.height - 1).astype(int)
    inner = np.s_[12:-12, 16:-16]
    before = (bent.semantic != straight.semantic)[inner].mean()
    after = (bent.semantic[cv, cu] != straight.semantic)[inner].mean()
    assert before > 0.08 and after < 0.4 * before
    assert undistort_image(bent.rgb, intr, lens).shape == bent.rgb.shape
    kw = dict(num_sequences=1, frames=2, image_size=(64, 48), spec=LayoutSpec(size=32), seed=1, progress=False)
    ds = open_dataset(
        generate_dataset(tmp_path / "d", DatasetSettings(config={"sensor": {"lens_k1": [-0.1, -0.1]}}, **kw))
    )
    rec = ds.sequences()[0].meta["intrinsics"]
    assert rec["k1"] == -0.1 and rec["k2"] == 0.0
    from layouts.camera_record import lens_from_record

    assert lens_from_record(rec, "meta.json") == Lens(k1=-0.1)
    with pytest.raises(InputError, match="sensor.lens_k1 = -0.500, lens_k2 = -0.300 fold the image over"):
        build_scene(
            np.random.default_rng(0), _cfg({"sensor": {"lens_k1": [-0.5, -0.5], "lens_k2": [-0.3, -0.3]}}), intr, 3
        )


def test_motion_blur_probability_blurs_a_share_of_the_sequences():
    cfg = _cfg({"sensor": {"motion_blur": [0.2, 0.4], "motion_blur_probability": 0.5}})
    drawn = [build_scene(np.random.default_rng(s), cfg, INTR, 2).sensor["motion_blur"] for s in range(20)]
    assert 4 <= sum(b > 0 for b in drawn) <= 16 and all(b == 0 or 0.2 <= b <= 0.4 for b in drawn)


@pytest.mark.parametrize(
    "bad, key",
    [
        ({"lighting": {"level": [0.5, 0.2]}}, "lighting.level"),
        ({"lighting": {"level": [0.0, 0.5]}}, "lighting.level"),
        ({"lighting": {"extra_lights": [0, 1.5]}}, "lighting.extra_lights"),
        ({"lighting": {"extra_lights": [0, 9]}}, "lighting.extra_lights"),
        ({"lighting": {"colour_temperature": [1000, 6500]}}, "lighting.colour_temperature"),
        ({"lighting": {"falloff": 0.02}}, "lighting.falloff"),
        ({"sensor": {"shot_noise": [-1, 1]}}, "sensor.shot_noise"),
        ({"sensor": {"read_noise": "high"}}, "sensor.read_noise"),
        ({"sensor": {"gamma": [0.1, 1.0]}}, "sensor.gamma"),
        ({"sensor": {"vignetting": [0.0, 1.0]}}, "sensor.vignetting"),
        ({"sensor": {"lens_k1": [-0.9, 0.0]}}, "sensor.lens_k1"),
        ({"sensor": {"exposure_ev": [0, 5]}}, "sensor.exposure_ev"),
        ({"sensor": {"auto_exposure": [0, 2]}}, "sensor.auto_exposure"),
        ({"sensor": {"white_balance_jitter": [0.1, 0.2]}}, "sensor.white_balance_jitter"),
        ({"sensor": {"motion_blur_probability": 1.5}}, "sensor.motion_blur_probability"),
        ({"sensor": {"compression": ["png"]}}, "sensor.compression"),
        ({"sensor": {"compression": []}}, "sensor.compression"),
        ({"sensor": {"jpeg_quality": [0, 90]}}, "sensor.jpeg_quality"),
        ({"sensor": {"jpeg_quality": [50.5, 90]}}, "sensor.jpeg_quality"),
        ({"sensor": {"jpeg_subsampling": ["4:1:1"]}}, "sensor.jpeg_subsampling"),
        ({"sensor": {"h264_blur": [0, 4]}}, "sensor.h264_blur"),
        ({"sensor": {"stream_mbps": [0, 4]}}, "sensor.stream_mbps"),
        ({"sensor": {"compression": ["h266_stream"]}}, "sensor.compression"),
        ({"boxes": {"textures": ["tiles"]}}, "boxes.textures"),
        ({"rack": {"board_textures": ["bricks"]}}, "rack.board_textures"),
    ],
)
def test_bad_look_values_are_refused_in_one_line_naming_the_key(bad, key):
    with pytest.raises(InputError) as e:
        load_config(bad)
    msg = str(e.value)
    assert msg.startswith(f"config: {key} ") and "\n" not in msg


def test_the_shipped_configs_load_by_name_and_the_shift_lies_outside_the_wide_ranges(tmp_path):
    assert shipped_configs() == ["shifted_look", "wide_camera", "wide_look"]
    wide, shifted = (json.loads((CONFIGS_DIR / f"{n}.json").read_text()) for n in ("wide_look", "shifted_look"))
    assert load_config("wide_look") == load_config(CONFIGS_DIR / "wide_look.json")
    for section in ("lighting", "sensor"):
        for k, v in shifted[section].items():
            w = wide[section].get(k, load_config()[section][k])
            if isinstance(v, list) and isinstance(v[0], (int, float)):
                assert v[0] > w[1] or v[1] < w[0], f"{section}.{k}: {v} overlaps {w}"
    for section in ("rack", "boxes", "floor", "wall"):
        assert not {tuple(c) for c in shifted[section]["colours"]} & {tuple(c) for c in wide[section]["colours"]}
    with pytest.raises(InputError, match="no_look: config file not found .*shifted_look, wide_camera, wide_look"):
        load_config("no_look")


def test_generate_takes_a_shipped_config_name_and_an_old_manifest_resumes(tmp_path, capsys):
    import shutil

    from mvracklay.cli import main
    from waresynth.dataset import open_dataset
    from waresynth.generate import DatasetSettings, generate_dataset

    args = ["generate", str(tmp_path / "w"), "--sequences", "2", "--frames", "2", "--size", "32", "--no-progress"]
    assert main([*args, "--config", "wide_look", "--seed", "3"]) == 0
    ds = open_dataset(tmp_path / "w")
    assert ds.config["lighting"]["level"] == [0.35, 1.3]
    assert all(sq.scene()["look"] for sq in ds.sequences())
    from waresynth.preview import format_summary, summarise

    said = format_summary(summarise(ds, progress=False))
    assert "look         2 of 2 sequences (waresynth.look): light level" in said
    # a dataset written before the look existed was neutral: it resumes as the default
    kw = dict(num_sequences=2, frames=2, image_size=(32, 32), spec=LayoutSpec(size=16), seed=4, progress=False)
    plain = generate_dataset(tmp_path / "plain", DatasetSettings(**kw))
    old = tmp_path / "old"
    shutil.copytree(plain, old)
    manifest = json.loads((old / "manifest.json").read_text())
    for section in ("lighting", "sensor"):
        for k in ("level", "falloff", "extra_lights", "extra_intensity", "colour_temperature", "gamma", "compression"):
            manifest["config"][section].pop(k, None)
    del manifest["config"]["rack"]["board_textures"]
    (old / "manifest.json").write_text(json.dumps(manifest))
    shutil.rmtree(old / "seq_00001")
    generate_dataset(old, DatasetSettings(**kw))
    np.testing.assert_array_equal(
        open_dataset(old).sequence("seq_00001").rgb(1), open_dataset(plain).sequence("seq_00001").rgb(1)
    )
