"""Network shapes per variant, streaming vs windowed equivalence, ResNet-18 weight loading."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from tiny_net import cached_and_naive_windows, tiny_config

from layouts import VIEWS, InputError, LayoutSpec
from network.inference.predictor import predict_layouts
from network.model.config import VARIANTS, ModelConfig
from network.model.decoders import anchors_from_rows
from network.model.discriminator import build_discriminators
from network.model.net import MVRackLay
from network.model.resnet import ResNet18Encoder, load_imagenet_weights

SPEC = LayoutSpec(num_slots=2, size=16)


def tiny(variant: str = "mvracklay-disc-4") -> ModelConfig:
    return tiny_config(SPEC, variant)


ANCHORS = torch.tensor([52.0, 30.0])  # canonical rows of the two slots' boards (64-row input)


@pytest.mark.parametrize("variant", sorted(VARIANTS))
def test_shapes_for_every_variant(variant):
    torch.manual_seed(0)
    cfg = tiny(variant)
    model = MVRackLay(cfg)
    t = cfg.seq_len
    out = model(torch.rand(2, t, 3, 64, 64), ANCHORS.expand(2, t, 2))
    assert set(out) == {"top", "front", "rows", "anchors"}
    for v in VIEWS:
        assert out[v].shape == (2, t, 2, 3, 16, 16)
    assert out["rows"].shape == (2, t, 64)
    step, state = model.step(torch.rand(2, 3, 64, 64))
    assert step["top"].shape == (2, 2, 3, 16, 16) and step["anchors"].shape == (2, 2)
    assert (state is None) == (not cfg.use_lstm)
    discs = build_discriminators(cfg)
    assert (discs is None) == (not VARIANTS[variant][2])
    if discs is not None:
        d = discs["top"](out["top"].flatten(0, 1).softmax(2))
        assert d.shape[0] == 2 * t and d.shape[1] == 1


def test_variant_sequence_lengths_and_bad_config():
    assert tiny("mvracklay-disc-8").seq_len == 8
    assert tiny("racklay").seq_len == 1 and not tiny("racklay").use_lstm
    assert not tiny("mvracklay-4").use_disc
    with pytest.raises(InputError, match="unknown variant"):
        ModelConfig(variant="bogus")
    with pytest.raises(InputError, match="multiple of 32"):
        ModelConfig(input_width=100)
    with pytest.raises(InputError, match="memory_hidden"):
        ModelConfig(memory_hidden=0)
    with pytest.raises(InputError, match="multiple of 4"):
        ModelConfig(spec=LayoutSpec(size=18))
    cfg = tiny()
    assert ModelConfig.from_dict(cfg.to_dict()) == cfg
    old = cfg.to_dict()
    del old["arch"]  # a record of the earlier column-transform decoder
    with pytest.raises(InputError, match="earlier decoder design"):
        ModelConfig.from_dict(old, "old.json")
    encoder_lstm = {**cfg.to_dict(), "temporal_residual": True}  # the ConvLSTM on the 1/32 map: refused
    with pytest.raises(InputError, match="earlier ConvLSTM on the 1/32 encoder map"):
        ModelConfig.from_dict(encoder_lstm, "old.json")
    single = {**tiny("racklay").to_dict(), "temporal_residual": False}  # single-frame records still load
    assert ModelConfig.from_dict(single) == tiny("racklay")
    with pytest.raises(InputError, match="expects images of 64x64"):
        MVRackLay(cfg).step(torch.rand(1, 3, 32, 64))
    with pytest.raises(InputError, match="anchors must have shape"):
        MVRackLay(cfg)(torch.rand(1, 4, 3, 64, 64), torch.zeros(1, 4, 3))


def test_slot_heads_sample_the_rows_above_each_board():
    """Front-window rows are heights above the anchor: row k samples canonical row anchor - h_k / px."""
    cfg = tiny()
    heads = MVRackLay(cfg).slots
    view, spec = cfg.view, cfg.spec
    ramp = torch.arange(64, dtype=torch.float32).add(0.5).view(1, 1, 64, 1).expand(1, 1, 64, 64)  # value = row centre
    got = heads._sample(ramp, ANCHORS[None], heads.front_fine, 16)  # (R, 1, D, D)
    for r, a in enumerate(ANCHORS.tolist()):
        h = (16 - np.arange(16) - 0.5) / 16 * spec.h_extent  # height of each front row, top row first
        want = a - h / view.metres_per_pixel
        torch.testing.assert_close(got[r, 0, :, 5], torch.tensor(want, dtype=torch.float32), atol=1e-4, rtol=0)
    band = heads._sample(ramp, ANCHORS[None], heads.band, 8)[0, 0, :, 0]
    assert band[0] < ANCHORS[0] - spec.h_extent / view.metres_per_pixel < ANCHORS[0] < band[-1]


def test_slots_without_an_anchor_are_background_and_anchors_move_the_front_view():
    torch.manual_seed(4)
    model = MVRackLay(tiny("racklay")).eval()
    x = torch.rand(1, 1, 3, 64, 64)
    with torch.no_grad():
        out = model(x, torch.tensor([[[52.0, float("nan")]]]))
        assert (out["front"][0, 0, 1].argmax(0) == 0).all() and (out["top"][0, 0, 1].argmax(0) == 0).all()
        assert not torch.equal(out["front"][0, 0, 0], out["front"][0, 0, 1])
        moved = model(x, torch.tensor([[[40.0, float("nan")]]]))
        assert not torch.allclose(out["front"][0, 0, 0], moved["front"][0, 0, 0])


def test_anchors_from_rows_decodes_the_lowest_boards_first():
    view = tiny().view  # 64 rows of 3/64 m: boards closer than 0.35 m (7.5 rows) are one board
    logits = torch.full((3, 64), -6.0)
    logits[0, [20, 45, 58]] = 4.0
    logits[0, 59] = 4.0  # the same board spread over two rows -> one anchor between them
    logits[1, [20, 24]] = torch.tensor([5.0, 3.0])  # too close: the stronger wins
    logits[2, 30] = -0.5  # below the threshold: no board
    a = anchors_from_rows(logits, view, 2)
    assert a.shape == (3, 2)
    assert abs(float(a[0, 0]) - 59.0) < 0.01 and abs(float(a[0, 1]) - 45.5) < 0.2  # lowest first; R = 2 kept
    assert abs(float(a[1, 0]) - 20.5) < 0.3 and torch.isnan(a[1, 1])
    assert torch.isnan(a[2]).all()


def test_streaming_equals_the_slot_memory_over_the_prefix():
    torch.manual_seed(1)
    model = MVRackLay(tiny()).eval()
    torch.nn.init.normal_(model.memory.out.weight, std=0.5)  # the correction starts at zero; make it count
    x = torch.rand(1, 6, 3, 64, 64)
    with torch.no_grad():
        full = model(x, ANCHORS.expand(1, 6, 2))
        state = None
        for t in range(6):
            out, state = model.step(x[:, t], state, ANCHORS[None])
            for v in ("top", "front", "rows"):
                torch.testing.assert_close(out[v], full[v][:, t], rtol=1e-4, atol=1e-5)
        # the memory carries something: frame 5 alone differs from frame 5 after the prefix
        alone, _ = model.step(x[:, 5], None, ANCHORS[None])
        assert not torch.allclose(alone["top"], full["top"][:, 5], atol=1e-3)


def test_a_fresh_memory_leaves_the_single_frame_outputs_unchanged():
    torch.manual_seed(5)
    seq = MVRackLay(tiny()).eval()
    single = MVRackLay(tiny("racklay")).eval()
    missing, unexpected = seq.load_state_dict(single.state_dict(), strict=False)
    assert all(k.startswith("memory.") for k in missing) and not unexpected
    x = torch.rand(1, 4, 3, 64, 64)
    with torch.no_grad():
        a = seq(x, ANCHORS.expand(1, 4, 2))
        b = single(x.transpose(0, 1), ANCHORS.expand(4, 1, 2))
    for v in ("top", "front"):
        torch.testing.assert_close(a[v][0], b[v][:, 0])


def test_windowed_predictor_matches_the_window_forward():
    torch.manual_seed(2)
    model = MVRackLay(tiny()).eval()
    pred, frames, cached, naive = cached_and_naive_windows(model, SPEC)
    streamed = list(pred.stream(frames))
    x = torch.stack([pred.preprocess(f, i)[0] for i, f in enumerate(frames)])  # (6, 3, H, W)
    with torch.no_grad():
        for t in (0, 2, 5):
            ids = [max(0, t - 3 + k) for k in range(4)]
            ref = model(x[ids][None])
            for v in ("top", "front", "rows"):
                torch.testing.assert_close(getattr(cached[t], v), ref[v][0, -1], rtol=1e-4, atol=1e-5)
                torch.testing.assert_close(getattr(naive[t], v), ref[v][0, -1], rtol=1e-4, atol=1e-5)
        assert streamed[0].top.shape == cached[0].top.shape
        assert torch.isfinite(cached[5].anchors).any()
    lay = list(predict_layouts(model, [f[:40] for f in frames], "window", size=32))
    assert len(lay) == 6 and lay[0]["front"].shape == (2, 32, 32) and lay[0]["top"].dtype == np.uint8
    assert lay[5]["top"].max() <= 2


def test_resnet_has_torchvision_names_and_loads_a_state_dict(tmp_path):
    enc = ResNet18Encoder(64)
    keys = set(enc.state_dict())
    for k in (
        "conv1.weight",
        "bn1.running_mean",
        "layer1.0.conv1.weight",
        "layer1.0.bn1.weight",
        "layer2.0.downsample.0.weight",
        "layer2.0.downsample.1.running_var",
        "layer4.1.bn2.bias",
    ):
        assert k in keys
    assert sum(v.numel() for k, v in enc.state_dict().items() if k.endswith("weight") or k.endswith("bias")) == 11176512
    torch.manual_seed(3)
    src = ResNet18Encoder(64)
    state = dict(src.state_dict())
    state["fc.weight"] = torch.zeros(1000, 512)
    state["fc.bias"] = torch.zeros(1000)
    path = tmp_path / "resnet18.pth"
    torch.save(state, path)
    load_imagenet_weights(enc, path)
    torch.testing.assert_close(enc.layer3[1].conv2.weight, src.layer3[1].conv2.weight)

    missing = {k: v for k, v in state.items() if k != "layer1.0.conv1.weight"}
    torch.save(missing, tmp_path / "missing.pth")
    with pytest.raises(InputError, match=r"missing\.pth.*1 missing keys"):
        load_imagenet_weights(enc, tmp_path / "missing.pth")
    torch.save({**state, "layer5.weight": torch.zeros(1)}, tmp_path / "extra.pth")
    with pytest.raises(InputError, match="1 unexpected keys"):
        load_imagenet_weights(enc, tmp_path / "extra.pth")
    with pytest.raises(InputError, match="width 64"):
        load_imagenet_weights(ResNet18Encoder(32), path)
    with pytest.raises(InputError, match="not found"):
        load_imagenet_weights(enc, tmp_path / "nope.pth")
