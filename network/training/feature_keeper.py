"""The feature-keeping term of fine-tuning (``train --keep-features W``).

The depth heads (back edges, uprights, box depth) are fitted on a frozen network's pyramid maps. Fine-tuned on
other looks, the network's maps move and the fitted heads read them worse (mixed-128: map recall on the standard
set 0.882 -> 0.861 with Table I unchanged). This term keeps the maps: the start network, frozen, maps the same
training frames, and the trained network's maps are pulled towards them (mean squared error over each map's
variance, so both scales weigh alike), as learning without forgetting does with outputs. Its batch-norm layers
normalise as the trained network's do: by each batch's statistics (their running ones left as they are), or by
the running ones under ``--frozen-bn``; so the term starts at zero.
"""

from __future__ import annotations

import torch
from torch import nn

from network.checkpoint import init_weights_from
from network.model.net import MVRackLay


class FeatureKeeper:
    """Targets from the network of ``init_from`` (frozen) for ``model``'s pyramid maps, caught by a hook."""

    def __init__(
        self, model: MVRackLay, init_from: str | None, device: torch.device, batch_statistics: bool = True
    ) -> None:
        if not init_from:
            raise ValueError("the feature-keeping term needs the network it keeps (init_from)")
        self.teacher = MVRackLay(model.cfg)
        init_weights_from(self.teacher, init_from)
        self.teacher.to(device).train(batch_statistics)
        for p in self.teacher.parameters():
            p.requires_grad_(False)
        for m in self.teacher.modules():
            if isinstance(m, nn.modules.batchnorm._BatchNorm):
                m.momentum = 0.0  # batch statistics used, the running ones never updated
        self.caught: tuple[torch.Tensor, ...] | None = None
        model.pyramid.register_forward_hook(self._catch)

    def _catch(self, module: nn.Module, inputs: object, output: tuple[torch.Tensor, ...]) -> None:
        self.caught = output

    def loss(self, images: torch.Tensor) -> torch.Tensor:
        """The term for the frames ``images`` ``(B, T, 3, H, W)`` whose forward pass just ran."""
        if self.caught is None:
            raise RuntimeError("the feature-keeping term: no pyramid maps were caught in the forward pass")
        with torch.no_grad():
            targets = self.teacher.maps(images.transpose(0, 1).flatten(0, 1))  # time-major, as MVRackLay.forward
        maps, self.caught = self.caught, None
        total = images.new_zeros(())
        for got, want in zip(maps, targets):
            if got.shape != want.shape:
                raise RuntimeError(f"the feature-keeping term: maps {tuple(got.shape)} against {tuple(want.shape)}")
            total = total + nn.functional.mse_loss(got.float(), want.float()) / want.float().var().clamp_min(1e-6)
        return total
