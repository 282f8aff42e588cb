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
    """Images ``(B, 3, S, S)`` in [0, 1] -> raw outputs ``(B, 2 + S // 4)`` (`forward`), read by `read`.

    Two heads on one trunk: the log ratio from the last feature map, flattened (where things are matters);
    the floor line as a distribution over rows of 4 canonical pixels, from the stride-4 features averaged
    along each row (the line is horizontal in a levelled view), read to a fraction of a row by its mean
    around the most likely row, beside one logit for "in view".
    """

    def __init__(self, cfg: DistanceReaderConfig | None = None) -> None:
        super().__init__()
        self.cfg = cfg or DistanceReaderConfig()
        self.stem = nn.Sequential(
            nn.Conv2d(3, STEM, 5, stride=2, padding=2, bias=False), nn.BatchNorm2d(STEM), nn.ReLU(True)
        )
        blocks, c = [], STEM
        for c_out in CHANNELS:
            blocks.append(_block(c, c_out))
            c = c_out
        self.blocks = nn.ModuleList(blocks)
        cells = (self.cfg.size // 2 ** (len(CHANNELS) + 1)) ** 2
        self.scale_head = nn.Sequential(
            nn.Conv2d(c, 16, 1),
            nn.ReLU(inplace=True),
            nn.Flatten(),
            nn.Linear(16 * cells, 128),
            nn.ReLU(inplace=True),
            nn.Linear(128, 2),  # log ratio, floor in view
        )
        fine = CHANNELS[0]
        self.row_head = nn.Sequential(
            nn.Conv1d(fine, 48, 3, padding=1),
            nn.ReLU(inplace=True),
            nn.Conv1d(48, 48, 3, padding=2, dilation=2),
            nn.ReLU(inplace=True),
            nn.Conv1d(48, 48, 3, padding=4, dilation=4),
            nn.ReLU(inplace=True),
            nn.Conv1d(48, 1, 3, padding=1),
        )

    @property
    def row_metres(self) -> float:
        """Canonical metres per floor-row bin (4 canonical pixels)."""
        return 4 * self.cfg.x_extent / self.cfg.size

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """``x`` in [0, 1] (`network.preprocess.to_tensor`) -> ``(B, 2 + R)``: log ratio, floor logit, R row logits."""
        f = self.stem((x - 0.45) / 0.25)
        f = self.blocks[0](f)
        rows = self.row_head(f.mean(dim=3)).squeeze(1)
        for b in self.blocks[1:]:
            f = b(f)
        return torch.cat([self.scale_head(f), rows], dim=1)

    def floor_y(self, row_logits: torch.Tensor, window: int = 2) -> torch.Tensor:
        """Canonical metres below the optical axis of the floor line: the probability-weighted row around the
        most likely one (``window`` rows either side)."""
        p = row_logits.softmax(dim=1)
        r = torch.arange(p.shape[1], device=p.device, dtype=p.dtype)
        top = p.argmax(dim=1, keepdim=True)
        near = ((r[None] - top).abs() <= window).to(p.dtype) * p
        row = (near * (r[None] + 0.5)).sum(1) / near.sum(1).clamp(min=1e-9)
        return (row - p.shape[1] / 2) * self.row_metres

    def read(self, x: torch.Tensor) -> torch.Tensor:
        """``(B, 3)``: log ratio ``log(d / d0)``, floor_y (canonical metres), floor-in-view logit."""
        out = self.forward(x)
        return torch.stack([out[:, 0], self.floor_y(out[:, 2:]), out[:, 1]], dim=1)
