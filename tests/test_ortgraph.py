"""The ONNX Runtime graphs (`network.model.ortgraph`, the ``onnx`` runtime of `network.model.frozen`): the torch
runtime's outputs within float rounding, the runtime chosen as asked, and torch's graphs or modules wherever
ONNX Runtime is absent or a part does not export."""

from __future__ import annotations

import pytest
import torch
from tiny_net import tiny_config

from layouts.errors import InputError
from layouts.spec import LayoutSpec
from network.heads.boxdepth import head_inputs
from network.model import frozen, ortgraph
from network.model.net import MVRackLay

needs_ort = pytest.mark.skipif(not ortgraph.available(), reason="onnxruntime is not installed")
ANCHORS = torch.tensor([[40.0, 20.0, float("nan")]])  # slot 2 has none: its logits are the background


def _model(seed: int = 0) -> MVRackLay:
    torch.manual_seed(seed)
    model = MVRackLay(tiny_config(LayoutSpec(size=16), box_depth=True))
    for m in model.modules():  # batch norms with statistics of their own, and a memory that is not a no-op
        if isinstance(m, (torch.nn.BatchNorm1d, torch.nn.BatchNorm2d)):
            m.running_mean.uniform_(-0.5, 0.5)
            m.running_var.uniform_(0.5, 2.0)
    torch.nn.init.normal_(model.memory.out.weight, std=0.3)
    return model.eval()


def _stream(model: MVRackLay, runtime: str, frames: list[torch.Tensor]) -> list[tuple[torch.Tensor, ...]]:
    """Each frame's logits (both views), box windows and box-depth logits, streamed in ``runtime``."""
    frozen.set_runtime(model, runtime)
    outs, state = [], None
    with torch.no_grad():
        for i, x in enumerate(frames):  # the camera's step given on some frames, read from the images on others
            step = torch.tensor([0.05 * i]) if i % 2 else None
            out, state = model.step(x, state, anchors=ANCHORS, motion=step)
            inputs = head_inputs(out["box_window"][0], out["top"][0], out["front"][0], ANCHORS[0], model.cfg.view, 2.5)
            outs.append((out["top"], out["front"], out["box_window"], model.box_logits(*inputs)))
    return outs


def _frames(n: int = 3) -> list[torch.Tensor]:
    torch.manual_seed(1)
    return [torch.rand(1, 3, 64, 64) for _ in range(n)]


@needs_ort
def test_a_stream_in_onnx_runtime_gives_the_torch_runtimes_outputs():
    model, frames = _model(), _frames()
    want = _stream(model, "torch", frames)
    got = _stream(model, "onnx", frames)
    for g, w in zip(got, want, strict=True):
        for p, q in zip(g, w, strict=True):
            torch.testing.assert_close(p, q, rtol=1e-4, atol=1e-4)
        for p, q in zip(g[:2], w[:2], strict=True):  # the layouts: the same class wherever the margin is not rounding
            top2 = q.topk(2, dim=2).values
            clear = (top2[:, :, 0] - top2[:, :, 1]) > 1e-3
            assert torch.equal(p.argmax(2)[clear], q.argmax(2)[clear])
    assert not torch.equal(got[-1][0], got[0][0])  # the memory carried something from frame to frame
    held = frozen._GRAPHS[model]
    sessions = sorted(k[0] for k, h in held.items() if isinstance(h[2], ortgraph.OrtGraph))
    # every part in ONNX Runtime: the trunk, the row heads, the slot maps, the box-depth head and the memory step
    # (fresh and carried)
    assert sessions == ["box_depth", "decode", "decode", "rows", "slots", "trunk"]


def test_the_torch_runtime_keeps_the_modules_arithmetic_for_the_memory_step():
    model, frames = _model(), _frames(3)
    got = _stream(model, "torch", frames)
    model.frozen_graphs = False
    want = _stream(model, "torch", frames)
    model.frozen_graphs = True
    assert not any(k[0] == "decode" for k in frozen._GRAPHS.get(model, {}))
    for g, w in zip(got, want, strict=True):
        torch.testing.assert_close(g, w, rtol=1e-4, atol=1e-5)


def test_without_onnx_runtime_auto_and_onnx_run_torchs_graphs(monkeypatch, capsys):
    monkeypatch.setattr(ortgraph, "available", lambda: False)
    model, frames = _model(), _frames(2)
    want = _stream(model, "torch", frames)
    frozen.use_runtime(model, "onnx")
    assert "onnxruntime (or onnx) is not installed" in capsys.readouterr().err
    for runtime in ("auto", "onnx"):
        assert frozen.graph_runtime(model) == "torch"
        for g, w in zip(_stream(model, runtime, frames), want, strict=True):
            for p, q in zip(g, w, strict=True):
                assert torch.equal(p, q)  # the same graphs
    assert not any(isinstance(h[2], ortgraph.OrtGraph) for h in frozen._GRAPHS[model].values())


