"""Neighbouring frames' layouts fused along the row (`network.inference.fusion`, ``Predictor(fuse_tau=...)``)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from tiny_net import fixed_steps, tiny_config

from layouts import VIEWS
from layouts.errors import InputError
from layouts.spec import LayoutSpec
from network.inference.fusion import LayoutFusion, check_tau, fuse_sequence, seen_columns
from network.inference.predictor import Predictor
from network.model.motion import motion_signature
from network.model.net import MVRackLay
from network.training.fit_box_depth import with_box_head
from network.training.toy import ToySequence

D = 16
X_EXTENT = 3.0
COL = X_EXTENT / D  #: metres per layout column


def _frames(n: int, seed: int = 0) -> tuple[list[dict[str, torch.Tensor]], list[float], list[torch.Tensor]]:
    """Random logits, camera steps of 0-2 whole columns one way along the row and random seen masks for
    ``n`` frames (what leaves the layouts' X extent is dropped, so a camera that turns back starts over)."""
    g = torch.Generator().manual_seed(seed)
    logits = [{v: torch.randn(2, 3, D, D, generator=g) for v in VIEWS} for _ in range(n)]
    cols = torch.randint(0, 3, (n,), generator=g) * (1 if seed % 2 else -1)
    steps = [0.0] + [float(c) * COL for c in cols[1:]]
    seen = [(torch.rand(D, generator=g) > 0.2).float() for _ in range(n)]
    return logits, steps, seen


def _brute(logits, steps, seen, tau: float, causal: bool) -> list[dict[str, torch.Tensor]]:
    """The definition, frame by frame: every other frame's logits moved into this frame's columns
    (frame s's column c + (x_t - x_s) / column), weighted exp(-|t - s| / tau) over the columns it saw."""
    x = np.cumsum(np.round(np.array(steps) / COL)).astype(int)  # camera position in columns
    out = []
    for t in range(len(logits)):
        num = {v: torch.zeros_like(logits[t][v]) for v in VIEWS}
        den = torch.zeros(D)
        for s in range(len(logits)):
            if causal and s > t:
                continue
            w = math.exp(-abs(t - s) / tau)
            src = torch.arange(D) + int(x[t] - x[s])
            ok = (src >= 0) & (src < D)
            m = torch.zeros(D)
            m[ok] = seen[s][src[ok]] * w
            den += m
            for v in VIEWS:
                moved = torch.zeros_like(logits[s][v])
                moved[..., ok] = logits[s][v][..., src[ok]]
                num[v] += moved * m
        out.append({v: torch.where(den > 1e-3, num[v] / den.clamp(min=1e-3), logits[t][v]) for v in VIEWS})
    return out


@pytest.mark.parametrize("tau", [0.5, 1.0, 3.0])
def test_streaming_fusion_is_the_decayed_average_of_the_frames_so_far(tau):
    logits, steps, seen = _frames(7, seed=1)
    fusion = LayoutFusion(tau, X_EXTENT)
    got = [fusion.add(lg, st, sn) for lg, st, sn in zip(logits, steps, seen)]
    want = _brute(logits, steps, seen, tau, causal=True)
    for g, w in zip(got, want):
        for v in VIEWS:
            torch.testing.assert_close(g[v], w[v], atol=1e-3, rtol=1e-3)


@pytest.mark.parametrize("tau", [0.5, 1.0, 3.0])
def test_sequence_fusion_also_takes_the_later_frames(tau):
    logits, steps, seen = _frames(7, seed=2)
    got = fuse_sequence(logits, steps, seen, tau, X_EXTENT)
    want = _brute(logits, steps, seen, tau, causal=False)
    for g, w in zip(got, want):
        for v in VIEWS:
            torch.testing.assert_close(g[v], w[v], atol=1e-3, rtol=1e-3)
    # the first frame gains what the later ones show; the streaming form cannot
    first = LayoutFusion(tau, X_EXTENT).add(logits[0], 0.0, seen[0])
    assert not torch.allclose(got[0]["top"], first["top"])


def test_one_world_seen_from_moving_frames_stays_put():
    """Frames that agree on the world (each the same row seen from its own place) fuse to themselves."""
    world = torch.randn(2, 3, D, 4 * D)
    steps = [0.0, 2 * COL, 3 * COL, COL]
    x = np.cumsum(np.round(np.array(steps) / COL)).astype(int) + D
    logits = [{v: world[..., c : c + D].clone() for v in VIEWS} for c in x]
    seen = [torch.ones(D)] * len(steps)
    fusion = LayoutFusion(1.0, X_EXTENT)
    for lg, st, sn in zip(logits, steps, seen):
        torch.testing.assert_close(fusion.add(lg, st, sn)["front"], lg["front"], atol=1e-5, rtol=1e-5)


def test_columns_no_frame_saw_keep_their_own_logits():
    logits, steps, _ = _frames(3, seed=3)
    blind = [torch.zeros(D)] * 3
    for g, lg in zip(fuse_sequence(logits, [0.0] * 3, blind, 1.0, X_EXTENT), logits):
        assert torch.equal(g["top"], lg["top"])


def test_seen_columns_follow_the_canonical_images_source_pixels():
    sig = torch.zeros(1, 2, 8, 64)
    sig[:, 1, :, 16:48] = 1.0  # the source image covers the middle half of the canonical columns
    assert seen_columns(sig, 16).tolist() == [0.0] * 4 + [1.0] * 8 + [0.0] * 4


@pytest.mark.parametrize("bad", [-1.0, float("nan"), float("inf"), True, "1"])
def test_bad_tau_is_refused_by_name(bad):
    with pytest.raises(InputError, match="--fuse-frames"):
        check_tau(bad, "--fuse-frames")


def test_predictor_fuses_its_decided_logits_with_the_motion_it_reads(monkeypatch):
    """``Predictor(fuse_tau)`` gives `LayoutFusion` / `fuse_sequence` of the unfused outputs, with the
    camera steps it reads and the columns the canonical images hold; the box-depth head still reads
    each frame's own outputs."""
    spec = LayoutSpec(size=16)
    model = with_box_head(MVRackLay(tiny_config(spec)).eval())
    torch.nn.init.constant_(model.rows.net[-1].bias, 2.0)
    step = spec.x_extent / spec.size
    monkeypatch.setattr("network.inference.predictor.StepReader", fixed_steps(step))
    seq = ToySequence(spec, num_frames=4, image_size=(64, 64))
    frames = [seq.rgb(i) for i in range(4)]
    plain_pred = Predictor(model, rack_depth=0.8, fuse_tau=0)
    seen = [seen_columns(motion_signature(plain_pred.preprocess(f, i)), spec.size) for i, f in enumerate(frames)]
    steps = [0.0] + [step] * 3
    for mode in ("stream", "window"):
        plain = list(plain_pred.run(frames, mode))
        raw = [{v: getattr(p, v) for v in VIEWS} for p in plain]
        fusion = LayoutFusion(1.0, spec.x_extent)
        want = [fusion.add(lg, st, sn) for lg, st, sn in zip(raw, steps, seen)]
        got = list(Predictor(model, rack_depth=0.8, fuse_tau=1.0).run(frames, mode))
        want_whole = fuse_sequence(raw, steps, seen, 1.0, spec.x_extent)
        whole = list(Predictor(model, rack_depth=0.8, fuse_tau=1.0, whole_sequence=True).run(frames, mode))
        for p, g, w, gw, ww in zip(plain, got, want, whole, want_whole):
            for v in VIEWS:
                torch.testing.assert_close(getattr(g, v), w[v])
                torch.testing.assert_close(getattr(gw, v), ww[v])
            assert np.array_equal(g.box_back, p.box_back, equal_nan=True)
        assert not torch.allclose(got[1].top, plain[1].top)  # fusion did something


@pytest.mark.parametrize("command", ["evaluate", "predict", "run", "eval-reconstruction"])
def test_fuse_frames_option_fails_with_one_line(command, tiny_dataset, tiny_checkpoint, tmp_path, capsys):
    from mvracklay.cli import main

    seq = str(sorted(p for p in tiny_dataset.iterdir() if p.is_dir())[0])
    ck = ["--checkpoint", str(tiny_checkpoint)]
    argv = {
        "evaluate": [*ck, "--data", str(tiny_dataset)],
        "predict": [seq, *ck, "--out", str(tmp_path / "pred")],
        "run": [seq, *ck, "--out", str(tmp_path / "run")],
        "eval-reconstruction": [str(tiny_dataset), *ck],
    }[command]
    assert main([command, *argv, "--fuse-frames", "-1"]) == 2
    err = capsys.readouterr().err
    assert "--fuse-frames" in err and len(err.strip().splitlines()) == 1, err
    assert not (tmp_path / "pred").exists() and not (tmp_path / "run").exists()  # nothing written


def test_fuse_frames_is_off_unless_asked_and_tau_1_when_bare():
    from mvracklay.cli import build_parser
    from network.inference.fusion import FUSE_TAU

    parse = build_parser().parse_args
    base = ["evaluate", "--checkpoint", "c.pt", "--data", "d"]
    assert parse(base).fuse_frames == 0.0
    assert parse([*base, "--fuse-frames"]).fuse_frames == FUSE_TAU == 1.0
    assert parse([*base, "--fuse-frames", "0.5"]).fuse_frames == 0.5
    assert Predictor(MVRackLay(tiny_config(LayoutSpec(size=16)))).fuse_tau == 0.0
