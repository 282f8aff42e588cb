"""bf16 training (`--precision bf16`) and single-frame records written before the memory was aligned."""

from __future__ import annotations

import json

import pytest
import torch
from test_network_train import seqs, tiny

from layouts import InputError
from network.checkpoint import load_checkpoint
from network.model.config import ModelConfig
from network.training.train_config import TrainConfig
from network.training.trainer import Trainer


def test_bf16_runs_the_forward_in_bf16_learns_and_keeps_fp32_weights(tmp_path):
    data = seqs()
    tcfg = TrainConfig(
        frames_per_step=4, steps_per_epoch=12, epochs=2, lr=2e-2, dice_weight=0.0, augment=False, threads=1,
        precision="bf16",
    )  # fmt: skip
    trainer = Trainer(tiny("mvracklay-disc-4"), tcfg, data, data, tmp_path / "run", progress=False)
    conv = next(m for m in trainer.model.modules() if isinstance(m, torch.nn.Conv2d))
    dtypes: set[torch.dtype] = set()
    conv.register_forward_hook(lambda _m, _i, out: dtypes.add(out.dtype))
    trainer.fit()
    assert torch.bfloat16 in dtypes  # training steps ran under autocast
    assert torch.float32 in dtypes  # validation did not
    hist = [json.loads(s) for s in (tmp_path / "run" / "metrics.jsonl").read_text().splitlines()]
    assert all(torch.isfinite(torch.tensor(list(e["loss"].values()))).all() for e in hist)
    assert hist[-1]["loss"]["sup"] < 0.8 * hist[0]["loss"]["sup"]
    payload, record = load_checkpoint(tmp_path / "run" / "last.pt")
    assert record["train_config"]["precision"] == "bf16"
    assert all(v.dtype == torch.float32 for v in payload["model"].values() if v.is_floating_point())


def test_unknown_precision_is_refused_naming_the_flag():
    with pytest.raises(InputError, match="--precision must be one of fp32, bf16"):
        TrainConfig(precision="fp16").validate()


def test_single_frame_record_from_before_the_aligned_memory_matches_the_current_config():
    d = tiny("racklay").to_dict()
    del d["align_memory"]  # such records read as align_memory=False
    assert ModelConfig.from_dict(d) == tiny("racklay")  # so `--resume` of an older racklay run works
    d = tiny("mvracklay-4").to_dict()
    del d["align_memory"]
    assert ModelConfig.from_dict(d) != tiny("mvracklay-4")  # a sequence model's memory did differ