@needs_ort
def test_a_part_that_does_not_export_runs_in_torch_with_a_warning(monkeypatch):
    def refuse(self, *args, **kwargs):
        raise RuntimeError("no exporter here")

    monkeypatch.setattr(ortgraph.OrtGraph, "__init__", refuse)
    model, frames = _model(), _frames(2)
    want = _stream(model, "torch", frames)
    with pytest.warns(UserWarning, match="could not run in ONNX Runtime"):
        got = _stream(model, "onnx", frames)
    for g, w in zip(got, want, strict=True):
        torch.testing.assert_close(g, w, rtol=1e-4, atol=1e-5)


def test_the_runtime_is_named_by_the_environment_and_checked_on_one_line(monkeypatch):
    monkeypatch.delenv(ortgraph.ENV, raising=False)
    assert ortgraph.default_runtime() == "auto"
    monkeypatch.setenv(ortgraph.ENV, " Torch ")
    assert ortgraph.default_runtime() == "torch"
    monkeypatch.setenv(ortgraph.ENV, "tensorrt")
    with pytest.raises(InputError, match="MVRACKLAY_RUNTIME must be one of auto, torch, onnx, got 'tensorrt'"):
        ortgraph.default_runtime()
    model = _model()
    with pytest.raises(InputError, match="must be one of auto, torch, onnx"):
        frozen.set_runtime(model, "tvm")
    assert model.graph_runtime == "torch"  # a model built in code runs torch's graphs
    frozen.set_runtime(model, "auto")
    assert frozen.graph_runtime(model) == ("onnx" if ortgraph.available() else "torch")
    frozen.set_precision(model, "bf16")
    assert frozen.graph_runtime(model, "trunk") == "torch"  # a bf16 trunk stays in torch's graph


def test_commands_load_models_in_the_runtime_the_environment_names(monkeypatch):
    from mvracklay.models import default_checkpoint
    from network.inference.loading import load_for_inference

    if not default_checkpoint().is_file():
        pytest.skip("no shipped model in this copy")
    monkeypatch.delenv(ortgraph.ENV, raising=False)  # the suite sets torch (conftest); a user's default is auto
    model, _ = load_for_inference(default_checkpoint(), "predict", "cpu")
    assert model.graph_runtime == "auto"
    monkeypatch.setenv(ortgraph.ENV, "torch")
    model, _ = load_for_inference(default_checkpoint(), "predict", "cpu")
    assert model.graph_runtime == "torch" and frozen.graph_runtime(model) == "torch"


@needs_ort
def test_an_export_is_cached_by_a_digest_of_what_it_depends_on_and_reloaded(monkeypatch, tmp_path):
    monkeypatch.setenv(ortgraph.CACHE_ENV, str(tmp_path))
    frames = _frames(2)
    model = _model()
    want = _stream(model, "onnx", frames)
    files = sorted(tmp_path.glob("*.onnx"))
    assert len(files) == 6  # trunk, rows, slots, box-depth head, memory step fresh and carried
    exports = []
    monkeypatch.setattr(ortgraph, "export", lambda *a: exports.append(1) or pytest.fail("exported again"))
    again = _model()  # another model object, the same weights: every part from the cache
    got = _stream(again, "onnx", frames)
    assert all(h[2].cached for h in frozen._GRAPHS[again].values() if isinstance(h[2], ortgraph.OrtGraph))
    for g, w in zip(got, want, strict=True):
        for p, q in zip(g, w, strict=True):
            assert torch.equal(p, q)
    monkeypatch.undo()
    monkeypatch.setenv(ortgraph.CACHE_ENV, str(tmp_path))
    files[0].write_bytes(b"not onnx")  # a damaged file is exported again and replaced
    other = _model(seed=3)  # other weights: other digests, new files beside the old
    _stream(other, "onnx", frames)
    _stream(_model(), "onnx", frames)
    assert len(list(tmp_path.glob("*.onnx"))) == 12 and files[0].read_bytes() != b"not onnx"
    assert not list(tmp_path.glob(".*.tmp"))  # atomic writes leave no temporaries
    monkeypatch.setenv(ortgraph.CACHE_ENV, "off")
    assert ortgraph.cache_dir() is None
