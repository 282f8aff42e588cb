"""The patch discriminators of the adversarial loss (variants with ``use_disc``), one per view."""

from __future__ import annotations

import torch
from torch import nn

from layouts import NUM_CLASSES, VIEWS
from network.model.config import ModelConfig


class PatchDiscriminator(nn.Module):
    """LSGAN patch discriminator on one view's per-slot class probabilities ``(N, R, 3, D, D)``."""

    def __init__(self, slots: int, width: int = 32) -> None:
        super().__init__()
        c = slots * NUM_CLASSES
        self.net = nn.Sequential(
            nn.Conv2d(c, width, 4, 2, 1),
            nn.LeakyReLU(0.2, True),
            nn.Conv2d(width, 2 * width, 4, 2, 1),
            nn.BatchNorm2d(2 * width),
            nn.LeakyReLU(0.2, True),
            nn.Conv2d(2 * width, 4 * width, 4, 2, 1),
            nn.BatchNorm2d(4 * width),
            nn.LeakyReLU(0.2, True),
            nn.Conv2d(4 * width, 1, 3, 1, 1),
        )

    def forward(self, probs: torch.Tensor) -> torch.Tensor:
        return self.net(probs.flatten(1, 2))


def build_discriminators(cfg: ModelConfig) -> nn.ModuleDict | None:
    """One patch discriminator per view, or None for variants without them."""
    if not cfg.use_disc:
        return None
    return nn.ModuleDict({v: PatchDiscriminator(cfg.spec.num_slots) for v in VIEWS})
