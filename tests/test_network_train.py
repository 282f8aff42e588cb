"""Training learns, checkpoints round-trip and resume, bad checkpoints are refused safely."""

from __future__ import annotations

import json
import math
import pickle

import pytest
import torch
from tiny_net import tiny_config

from layouts import InputError, LayoutSpec
from network.checkpoint import export_weights, init_weights_from, load_checkpoint, load_model, save_checkpoint
from network.inference.layout_eval import evaluate_sequences
from network.model.config import ModelConfig
from network.model.discriminator import build_discriminators
from network.model.net import MVRackLay
from network.training.toy import ToySequence
from network.training.train_config import TrainConfig, retired_options_off
from network.training.trainer import Trainer

SPEC = LayoutSpec(num_slots=2, size=16)


def tiny(variant: str = "mvracklay-disc-4") -> ModelConfig:
    return tiny_config(SPEC, variant)


def seqs(n: int = 2, frames: int = 6):
    return [ToySequence(SPEC, num_frames=frames, step_cols=2, seed=s, name=f"toy{s}") for s in range(n)]


def test_fitting_a_handful_of_frames_lowers_loss_and_raises_iou(tmp_path):
    data = seqs()
    tcfg = TrainConfig(
        frames_per_step=8, steps_per_epoch=20, epochs=3, lr=1e-2, dice_weight=0.0, augment=False, seed=0, threads=1
    )
    trainer = Trainer(tiny("mvracklay-4"), tcfg, data, data, tmp_path / "run", progress=False)
    before = evaluate_sequences(trainer.model.eval(), data, progress=False)
    trainer.fit()
    after = evaluate_sequences(trainer.model.eval(), data, progress=False)
    hist = [json.loads(s) for s in (tmp_path / "run" / "metrics.jsonl").read_text().splitlines()]
    assert len(hist) == 3 and hist[-1]["step"] == 60
    assert hist[-1]["loss"]["sup"] < 0.6 * hist[0]["loss"]["sup"]
    for view in ("top", "front"):
        assert after["visible"][view]["rack"]["miou"] > max(0.8, before["visible"][view]["rack"]["miou"] + 0.2)
    box = after["visible"]["front"]["box"]["miou"]
    assert not math.isnan(box) and box > before["visible"]["front"]["box"]["miou"] + 0.1
    assert (tmp_path / "run" / "best.pt").exists() and (tmp_path / "run" / "best.json").exists()


def test_checkpoint_round_trip_resume_and_export(tmp_path):
    data = seqs(1, 5)
    tcfg = TrainConfig(frames_per_step=4, steps_per_epoch=2, epochs=1, seed=1, threads=1)
    run = tmp_path / "run"
    Trainer(tiny(), tcfg, data, data, run, progress=False).fit()
    model, record = load_model(run / "last.pt")
    assert record["variant"] == "mvracklay-disc-4" and record["step"] == 2
    assert LayoutSpec.from_dict(record["spec"]) == SPEC
    assert json.loads((run / "last.json").read_text())["model_config"] == tiny().to_dict()
    payload, _ = load_checkpoint(run / "last.pt")
    fresh = MVRackLay(tiny())
    fresh.load_state_dict(payload["model"])
    fresh.eval()
    x = torch.rand(1, 4, 3, 64, 64)
    with torch.no_grad():
        torch.testing.assert_close(model(x)["top"], fresh(x)["top"])
    # Resume continues the step count with the optimiser state; a fresh run into the folder is refused.
    with pytest.raises(InputError, match="--resume"):
        Trainer(tiny(), tcfg, data, data, run, progress=False)
    tcfg2 = TrainConfig(frames_per_step=4, steps_per_epoch=2, epochs=2, seed=1, threads=1)
    t2 = Trainer(tiny(), tcfg2, data, data, run, resume=True, progress=False)
    assert t2.step == 2 and t2.opt.state_dict()["state"]
    t2.fit()
    assert load_checkpoint(run / "last.pt")[1]["step"] == 4
    with pytest.raises(InputError, match="different model config"):
        Trainer(tiny("mvracklay-4"), tcfg2, data, data, run, resume=True, progress=False)
    # fp16 export loads back into a float32 model.
    export_weights(run / "last.pt", tmp_path / "w.pt")
    p, rec = load_checkpoint(tmp_path / "w.pt")
    assert rec["dtype"] == "float16" and "optimizer" not in p
    assert p["model"]["encoder.conv1.weight"].dtype == torch.float16
    m16, _ = load_model(tmp_path / "w.pt")
    with torch.no_grad():
        agree = (m16(x)["top"].argmax(3) == model(x)["top"].argmax(3)).float().mean()
    assert agree > 0.9  # near-tied logits of an untrained model may flip


