"""Fine-tuning with ``--keep-features W``: the start network's pyramid maps (what fitted depth heads read) are kept
on the training frames; without the term the maps move freely."""

from __future__ import annotations

import pytest
import torch
from tiny_net import tiny_config

from layouts import InputError, LayoutSpec
from network.checkpoint import init_weights_from, save_checkpoint
from network.model.net import MVRackLay
from network.training.toy import ToySequence
from network.training.train_config import TrainConfig
from network.training.trainer import Trainer

SPEC = LayoutSpec(num_slots=2, size=16)


def _start(tmp_path):
    """A start network, saved as a checkpoint to fine-tune from."""
    cfg = tiny_config(SPEC, "mvracklay-disc-4")
    torch.manual_seed(1)
    path = tmp_path / "start.pt"
    record = {"model_config": cfg.to_dict(), "variant": cfg.variant, "step": 0}
    save_checkpoint(path, {"model": MVRackLay(cfg).state_dict()}, record)
    return cfg, path


def _maps_moved(tmp_path, cfg, start, weight: float) -> float:
    data = [ToySequence(SPEC, num_frames=6, step_cols=2, seed=s, name=f"toy{s}") for s in range(2)]
    tcfg = TrainConfig(frames_per_step=8, steps_per_epoch=6, epochs=1, lr=1e-2, adv_weight=0.0, augment=False,
                       seed=0, threads=1, init_from=str(start), keep_features=weight, frozen_bn=True)  # fmt: skip
    trainer = Trainer(cfg, tcfg, data, data, tmp_path / f"run{weight}", progress=False)
    trainer.fit()
    assert (trainer.keeper is not None) == (weight > 0)
    frames = torch.stack([torch.as_tensor(data[0].rgb(i)) for i in range(4)]).permute(0, 3, 1, 2).float() / 255
    teacher = MVRackLay(cfg)
    init_weights_from(teacher, str(start))
    with torch.no_grad():
        got = trainer.model.eval().maps(frames)
        want = teacher.eval().maps(frames)
    return sum(float(((a - b) ** 2).mean() / b.var()) for a, b in zip(got, want))


def test_the_kept_maps_stay_nearer_the_start_networks(tmp_path):
    cfg, start = _start(tmp_path)
    free, kept = _maps_moved(tmp_path, cfg, start, 0.0), _maps_moved(tmp_path, cfg, start, 10.0)
    assert kept < 0.5 * free, (kept, free)


def test_the_term_starts_at_zero_and_compares_each_frame_with_itself(tmp_path):
    """Before any step the trained network is the start network: the term is zero on a window of different
    frames (frame order as the model's forward pass takes them)."""
    cfg, start = _start(tmp_path)
    data = [ToySequence(SPEC, num_frames=6, step_cols=2, seed=s, name=f"toy{s}") for s in range(2)]
    tcfg = TrainConfig(frames_per_step=8, steps_per_epoch=1, epochs=1, adv_weight=0.0, augment=False, threads=1,
                       init_from=str(start), keep_features=1.0, frozen_bn=True)  # fmt: skip
    trainer = Trainer(cfg, tcfg, data, data, tmp_path / "run", progress=False)
    windows = torch.stack([torch.as_tensor(d.rgb(i)) for d in data for i in range(4)]).permute(0, 3, 1, 2)
    windows = windows.float().div(255).reshape(2, 4, 3, *windows.shape[-2:])
    trainer.model.eval()  # batch norm as --frozen-bn runs it; gradients on, as in training (the eager path)
    trainer.model(windows)
    assert float(trainer.keeper.loss(windows).detach()) < 1e-8


def test_keeping_features_needs_the_network_to_keep():
    with pytest.raises(InputError, match="--keep-features needs --init-from"):
        TrainConfig(keep_features=1.0).validate()
    with pytest.raises(InputError, match="--keep-features must be a finite number >= 0"):
        TrainConfig(keep_features=-1.0, init_from="x.pt").validate()
