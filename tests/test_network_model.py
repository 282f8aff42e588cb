"""Network shapes per variant, streaming vs windowed equivalence, ResNet-18 weight loading."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import torch

from layouts import VIEWS, InputError, LayoutSpec
from network.convlstm import StackedConvLSTM
from network.infer import Predictor, predict_layouts
from network.model import VARIANTS, ModelConfig, MVRackLay, build_discriminators
from network.resnet import ResNet18Encoder, load_imagenet_weights
from network.toy import ToySequence

SPEC = LayoutSpec(num_slots=2, size=16)


def tiny(variant: str = "mvracklay-disc-4") -> ModelConfig:
    return ModelConfig(
        variant=variant, input_width=64, input_height=64, spec=SPEC, encoder_width=8, hidden=16, decoder_width=8
    )


@pytest.mark.parametrize("variant", sorted(VARIANTS))
def test_shapes_for_every_variant(variant):
    torch.manual_seed(0)
    cfg = tiny(variant)
    model = MVRackLay(cfg)
    t = cfg.seq_len
    out = model(torch.rand(2, t, 3, 64, 64))
    assert set(out) == {"top", "front"}
    for v in out.values():
        assert v.shape == (2, t, 2, 3, 16, 16)
    step, state = model.step(torch.rand(2, 3, 64, 64))
    assert step["top"].shape == (2, 2, 3, 16, 16)
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
    cfg = tiny()
    assert ModelConfig.from_dict(cfg.to_dict()) == cfg
    with pytest.raises(InputError, match="expects images of 64x64"):
        MVRackLay(cfg).step(torch.rand(1, 3, 32, 64))


def test_fine_skip_feeds_the_quarter_map_and_old_records_load_without_it():
    torch.manual_seed(0)
    cfg = tiny()
    assert cfg.fine_skip
    model = MVRackLay(cfg).eval()
    x = torch.rand(1, 3, 64, 64)
    f2, f3, f4, f5 = model.encode(x)
    assert f2.shape[-2:] == (16, 16) and f5.shape[-2:] == (2, 2)
    base = model.decode((f2, f3, f4, f5))["front"]
    bumped = model.decode((f2 + 1.0, f3, f4, f5))["front"]
    assert not torch.allclose(base, bumped)  # the 1/4 map reaches the logits
    old = cfg.to_dict()
    del old["fine_skip"], old["temporal_residual"]
    coarse = ModelConfig.from_dict(old)
    assert not coarse.fine_skip and not coarse.temporal_residual
    assert isinstance(MVRackLay(coarse).temporal, StackedConvLSTM)  # shipped older weights keep their layout
    single = tiny("racklay").to_dict()
    del single["temporal_residual"]
    assert ModelConfig.from_dict(single) == tiny("racklay")  # an older single-frame run still resumes
    plain = MVRackLay(coarse).eval()
    assert plain.decoders["top"].t2 is None
    g2, g3, g4, g5 = plain.encode(x)
    assert torch.equal(plain.decode((g2 + 1.0, g3, g4, g5))["top"], plain.decode((g2, g3, g4, g5))["top"])
    with pytest.raises(InputError, match="fine_skip"):
        ModelConfig(fine_skip="yes")
    with pytest.raises(InputError, match="temporal_residual"):
        ModelConfig(temporal_residual=1)


@pytest.mark.parametrize("residual", [True, False])
def test_streaming_equals_convlstm_over_the_prefix(residual):
    torch.manual_seed(1)
    model = MVRackLay(replace(tiny(), temporal_residual=residual)).eval()
    if residual:  # the correction starts at zero; make the ConvLSTM path count
        torch.nn.init.normal_(model.temporal.out.weight, std=0.5)
    x = torch.rand(1, 6, 3, 64, 64)
    with torch.no_grad():
        full = model(x)
        state = None
        for t in range(6):
            out, state = model.step(x[:, t], state)
            for v in out:
                torch.testing.assert_close(out[v], full[v][:, t], rtol=1e-4, atol=1e-5)


def test_windowed_predictor_matches_the_window_forward():
    torch.manual_seed(2)
    model = MVRackLay(tiny()).eval()
    seq = ToySequence(SPEC, num_frames=6, image_size=(64, 64))
    frames = [seq.rgb(i) for i in range(6)]
    pred = Predictor(model)
    cached = list(pred.window(frames))
    naive = list(pred.window(frames, recompute=True))
    streamed = list(pred.stream(frames))
    x = torch.stack([pred.preprocess(f)[0] for f in frames])  # (6, 3, H, W)
    with torch.no_grad():
        for t in (0, 2, 5):
            ids = [max(0, t - 3 + k) for k in range(4)]
            ref = model(x[ids][None])
            for v in ("top", "front"):
                torch.testing.assert_close(cached[t][v], ref[v][0, -1], rtol=1e-4, atol=1e-5)
                torch.testing.assert_close(naive[t][v], ref[v][0, -1], rtol=1e-4, atol=1e-5)
        assert streamed[0]["top"].shape == cached[0]["top"].shape
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


def test_rescale_x_moves_content_to_its_metric_place():
    from network.infer import frame_layouts, rescale_x

    spec = LayoutSpec(num_slots=1, size=64)
    lay = np.zeros((1, 64, 64), np.uint8)
    c0, c1 = (int(round(float(spec.x_to_col(x)))) for x in (0.3, 0.6))
    lay[0, :, c0:c1] = 2  # a box from x = 0.3 to 0.6 m
    lay[0, :, :8] = 1  # shelf from x = -1.5 to -1.125 m
    logits = {
        v: torch.nn.functional.one_hot(torch.from_numpy(lay).long(), 3).permute(0, 3, 1, 2).float() for v in VIEWS
    }
    assert rescale_x(logits, 1.0) is logits
    for s in (0.9, 1.1):
        out = frame_layouts(rescale_x(logits, s))["front"][0]
        cols = np.flatnonzero(out[10] == 2)
        lo, hi = spec.col_to_x(cols[0]), spec.col_to_x(cols[-1] + 1)
        assert abs(lo - 0.3 * s) <= spec.x_extent / 64 and abs(hi - 0.6 * s) <= spec.x_extent / 64
        if s < 1:  # x < -1.5 * 0.9 lies beyond the predicted extent: background
            assert (out[:, :3] == 0).all() and (out[:, 4:6] == 1).all()
        else:  # the shelf spreads out to -1.24 m
            assert (out[:, :5] == 1).all() and (out[:, 7] == 0).all()
    with pytest.raises(ValueError):
        rescale_x(logits, 0.0)
