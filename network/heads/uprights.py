"""The rack depth read from the racks' rear uprights.

A rack stands on four uprights, two at its front and two at its back, at the same X. In the
canonical view (`layouts.canonical`) a vertical edge ``Z`` metres behind the rack front, ``x`` metres
to the side of the optical axis, lies at column offset ``x * rho / m`` from the centre, ``rho = d /
(d + Z)`` (``m``: metres per canonical pixel on the front plane; ``d``: the camera-to-rack distance).
The front uprights stand on the front plane (``rho = 1``), so every front upright at offset ``x``
has its rear partner at ``x * rho``, drawn closer to the centre the deeper the rack. Unlike a
board's back edge, which is a few pixels from its front edge for boards near eye level, the rear
uprights are tall, seen at every camera height, and pulled 0.2-0.4 m in from their front partners at
the image edges; and a busy background has no structure that keeps that pairing frame after frame.

`UprightHead` marks, per canonical column, front and rear uprights of the mapped row: a 1-D network
along the columns on row-pooled pyramid features (`pool_columns`), fitted with the rest of the
network frozen (`network.training.fit_uprights`). `upright_depth_scores` turns one frame's marks into a
log-likelihood over rack depths; `network.heads.backedge.DepthReader` sums it over the frames with the
back-edge scores (weighted `BACK_EDGE_WEIGHT`: the uprights read the depth better, measured in docs/network.md).
"""

from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from layouts.canonical import CanonicalView

#: metres from the rack's back to the rear uprights' visible face: the generator's uprights are 6-10 cm wide
#: (their centre half a width in, their front face a width in); chosen on the training scenes
REAR_FACE = 0.09
#: columns within this many metres of the optical axis are left out: there the rear upright hides behind the front
MIN_AXIS_OFFSET = 0.3
#: a column is a front upright from this probability on
FRONT_THRESHOLD = 0.5
#: rear-upright probabilities are clipped here before the log, so one hidden upright cannot veto a hypothesis
PROB_FLOOR = 1e-3
#: the back-edge scores' weight in the depth read when the uprights are read too (chosen on the tuning sets)
BACK_EDGE_WEIGHT = 0.1


def pool_pyramid(p1: torch.Tensor, p2: torch.Tensor, over: int) -> torch.Tensor:
    """Pyramid maps ``(N, c1, H/2, W/2)`` and ``(N, c2, H/4, W/4)`` -> mean and max over dimension ``over`` (-2:
    the rows, -1: the columns), the coarse map brought to the fine positions left: ``(N, 2 (c1 + c2), L)``."""
    a = torch.cat([p1.mean(over), p1.amax(over)], 1)
    b = torch.cat([p2.mean(over), p2.amax(over)], 1)
    b = F.interpolate(b, size=a.shape[-1], mode="linear", align_corners=False)
    return torch.cat([a, b], 1)


def pool_columns(p1: torch.Tensor, p2: torch.Tensor) -> torch.Tensor:
    """`pool_pyramid` over the rows (uprights are vertical in the canonical image): ``(N, 2 (c1 + c2), W/2)``."""
    return pool_pyramid(p1, p2, -2)


class UprightHead(nn.Module):
    """Logits ``(N, 2, W)`` over canonical columns: a front upright here (channel 0), a rear one (1)."""

    def __init__(self, channels: int, width: int, hidden: int = 64) -> None:
        super().__init__()
        self.width = width

        def block(cin: int, k: int, dil: int) -> list[nn.Module]:
            return [nn.Conv1d(cin, hidden, k, padding=dil * (k // 2), dilation=dil, bias=False),
                    nn.BatchNorm1d(hidden), nn.ReLU(True)]  # fmt: skip

        self.net = nn.Sequential(
            *block(channels, 5, 1), *block(hidden, 5, 2), *block(hidden, 5, 4), *block(hidden, 3, 1),
            nn.Conv1d(hidden, 4, 1),  # two classes x the two canonical columns of each pooled column
        )  # fmt: skip
        with torch.no_grad():  # uprights are rare columns
            self.net[-1].bias.fill_(-2.0)

    def forward(self, pooled: torch.Tensor) -> torch.Tensor:
        y = self.net(pooled)  # (N, 4, W/2): front even, front odd, rear even, rear odd
        n = y.shape[0]
        return y.view(n, 2, 2, -1).transpose(2, 3).reshape(n, 2, -1)[..., : self.width]


def column_offsets(view: CanonicalView) -> np.ndarray:
    """``(W,)`` metres on the front plane from the optical axis to each canonical column's centre."""
    return (np.arange(view.width) + 0.5 - view.width / 2) * view.metres_per_pixel


def upright_depth_scores(
    front: np.ndarray, rear: np.ndarray, view: CanonicalView, distance: float, depths: np.ndarray
) -> np.ndarray | None:
    """Log-likelihood ``(Z,)`` of each rack depth given one frame's upright probabilities ``(W,)`` (front,
    rear), or None when no front upright lies far enough off the axis.

    Per front-upright column at offset ``x`` (weighted by its probability): the rear-upright
    log-probability (floored at `PROB_FLOOR`) at ``x * rho``, ``rho`` of the rear face `REAR_FACE` in
    front of the rack's back; the mean over those columns, so every frame weighs alike.
    """
    x = column_offsets(view)
    front = np.asarray(front, np.float64)
    use = (np.abs(x) > MIN_AXIS_OFFSET) & (front >= FRONT_THRESHOLD)
    if not use.any():
        return None
    w, x = front[use], x[use]
    logp = np.log(np.clip(np.asarray(rear, np.float64), PROB_FLOOR, 1.0))
    rho = distance / (distance + np.maximum(np.asarray(depths, np.float64) - REAR_FACE, 0.0))
    cols = (x[None, :] * rho[:, None]) / view.metres_per_pixel + view.width / 2 - 0.5  # continuous column index
    s = np.interp(cols, np.arange(view.width), logp)
    return (s * w[None, :]).sum(1) / w.sum()