def test_same_seed_gives_the_same_weights(tmp_path):
    data = seqs(1, 5)
    states = []
    for k in range(2):
        tcfg = TrainConfig(frames_per_step=4, steps_per_epoch=2, epochs=1, seed=3, threads=1)
        Trainer(tiny(), tcfg, data, [], tmp_path / f"r{k}", progress=False).fit()
        states.append(load_checkpoint(tmp_path / f"r{k}" / "last.pt")[0]["model"])
    for key, v in states[0].items():
        assert torch.equal(v, states[1][key]), key


class _Evil:
    def __init__(self, path):
        self.path = path

    def __reduce__(self):
        return (open, (self.path, "w"))


def test_corrupt_or_pickled_checkpoints_are_refused(tmp_path):
    good = tmp_path / "good.pt"
    save_checkpoint(good, {"model": MVRackLay(tiny()).state_dict()}, {"model_config": tiny().to_dict()})
    data = good.read_bytes()
    trunc = tmp_path / "trunc.pt"
    trunc.write_bytes(data[: len(data) // 2])
    with pytest.raises(InputError, match=r"trunc\.pt: truncated or corrupted checkpoint"):
        load_model(trunc)
    sentinel = tmp_path / "pwned"
    evil = tmp_path / "evil.pt"
    torch.save({"model": {}, "record_json": "{}", "x": _Evil(str(sentinel))}, evil)
    with pytest.raises(InputError, match=r"evil\.pt: holds pickled Python objects"):
        load_model(evil)
    assert not sentinel.exists()
    raw = tmp_path / "raw.pt"
    raw.write_bytes(pickle.dumps(_Evil(str(sentinel))))
    with pytest.raises(InputError, match=r"raw\.pt"):
        load_model(raw)
    assert not sentinel.exists()
    other = tmp_path / "other.pt"
    torch.save({"weights": torch.zeros(2)}, other)
    with pytest.raises(InputError, match="not an MVRackLay checkpoint"):
        load_model(other)
    with pytest.raises(InputError, match="not found"):
        load_model(tmp_path / "missing.pt")


def test_warm_start_from_racklay_reproduces_it_then_trains_the_convlstm(tmp_path):
    data = seqs(1, 5)
    tcfg = TrainConfig(frames_per_step=4, steps_per_epoch=2, epochs=1, seed=3, threads=1)
    Trainer(tiny("racklay"), tcfg, data, data, tmp_path / "single", progress=False).fit()
    src = tmp_path / "single" / "last.pt"
    single, _ = load_model(src)
    # A fresh residual sequence model warm-started from it predicts what the single-frame model does.
    model = MVRackLay(tiny())
    discs = build_discriminators(tiny())
    info = init_weights_from(model, src, discs)
    assert info["variant"] == "racklay" and info["step"] == 2 and info["discriminators"]
    assert info["fresh_prefixes"] == ["memory.lstm", "memory.out"]
    x = torch.rand(1, 4, 3, 64, 64)
    anchors = torch.tensor([52.0, 30.0]).expand(1, 4, 2)
    with torch.no_grad():
        seq_out = model.eval()(x, anchors)
        one = single(x.flatten(0, 1)[:, None], anchors.reshape(4, 1, 2))
    for v in ("top", "front", "rows"):
        torch.testing.assert_close(seq_out[v][0], one[v][:, 0])
    # Through the trainer: the source is in the record, and training moves the ConvLSTM's correction.
    t2 = TrainConfig(frames_per_step=4, steps_per_epoch=2, epochs=1, seed=3, threads=1, init_from=str(src))
    Trainer(tiny(), t2, data, data, tmp_path / "seq", progress=False).fit()
    record = json.loads((tmp_path / "seq" / "last.json").read_text())
    assert record["init_from"]["path"] == str(src) and record["init_from"]["variant"] == "racklay"
    trained, _ = load_model(tmp_path / "seq" / "last.pt")
    assert trained.memory.out.weight.abs().sum() > 0
    # Different sizes are refused with the setting named.
    other = MVRackLay(
        ModelConfig(input_width=64, input_height=64, spec=SPEC, encoder_width=8, hidden=32, decoder_width=8)
    )
    with pytest.raises(InputError, match="hidden"):
        init_weights_from(other, src)
    # A fp16 copy with its discriminators is a warm start as good as the full checkpoint.
    export_weights(src, tmp_path / "w.pt")
    assert not init_weights_from(MVRackLay(tiny()), tmp_path / "w.pt", build_discriminators(tiny()))["discriminators"]
    export_weights(src, tmp_path / "wd.pt", discriminators=True)
    discs16 = build_discriminators(tiny())
    assert init_weights_from(MVRackLay(tiny()), tmp_path / "wd.pt", discs16)["discriminators"]
    for key, v in discs.state_dict().items():
        torch.testing.assert_close(discs16.state_dict()[key], v, rtol=2e-3, atol=1e-3)
    with pytest.raises(InputError, match="no discriminators"):
        export_weights(tmp_path / "w.pt", tmp_path / "bad.pt", discriminators=True)


def test_stop_at_pauses_inside_the_schedule_and_resume_continues(tmp_path):
    data = seqs(1, 5)
    run = tmp_path / "run"
    # pause after the first step, inside the first epoch; the schedule spans 100 epochs x 3 steps
    tcfg = TrainConfig(frames_per_step=4, steps_per_epoch=3, epochs=100, stop_step=1, seed=1, threads=1)
    t1 = Trainer(tiny("mvracklay-4"), tcfg, data, data, run, progress=False)
    t1.fit()
    assert t1.step == 1 and t1._progress() < 0.01  # paused early, far from the schedule's end
    assert t1.opt.param_groups[0]["lr"] > 0.99 * tcfg.lr
    t2 = Trainer(
        tiny("mvracklay-4"),
        TrainConfig(**{**tcfg.__dict__, "stop_step": 0, "epochs": 2}),
        data,
        data,
        run,
        resume=True,
        progress=False,
    )
    assert (t2.step, t2.epoch, t2.epoch_step) == (1, 0, 1)  # at the same place inside the epoch
    t2.fit()
    assert t2.step == 6 and load_checkpoint(run / "last.pt")[1]["step"] == 6
    with pytest.raises(InputError, match="--stop-at"):
        TrainConfig(stop_step=-1).validate()
    # a record of an earlier version with a pause point in minutes still reads
    assert "stop_minutes" not in retired_options_off({"stop_minutes": 80.0}, "x")


def test_native_bf16_is_read_from_the_cpu_flags(tmp_path):
    from network.precision import cpu_has_native_bf16

    info = tmp_path / "cpuinfo"
    info.write_text("processor\t: 0\nflags\t\t: fpu sse2 avx2 fma\n\nprocessor\t: 1\nflags\t\t: fpu sse2 avx2 fma\n")
    assert cpu_has_native_bf16(info) is False
    info.write_text("processor\t: 0\nflags\t\t: fpu avx2 avx512f avx512_bf16\n")
    assert cpu_has_native_bf16(info) is True
    info.write_text("processor\t: 0\nflags\t\t: fpu avx2 amx_tile amx_bf16\n")
    assert cpu_has_native_bf16(info) is True
    info.write_text("no flags here\n")
    assert cpu_has_native_bf16(info) is None
    assert cpu_has_native_bf16(tmp_path / "missing") is None
