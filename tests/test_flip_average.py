"""Test-time flip averaging (`Predictor(flip=True)`, `--flip-average`): what it computes, in every mode."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from tiny_net import tiny_config

from layouts import VIEWS, LayoutSpec
from network.inference.decision import apply_box_offset
from network.inference.predictor import Predictor
from network.model.net import MVRackLay
from network.training.toy import ToySequence

SPEC = LayoutSpec(num_slots=2, size=16)
OFFSETS = {"top": 0.5, "front": 0.25}


def tiny_model(seed: int = 3) -> MVRackLay:
    torch.manual_seed(seed)
    model = MVRackLay(tiny_config(SPEC)).eval()
    torch.nn.init.constant_(model.rows.net[-1].bias, 2.0)  # the row head finds boards, so slots decode
    model.box_logit_offset = dict(OFFSETS)
    return model


def toy_frames(n: int = 5) -> list[np.ndarray]:
    seq = ToySequence(SPEC, num_frames=n, image_size=(64, 64))
    return [seq.rgb(i) for i in range(n)]


def test_streamed_flip_average_is_the_mean_of_a_direct_and_a_mirrored_pass():
    model, frames = tiny_model(), toy_frames()
    got = list(Predictor(model, flip=True, fuse_tau=0).stream(frames))  # each frame alone (network.inference.fusion)
    plain = Predictor(model, fuse_tau=0)
    direct = mirrored = None
    with torch.no_grad():
        for i, f in enumerate(frames):
            x = plain.preprocess(f, i)
            a, direct = model.step(x, direct)
            b, mirrored = model.step(x.flip(-1), mirrored, a["anchors"])  # the mirrored pass fills the same slots
            for v in VIEWS:
                want = apply_box_offset(0.5 * (a[v][0] + b[v][0].flip(-1)), OFFSETS[v])
                torch.testing.assert_close(getattr(got[i], v), want, rtol=1e-5, atol=1e-6)
            torch.testing.assert_close(got[i].anchors, a["anchors"][0])
            assert torch.isfinite(a["anchors"]).any()
    # and it is not the plain prediction
    assert not torch.allclose(got[-1].top, list(plain.stream(frames))[-1].top, atol=1e-4)


def test_windowed_flip_average_cached_equals_re_encoded():
    model, frames = tiny_model(4), toy_frames(6)
    pred = Predictor(model, flip=True, fuse_tau=0)
    cached, naive = list(pred.window(frames)), list(pred.window(frames, recompute=True))
    assert len(cached) == len(naive) == 6
    for c, n in zip(cached, naive):
        for k in (*VIEWS, "anchors"):
            torch.testing.assert_close(getattr(c, k), getattr(n, k), rtol=1e-4, atol=1e-5)


@pytest.mark.parametrize("mode", ["stream", "window"])
def test_flip_average_of_mirror_symmetric_frames_is_mirror_symmetric(mode):
    model = tiny_model(5)
    frames = []
    for f in toy_frames(4):
        left = f[:, :32]
        frames.append(np.ascontiguousarray(np.concatenate([left, left[:, ::-1]], axis=1)))
    plain, flipped = Predictor(model, fuse_tau=0), Predictor(model, flip=True, fuse_tau=0)
    x = plain.preprocess(frames[0])
    torch.testing.assert_close(x, x.flip(-1))  # the canonical warp keeps the symmetry
    for out in flipped.run(frames, mode):
        for v in VIEWS:
            torch.testing.assert_close(getattr(out, v), getattr(out, v).flip(-1), rtol=1e-5, atol=1e-5)
    last = list(plain.run(frames, mode))[-1]
    assert not torch.allclose(last.top, last.top.flip(-1), atol=1e-3)  # the model alone is not symmetric
