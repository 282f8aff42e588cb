"""The frozen graphs (`network.model.frozen`): the modules' function, never stale, only where they apply."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from tiny_net import tiny_config

from layouts.errors import InputError
from layouts.spec import LayoutSpec
from network.heads.boxdepth import head_inputs
from network.inference.predictor import Predictor, warm_up
from network.model import frozen
from network.model.net import MVRackLay


def _model(seed: int = 0, **options) -> MVRackLay:
    torch.manual_seed(seed)
    model = MVRackLay(tiny_config(LayoutSpec(size=16), **options))
    for m in model.modules():  # batch norms with statistics of their own, so folding them is not a no-op
        if isinstance(m, (torch.nn.BatchNorm1d, torch.nn.BatchNorm2d)):
            m.running_mean.uniform_(-0.5, 0.5)
            m.running_var.uniform_(0.5, 2.0)
    return model.eval()


def _close(a: tuple[torch.Tensor, ...], b: tuple[torch.Tensor, ...]) -> None:
    for p, q in zip(a, b, strict=True):
        torch.testing.assert_close(p, q, rtol=1e-4, atol=1e-5)


def _builds(monkeypatch) -> list[tuple]:
    """Each graph built from now on, as (part, first input's shape)."""
    built: list[tuple] = []
    build = frozen._build

    def counted(model, part, fn, xs, bf16):
        built.append((part, tuple(xs[0].shape)) + (("bf16",) if bf16 else ()))
        return build(model, part, fn, xs, bf16)

    monkeypatch.setattr(frozen, "_build", counted)
    return built


def _off(model: MVRackLay, fn):
    """``fn()`` with the model's graphs turned off (the modules' own outputs)."""
    model.frozen_graphs = False
    try:
        return fn()
    finally:
        model.frozen_graphs = True


def test_the_graph_gives_the_modules_maps_once_built_per_shape(monkeypatch):
    model = _model()
    builds = _builds(monkeypatch)
    x1, x4 = torch.rand(1, 3, 64, 64), torch.rand(4, 3, 64, 64)
    with torch.no_grad():
        want1, want4 = frozen.trunk_maps(model, x1), frozen.trunk_maps(model, x4)
        for _ in range(2):  # a stream and a window alternating: one graph each, built once
            _close(model.maps(x1), want1)
            _close(model.maps(x4), want4)
        assert all(m.is_contiguous() for m in model.maps(x1))  # the channels-last trunk's maps given back
    assert builds == [("trunk", (1, 3, 64, 64)), ("trunk", (4, 3, 64, 64))]
    assert all(held[2] is not None for held in frozen._GRAPHS[model].values())  # graphs, not the fallback


def test_a_stream_through_the_graphs_gives_the_modules_outputs(monkeypatch):
    """Trunk, slot maps and box windows, and the box-depth head: a streamed frame's outputs within rounding."""
    model = _model(box_depth=True)
    builds = _builds(monkeypatch)
    frames = [torch.rand(1, 3, 64, 64) for _ in range(3)]
    anchors = torch.tensor([[40.0, 20.0, float("nan")]])  # slot 2 has none: its outputs are the background
    with torch.no_grad():

        def stream():
            outs, state = [], None
            for x in frames:
                out, state = model.step(x, state, anchors=anchors, motion=torch.tensor([0.05]))
                inputs = head_inputs(
                    out["box_window"][0], out["top"][0], out["front"][0], anchors[0], model.cfg.view, 2.5
                )
                outs.append((out["top"], out["front"], out["box_window"], model.box_logits(*inputs)))
            return outs

        want = _off(model, stream)
        assert builds == []
        for got, ref in zip(stream(), want, strict=True):
            _close(got, ref)
    assert sorted(p for p, _ in builds) == ["box_depth", "slots", "trunk"]  # each built once for the stream


def test_changed_weights_rebuild_the_graph(monkeypatch):
    model, other = _model(0), _model(1)
    builds = _builds(monkeypatch)
    x = torch.rand(1, 3, 64, 64)
    opt = torch.optim.SGD(model.parameters(), lr=0.5)
    with torch.no_grad():
        before = model.maps(x)
    model.train()
    loss = sum(m.square().mean() for m in model.maps(x))  # training: the modules, with gradients
    loss.backward()
    opt.step()  # in-place updates of the trunk's weights
    model.eval()
    with torch.no_grad():
        after = model.maps(x)
        _close(after, frozen.trunk_maps(model, x))
        assert not torch.allclose(after[0], before[0], atol=1e-4)
        model.load_state_dict(other.state_dict())  # another network's weights copied in
        _close(model.maps(x), frozen.trunk_maps(other, x))
    assert len(builds) == 3


def test_a_head_fitted_on_the_frozen_trunk_rebuilds_its_graph_alone(monkeypatch):
    """As the `fit-box-depth` stage does: only the box-depth head's weights move; its graph follows them."""
    model = _model(box_depth=True)
    win = torch.rand(3, model.box_depth.c2d, 8, 32)
    extra = torch.rand(3, model.box_depth.c1d, model.cfg.spec.size)
    x = torch.rand(1, 3, 64, 64)
    with torch.no_grad():
        model.maps(x)
        before = model.box_logits(win, extra)
    builds = _builds(monkeypatch)
    head = model.box_depth.train()
    opt = torch.optim.SGD(head.parameters(), lr=0.5)
    head(win, extra).square().mean().backward()
    opt.step()
    head.eval()
    with torch.no_grad():
        after = model.box_logits(win, extra)
        _close((after,), (head(win, extra),))
        assert not torch.allclose(after, before, atol=1e-4)
        model.maps(x)  # the trunk's graph still holds
    assert builds == [("box_depth", (3, model.box_depth.c2d, 8, 32))]


def test_the_modules_run_where_the_graph_does_not_apply(monkeypatch):
    model = _model()
    builds = _builds(monkeypatch)
    x = torch.rand(2, 3, 64, 64)
    with torch.no_grad():
        want = frozen.trunk_maps(model, x)
        off = _off(model, lambda: model.maps(x))
        with torch.autocast("cpu", dtype=torch.bfloat16):
            model.maps(x)
    for p, q in zip(off, want, strict=True):
        assert torch.equal(p, q)
    assert model.maps(x)[0].requires_grad  # gradients on
    model.train()
    with torch.no_grad():
        model.maps(x)  # training mode: batch statistics
    assert builds == []


def test_a_bf16_trunk_graph_gives_float32_maps_near_the_modules_and_leaves_the_weights(monkeypatch):
    model = _model()
    builds = _builds(monkeypatch)
    x = torch.rand(2, 3, 64, 64)
    with torch.no_grad():
        want = frozen.trunk_maps(model, x)
        _close(model.maps(x), want)
        frozen.set_precision(model, "bf16")
        got = model.maps(x)
        for g, w in zip(got, want, strict=True):
            assert g.dtype == torch.float32 and g.is_contiguous() and g.shape == w.shape
            err = float((g - w).abs().mean() / w.abs().mean())
            assert 0 < err < 0.05  # bf16 rounding: near the float32 maps, not them
        model.maps(x)  # built once
        frozen.set_precision(model, "fp32")
        _close(model.maps(x), want)  # the float32 graph again, kept beside the bf16 one
    assert builds == [("trunk", (2, 3, 64, 64)), ("trunk", (2, 3, 64, 64), "bf16")]
    assert all(p.dtype == torch.float32 for p in model.parameters())


def test_bf16_leaves_the_other_parts_in_float32(monkeypatch):
    model = _model(box_depth=True)
    frozen.set_precision(model, "bf16")
    builds = _builds(monkeypatch)
    with torch.no_grad():
        model.step(torch.rand(1, 3, 64, 64), None, anchors=torch.tensor([[40.0, 20.0, 50.0]]))
    assert sorted((b[0], b[-1] == "bf16") for b in builds) == [("slots", False), ("trunk", True)]


def test_an_unknown_precision_is_refused_on_one_line():
    model = _model()
    with pytest.raises(InputError, match="--precision must be one of fp32, bf16, got 'fp16'"):
        frozen.set_precision(model, "fp16")
    assert model.graph_precision == "fp32" and frozen.trunk_precision(model) == "fp32"


def test_the_trunk_runs_in_bf16_only_where_its_graph_runs(capsys):
    model = _model()
    frozen.use_precision(model, "bf16")
    assert frozen.trunk_precision(model) == "bf16"
    model.frozen_graphs = False  # the modules: float32 whatever was asked, and the records say so
    assert frozen.trunk_precision(model) == "fp32"
    frozen.use_precision(model, "bf16")
    assert "here the network runs in float32" in capsys.readouterr().err


def test_a_warmed_up_model_streams_without_building_a_graph(monkeypatch):
    """`warm_up` builds what a stream's first frames would, so a live stream's first frame does not wait on it
    (~0.8 s on 2 threads, the frames behind it dropped)."""
    model = _model(box_depth=True)
    builds = _builds(monkeypatch)
    warm_up(model)
    built = sorted(p for p, _ in builds)
    assert {"trunk", "slots"} <= set(built)
    rng = np.random.default_rng(1)
    frames = [rng.integers(0, 256, (48, 80, 3), np.uint8) for _ in range(3)]  # any size: warped to the model's view
    with torch.no_grad():
        assert len(list(Predictor(model).stream(frames))) == 3
    assert sorted(p for p, _ in builds) == built  # nothing more built
