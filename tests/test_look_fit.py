"""The look-invariance fit: frames restyled in image space (`waresynth.restyle`) and stage ``fit-look``."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from layouts.camera import Intrinsics
from layouts.errors import InputError
from network.checkpoint import load_checkpoint
from network.model.frozen import PARTS
from waresynth.config import load_config
from waresynth.restyle import Restyler, box_blur_rows, light_field

INTR = Intrinsics.from_fov(64, 48, 60.0)


def _frame(seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    img = np.full((48, 64, 3), 120, np.uint8)
    img[10:30, 8:40] = rng.integers(0, 255, 3)
    return img


def test_a_drawn_look_restyles_the_same_frame_to_the_same_bytes_and_another_look_differs():
    r = Restyler("wide_look")
    a = r.draw(np.random.default_rng(1), INTR)
    b = r.draw(np.random.default_rng(1), INTR)
    assert a == b
    img = _frame()
    out = r.apply(img, a, INTR, step_px=6.0)
    assert out.dtype == np.uint8 and out.shape == img.shape
    assert np.array_equal(out, r.apply(img, b, INTR, step_px=6.0))
    other = r.apply(img, r.draw(np.random.default_rng(2), INTR), INTR, step_px=6.0)
    assert not np.array_equal(out, other)


def test_drawn_looks_stay_in_the_configs_ranges_and_leave_the_lens_out():
    cfg = load_config("shifted_look")
    r = Restyler("shifted_look")
    for seed in range(20):
        d = r.draw(np.random.default_rng(seed), INTR)
        look = d["look"]
        assert cfg["lighting"]["level"][0] <= look["level"] <= cfg["lighting"]["level"][1]
        assert cfg["sensor"]["shot_noise"][0] <= look["shot_noise"] <= cfg["sensor"]["shot_noise"][1]
        assert cfg["sensor"]["motion_blur"][0] <= d["motion_blur"] <= cfg["sensor"]["motion_blur"][1]
        assert look["compression"] in cfg["sensor"]["compression"]
        assert "lens_k1" not in look and "lens_k2" not in look


def test_a_dim_look_darkens_and_adds_noise_where_the_frame_is_flat():
    cfg = load_config("shifted_look")
    cfg["sensor"]["compression"] = ["none"]
    r = Restyler(cfg)
    img = np.full((48, 64, 3), 160, np.uint8)
    out = r.apply(img, r.draw(np.random.default_rng(0), INTR), INTR).astype(float)
    assert out.std() > 3.0  # flat input: all of the spread is the look's noise and light field
    neutral = Restyler(load_config())  # the default config draws no look: only its Gaussian noise
    same = neutral.apply(img, neutral.draw(np.random.default_rng(0), INTR), INTR).astype(float)
    assert abs(same.mean() - 160) < 20 and same.std() < 6


def test_the_light_field_has_mean_one_and_the_row_blur_keeps_a_flat_image():
    f = light_field(np.random.default_rng(0), 40, 60, falloff=0.08, lights=3, strength=0.5)
    assert f.shape == (40, 60) and abs(f.mean() - 1) < 1e-5 and f.min() > 0 and f.std() > 0.01
    cols = [np.full(40 * 60, 7.0, np.float32) for _ in range(3)]
    box_blur_rows(cols, 40, 60, 5.5)
    assert all(np.allclose(c, 7.0) for c in cols)
    edge = np.zeros((40, 60), np.float32)
    edge[:, 30:] = 100
    cols = [edge.reshape(-1).copy()]
    box_blur_rows(cols, 40, 60, 6.0)
    row = cols[0].reshape(40, 60)[0]
    assert 0 < row[29] < 100 and 0 < row[30] < 100 and row[0] == 0 and row[-1] == pytest.approx(100)


def test_restyle_refuses_a_frame_that_is_not_uint8_rgb():
    r = Restyler("wide_look")
    d = r.draw(np.random.default_rng(0), INTR)
    with pytest.raises(InputError, match="restyle: expected a uint8"):
        r.apply(np.zeros((48, 64), np.uint8), d, INTR)
    with pytest.raises(InputError, match="restyle: expected a uint8"):
        r.apply(np.zeros((48, 64, 3), np.float32), d, INTR)


def test_fit_look_tunes_the_trunk_alone_and_resumes(tiny_checkpoint, tiny_dataset, tmp_path, monkeypatch, capsys):
    from mvracklay.training import stages
    from network.training import fit_look

    out = tmp_path / "look.pt"
    argv = ["--checkpoint", str(tiny_checkpoint), "--data", str(tiny_dataset), "--out", str(out), "--steps", "3"]
    argv += ["--batch", "2", "--threads", "1", "--quiet", "--json-out", str(tmp_path / "fit.json")]
    # the first run stops after the state of step 2 is saved: the rerun resumes there
    monkeypatch.setattr(fit_look, "SAVE_EVERY", 1)
    real, calls = fit_look.make_pairs, {"n": 0}

    def failing(*a, **k):
        calls["n"] += 1
        if calls["n"] == 4:  # the validation batch, steps 1 and 2, then this
            raise RuntimeError("interrupted")
        return real(*a, **k)

    monkeypatch.setattr(fit_look, "make_pairs", failing)
    with pytest.raises(RuntimeError, match="interrupted"):
        stages.run_stage("fit-look", argv)
    state = out.with_name(out.name + ".fit-state.pt")
    assert state.is_file() and not out.exists()
    monkeypatch.setattr(fit_look, "make_pairs", real)
    assert stages.run_stage("fit-look", argv) == 0
    assert "resuming at step 2 of 3" in capsys.readouterr().err
    assert out.is_file() and not state.exists()
    (old, _), (new, record) = load_checkpoint(tiny_checkpoint), load_checkpoint(out)
    fit = record["look_fit"]
    assert fit["steps"] == 3 and len(fit["val_loss"]) == 2 and fit["look"] == "wide_look"
    trunk = tuple(f"{m}." for m in PARTS["trunk"].modules)
    moved = [k for k in old["model"] if not torch.equal(old["model"][k], new["model"][k])]
    assert moved and all(k.startswith(trunk) for k in moved)
    assert set(old["model"]) == set(new["model"])


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--steps", "0"], "fit-look: steps >= 1"),
        (["--minutes", "0"], "--minutes must be > 0"),
        (["--look", "no_such_look"], "no_such_look: config file not found"),
    ],
)
def test_fit_look_refuses_bad_options_in_one_line(tiny_checkpoint, tiny_dataset, tmp_path, capsys, extra, message):
    from mvracklay.training import stages

    argv = ["--checkpoint", str(tiny_checkpoint), "--data", str(tiny_dataset), "--out", str(tmp_path / "x.pt")]
    assert stages.run_stage("fit-look", [*argv, "--quiet", *extra]) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1 and not (tmp_path / "x.pt").exists()


def test_objects_are_recoloured_one_colour_each_and_only_with_their_labels():
    from waresynth.restyle import recolour_gains

    sem = np.zeros((48, 64), np.uint8)
    inst = np.zeros((48, 64), np.uint16)
    sem[10:30, 8:40], inst[10:30, 8:40] = 5, 3
    g = recolour_gains(sem, inst, seed=4).reshape(48, 64, 3)
    assert np.allclose(g[10:30, 8:40], g[12, 10]) and np.allclose(g[:10], g[0, 0])
    assert not np.allclose(g[12, 10], g[0, 0])
    assert np.array_equal(g, recolour_gains(sem, inst, seed=4).reshape(48, 64, 3))
    cfg = load_config()
    cfg["sensor"]["noise_sigma"] = [0.0, 0.0]
    r = Restyler(cfg)
    d = {**r.draw(np.random.default_rng(0), INTR), "recolour": True}
    img = _frame()
    assert not np.array_equal(r.apply(img, d, INTR, labels=(sem, inst)), r.apply(img, d, INTR))
    with pytest.raises(InputError, match="labels of shape"):
        r.apply(img, d, INTR, labels=(sem[:10], inst[:10]))
