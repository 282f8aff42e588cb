"""Fine-tuning with ``--frozen-bn``: a training step leaves the batch-norm layers' running statistics as the
warm-start weights had them (their affine weights still learn); without it they move to the new data's."""

from __future__ import annotations

import torch
from torch import nn

from mvracklay.training.train_network import TrainSettings, _train_config
from network.training.trainer import keep_batch_norm_statistics


def _net() -> nn.Module:
    torch.manual_seed(0)
    return nn.Sequential(nn.Conv2d(3, 4, 3), nn.BatchNorm2d(4), nn.ReLU(), nn.Conv2d(4, 2, 1), nn.BatchNorm2d(2))


def _step(net: nn.Module, frozen: bool) -> None:
    net.train()
    if frozen:
        keep_batch_norm_statistics(net)
    opt = torch.optim.SGD(net.parameters(), lr=0.1)
    loss = net(torch.rand(4, 3, 8, 8) * 5 + 2).pow(2).mean()  # a look far from the statistics' (mean 0, var 1)
    loss.backward()
    opt.step()


def test_a_step_with_frozen_batch_norm_keeps_its_statistics_and_learns_its_weights():
    kept, moved = _net(), _net()
    before = {k: v.clone() for k, v in kept.state_dict().items()}
    _step(kept, frozen=True)
    _step(moved, frozen=False)
    stats = [k for k in before if "running_" in k]
    assert stats and all(torch.equal(kept.state_dict()[k], before[k]) for k in stats)
    assert not all(torch.equal(moved.state_dict()[k], before[k]) for k in stats)
    assert not torch.equal(kept.state_dict()["1.weight"], before["1.weight"])  # the affine weights learn
    assert kept[0].training and not kept[1].training  # only the batch-norm layers are in eval mode


def test_the_option_reaches_the_train_config():
    assert TrainSettings.__dataclass_fields__["frozen_bn"].default is False
    assert _train_config(TrainSettings(frozen_bn=True), adv=0.0).frozen_bn
    assert not _train_config(TrainSettings(), adv=0.0).frozen_bn
