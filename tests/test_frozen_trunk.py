"""The trunk's frozen graph (`network.frozen`): the same maps as the modules, never stale, only where it applies."""

from __future__ import annotations

import torch
from tiny_net import tiny_config

from layouts.spec import LayoutSpec
from network import frozen
from network.model import MVRackLay


def _model(seed: int = 0) -> MVRackLay:
    torch.manual_seed(seed)
    model = MVRackLay(tiny_config(LayoutSpec(size=16)))
    for m in model.modules():  # batch norms with statistics of their own, so folding them is not a no-op
        if isinstance(m, torch.nn.BatchNorm2d):
            m.running_mean.uniform_(-0.5, 0.5)
            m.running_var.uniform_(0.5, 2.0)
    return model.eval()


def _close(a: tuple[torch.Tensor, ...], b: tuple[torch.Tensor, ...]) -> None:
    for p, q in zip(a, b, strict=True):
        torch.testing.assert_close(p, q, rtol=1e-4, atol=1e-5)


def _builds(monkeypatch) -> list[tuple[int, ...]]:
    shapes: list[tuple[int, ...]] = []
    build = frozen._build

    def counted(model, x):
        shapes.append(tuple(x.shape))
        return build(model, x)

    monkeypatch.setattr(frozen, "_build", counted)
    return shapes


def test_the_graph_gives_the_modules_maps_once_built_per_shape(monkeypatch):
    model = _model()
    builds = _builds(monkeypatch)
    x1, x4 = torch.rand(1, 3, 64, 64), torch.rand(4, 3, 64, 64)
    with torch.no_grad():
        want1, want4 = frozen.trunk_maps(model, x1), frozen.trunk_maps(model, x4)
        for _ in range(2):  # a stream and a window alternating: one graph each, built once
            _close(model.maps(x1), want1)
            _close(model.maps(x4), want4)
    assert builds == [(1, 3, 64, 64), (4, 3, 64, 64)]
    assert all(held[2] is not None for held in frozen._GRAPHS[model].values())  # graphs, not the fallback


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


def test_the_modules_run_where_the_graph_does_not_apply(monkeypatch):
    model = _model()
    builds = _builds(monkeypatch)
    x = torch.rand(2, 3, 64, 64)
    with torch.no_grad():
        want = frozen.trunk_maps(model, x)
        model.frozen_trunk = False
        off = model.maps(x)
        model.frozen_trunk = True
        with torch.autocast("cpu", dtype=torch.bfloat16):
            model.maps(x)
    for p, q in zip(off, want, strict=True):
        assert torch.equal(p, q)
    assert model.maps(x)[0].requires_grad  # gradients on
    model.train()
    with torch.no_grad():
        model.maps(x)  # training mode: batch statistics
    assert builds == []
