"""The box-depth fit's cold start: the frames before the kept ones skip the network (`HeadInputPredictor(trunk_from=)`,
`fit-box-depth --cold-start`), entering only the motion estimate and the parallax history."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from layouts import VIEWS
from layouts.errors import InputError
from mvracklay.training.stages import run_stage
from network.checkpoint import load_checkpoint, load_model
from network.heads.boxdepth import PARALLAX_CHANNELS
from network.inference.predictor import Predictor, sequence_camera
from network.training.box_cache import FrameChoice, cache_inputs
from network.training.fit_box_depth import with_box_head
from network.training.head_inputs import HeadInputPredictor
from waresynth.dataset import open_dataset
from waresynth.visibility import SeenTracker


@pytest.fixture(scope="module")
def parallax_model(tiny_checkpoint):
    return with_box_head(load_model(tiny_checkpoint)[0], parallax=True)


def test_frames_before_trunk_from_skip_the_network_and_the_memory_starts_there(parallax_model, tiny_dataset):
    model = parallax_model
    seq = open_dataset(tiny_dataset).sequences()[0]
    frames = [seq.rgb(i) for i in range(6)]
    camera, k = sequence_camera(seq), 2
    calls = []
    step = model.step
    model.step = lambda *a, **kw: calls.append(1) or step(*a, **kw)
    try:
        cold = list(HeadInputPredictor(model, camera, read_depth=False, box_inputs_from=k, trunk_from=k)
                    .stream(frames))  # fmt: skip
    finally:
        del model.step
    assert len(calls) == len(frames) - k and cold[:k] == [None] * k
    fresh = list(Predictor(model, lambda i: camera(i + k), read_depth=False).stream(frames[k:]))
    for a, b in zip(cold[k:], fresh):  # the network's outputs: a stream begun at frame k
        for v in VIEWS:
            torch.testing.assert_close(getattr(a, v), getattr(b, v), rtol=0, atol=0)
    warm = list(HeadInputPredictor(model, camera, read_depth=False, box_inputs_from=k).stream(frames))
    for a, b in zip(cold[k:], warm[k:]):  # the parallax history holds the skipped frames all the same
        torch.testing.assert_close(a.maps["box_parallax"], b.maps["box_parallax"], rtol=0, atol=0)


def test_trunk_from_is_refused_where_it_cannot_hold(parallax_model, tiny_dataset):
    camera = sequence_camera(open_dataset(tiny_dataset).sequences()[0])
    base = {"read_depth": False, "box_inputs_from": 2}
    for extra, word in (({"trunk_from": 3}, "trunk_from must be"), ({"trunk_from": True}, "trunk_from must be"),
                        ({"trunk_from": 2, "flip": True}, "not with flip"),
                        ({"trunk_from": 2, "fuse_tau": 1.0}, "not with flip")):  # fmt: skip
        with pytest.raises(InputError, match=word):
            HeadInputPredictor(parallax_model, camera, **{**base, **extra})
    with pytest.raises(InputError, match="windowed mode"):
        HeadInputPredictor(parallax_model, camera, **base, trunk_from=1).window([])


def test_a_cold_cache_keeps_the_same_slots_and_targets_and_keys_its_own_cache(
    parallax_model, tiny_checkpoint, tiny_dataset, tmp_path, capsys
):
    seq = open_dataset(tiny_dataset).sequences()[:1]
    (tmp_path / "warm").mkdir()
    (tmp_path / "cold").mkdir()
    warm = cache_inputs(parallax_model, seq, SeenTracker, tmp_path / "warm", False, FrameChoice(5, 2))
    cold = cache_inputs(parallax_model, seq, SeenTracker, tmp_path / "cold", False, FrameChoice(5, 2, cold=True))
    assert len(cold) == len(warm) > 0
    for k in ("back", "shown", "front"):
        np.testing.assert_array_equal(np.asarray(getattr(cold, k)), np.asarray(getattr(warm, k)))
    p = PARALLAX_CHANNELS
    np.testing.assert_array_equal(np.asarray(cold.win)[:, -p:], np.asarray(warm.win)[:, -p:])
    assert not np.array_equal(np.asarray(cold.extra), np.asarray(warm.extra))  # the decoders' own memory
    assert FrameChoice(5, 2, cold=True).key() == {"frames": 5, "from_frame": 2, "cold": True}
    assert FrameChoice(5, 2).key() == {"frames": 5, "from_frame": 2}  # caches kept before keep their keys

    keep = tmp_path / "kept"
    args = ["--checkpoint", str(tiny_checkpoint), "--data", str(tiny_dataset), "--epochs", "1",
            "--threads", "1", "--quiet", "--keep-cache", str(keep), "--frames", "4", "--from-frame", "2"]  # fmt: skip
    assert run_stage("fit-box-depth", [*args, "--cold-start", "--out", str(tmp_path / "a.pt")]) == 0
    assert load_checkpoint(tmp_path / "a.pt")[1]["box_depth"]["cold"] is True
    capsys.readouterr()
    assert (
        run_stage("fit-box-depth", [*args, "--out", str(tmp_path / "b.pt")]) == 2
    )  # a warm fit: another cache's inputs, refused
    assert "another" in capsys.readouterr().err
    bad = ["--checkpoint", str(tiny_checkpoint), "--data", str(tiny_dataset), "--cold-start",
           "--out", str(tmp_path / "c.pt")]  # fmt: skip
    assert run_stage("fit-box-depth", bad) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--cold-start" in err and "--from-frame" in err
