"""`DistanceReader`: the camera-to-rack distance read from one frame, and the floor line below the racks.

A monocular frame fixes sizes only up to the distance: the same rack filmed from 2.3 m or from 2.9 m
differs by scale alone. The layouts network needs that scale (`layouts.canonical` resamples every frame
to a fixed number of metres per pixel on the rack front plane), so a wrong distance zooms what it sees.
The reader takes the frame resampled at an *assumed* distance ``d0`` (its own `CanonicalView`,
independent of any layouts model) and regresses:

* ``log(d / d0)``: how far the assumption is off, from what sizes look like at that scale (boards,
  uprights, boxes, the racks' depth in perspective, surface textures);
* ``floor_y``: where the floor meets the rack front below the optical axis, in the canonical view's
  metres (``camera height * d0 / d``) — with a known camera height this gives the distance by geometry;
* ``floor_logit``: whether that line is in view at all.

A small convolutional network (about 0.4 M parameters, ~1 ms a frame on a CPU core) trained on generated
frames by `network.training.fit_distance`; read by `network.inference.distance`.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import torch
from torch import nn

from layouts.canonical import CanonicalView
from layouts.errors import InputError

#: channels of the stem (one strided convolution) and of the strided blocks after it
STEM = 16
CHANNELS = (32, 48, 64, 96)


@dataclass(frozen=True)
class DistanceReaderConfig:
    """The reader's input geometry: a ``size x size`` canonical view ``x_extent`` metres wide."""

    size: int = 128
    x_extent: float = 3.2

    @property
    def view(self) -> CanonicalView:
        return CanonicalView(self.size, self.size, self.x_extent)

    @classmethod
    def from_dict(cls, d: Any) -> DistanceReaderConfig:
        if not isinstance(d, dict) or set(d) - {"size", "x_extent"}:
            raise InputError(f"distance reader config must hold size and x_extent, got {d!r}")
        cfg = cls(**d)
        if not isinstance(cfg.size, int) or cfg.size % 32 or not 64 <= cfg.size <= 512:
            raise InputError(f"distance reader size must be a multiple of 32 in [64, 512], got {cfg.size!r}")
        _ = cfg.view  # checks x_extent
        return cfg

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def _block(c_in: int, c_out: int) -> nn.Sequential:
    return nn.Sequential(
        nn.Conv2d(c_in, c_out, 3, stride=2, padding=1, bias=False),
        nn.BatchNorm2d(c_out),
        nn.ReLU(inplace=True),
        nn.Conv2d(c_out, c_out, 3, padding=1, bias=False),
        nn.BatchNorm2d(c_out),
        nn.ReLU(inplace=True),
    )


class DistanceReader(nn.Module):
    """Images ``(B, 3, S, S)`` in [0, 1] -> ``(B, 3)``: log ratio, floor_y, floor logit.

    The last feature map is flattened rather than pooled: where things are (the floor line's row) matters.
    """

    def __init__(self, cfg: DistanceReaderConfig | None = None) -> None:
        super().__init__()
        self.cfg = cfg or DistanceReaderConfig()
        stem = nn.Sequential(
            nn.Conv2d(3, STEM, 5, stride=2, padding=2, bias=False), nn.BatchNorm2d(STEM), nn.ReLU(True)
        )
        blocks, c = [stem], STEM
        for c_out in CHANNELS:
            blocks.append(_block(c, c_out))
            c = c_out
        self.features = nn.Sequential(*blocks)
        cells = (self.cfg.size // 2 ** (len(CHANNELS) + 1)) ** 2
        self.head = nn.Sequential(
            nn.Conv2d(c, 16, 1),
            nn.ReLU(inplace=True),
            nn.Flatten(),
            nn.Linear(16 * cells, 128),
            nn.ReLU(inplace=True),
            nn.Linear(128, 3),
        )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """``x`` in [0, 1] (`network.data.to_tensor`)."""
        return self.head(self.features((x - 0.45) / 0.25))
