"""Training on compressed frames (`mvracklay train --jpeg P --jpeg-quality LOW HIGH`)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from tiny_net import TINY_NET

from layouts import InputError
from mvracklay.cli import main
from network.data import WindowDataset, jpeg_round_trip
from waresynth.dataset import open_dataset


def _windows(root, **kw) -> WindowDataset:
    ds = open_dataset(root)
    return WindowDataset(ds.sequences(), seq_len=4, input_size=(128, 128), spec=ds.spec, seed=3, max_stride=3, **kw)


def test_compressed_windows_keep_everything_but_the_pixels(tiny_dataset):
    plain = _windows(tiny_dataset, augment=True)
    comp = _windows(tiny_dataset, augment=True, jpeg=1.0, jpeg_quality=(10, 10))
    for idx in (0, 5, 13):
        a, b = plain[idx], comp[idx]
        # the same window, stride, flip, jitter and anchors as the run without --jpeg ...
        assert a["flipped"] == b["flipped"]
        for k in ("top", "front", "visible", "cam_x", "anchors", "rows"):
            assert np.array_equal(a[k].numpy(), b[k].numpy(), equal_nan=k == "anchors"), k
        # ... only the images went through JPEG
        assert 1.0 < float((a["images"] - b["images"]).abs().mean()) * 255 < 25.0
    # without augmentation (validation, evaluation) nothing is compressed
    off = _windows(tiny_dataset, augment=False, jpeg=1.0)
    assert np.array_equal(off[4]["images"].numpy(), _windows(tiny_dataset, augment=False)[4]["images"].numpy())


def test_lower_quality_changes_the_frames_more(tiny_dataset):
    rgb = open_dataset(tiny_dataset).sequences()[0].rgb(2)
    err = {q: np.abs(jpeg_round_trip(rgb, q).astype(float) - rgb).mean() for q in (10, 40, 90)}
    assert err[10] > err[40] > err[90] > 0.0
    plain = _windows(tiny_dataset, augment=True)[7]["images"]
    diff = {
        q: float(
            (_windows(tiny_dataset, augment=True, jpeg=1.0, jpeg_quality=(q, q))[7]["images"] - plain).abs().mean()
        )
        for q in (10, 90)
    }
    assert diff[10] > 2 * diff[90] > 0.0


def test_the_share_and_qualities_of_compressed_windows(tiny_dataset):
    ds = _windows(tiny_dataset, augment=True, jpeg=0.5, jpeg_quality=(30, 60))
    draws = [ds._jpeg_quality(i) for i in range(len(ds))]
    qs = [q for q in draws if q is not None]
    assert 0.25 < len(qs) / len(draws) < 0.75 and min(qs) >= 30 and max(qs) <= 60 and len(set(qs)) > 3
    assert draws == [ds._jpeg_quality(i) for i in range(len(ds))]  # same seed and epoch, same draws
    ds.set_epoch(1)
    assert draws != [ds._jpeg_quality(i) for i in range(len(ds))]  # a new epoch draws again
    assert all(_windows(tiny_dataset, augment=True)._jpeg_quality(i) is None for i in range(len(ds)))


@pytest.mark.parametrize(
    ("kw", "word"),
    [
        ({"jpeg": 1.5}, "jpeg must"),
        ({"jpeg_quality": (60, 30)}, "jpeg_quality"),
        ({"jpeg_quality": (0, 30)}, "jpeg_quality"),
    ],
)
def test_bad_jpeg_settings_are_refused(tiny_dataset, kw, word):
    with pytest.raises(InputError, match=word):
        _windows(tiny_dataset, augment=True, **kw)


def test_train_records_the_setting_and_refuses_bad_flags(tiny_dataset, tmp_path, capsys):
    out = tmp_path / "run"
    args = ["train", "--data", str(tiny_dataset), "--out", str(out), "--epochs", "1", "--steps-per-epoch", "1"]
    assert main([*args, "--frames-per-step", "4", "--jpeg", "0.5", "--jpeg-quality", "20", "70", *TINY_NET]) == 0
    cfg = json.loads((out / "last.json").read_text())["train_config"]
    assert cfg["jpeg"] == 0.5 and list(cfg["jpeg_quality"]) == [20, 70]
    capsys.readouterr()
    for bad, flag in (
        (["--jpeg", "2"], "--jpeg "),
        (["--jpeg", "0.5", "--jpeg-quality", "80", "20"], "--jpeg-quality"),
    ):
        assert main([*args[:3], "--out", str(tmp_path / "bad"), *bad, *TINY_NET]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and flag in err
