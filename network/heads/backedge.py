"""The rack depth read from the shelf boards' back edges.

The top view is centred on the rack's mid-depth (`layouts.spec`), so the rack depth places the
footprint's front edge and every box standing at it; a top-view decoder that reads it a few
centimetres wrong costs more than anything else in the top view (docs/network.md). The depth is
plain geometry in the canonical view (`layouts.canonical`): a point ``Z`` metres behind the rack
front plane, ``y`` metres below the camera (``y < 0``: above), projects at row
``H/2 + y * rho / m`` with ``rho = d / (d + Z)`` (``m``: metres per canonical pixel on the front
plane; ``d``: the camera-to-rack distance the canonical warp already uses). A board below the camera
shows its top face from the front edge, which the row head finds, to the back edge ``depth`` behind
it; a board above shows its underside (one board thickness lower). So each board's back-edge row
and front row give the rack depth, and a sequence gives many boards.

`BackEdgeHead` finds back-edge rows: a 1-D network like the row head's, on the same column-pooled
pyramid features, trained with the rest of the network frozen (`network.training.fit_back_edges`).
`DepthReader` turns its probabilities into a depth: it scores every depth hypothesis by the
back-edge log-probability where each board's back edge would then fall, sums the scores over the
frames seen so far, and returns the best hypothesis; `network.inference.predictor.Predictor` imposes it on the top
views (`layouts.rackdepth.impose_rack_depth`).
"""

from __future__ import annotations

import numpy as np
import torch
from torch import nn

from layouts.canonical import CanonicalView
from network.heads.uprights import BACK_EDGE_WEIGHT, pool_pyramid, upright_depth_scores

#: board thickness assumed for the underside of boards above the camera (the generator draws 4-8 cm)
NOMINAL_THICKNESS = 0.06
#: boards within this height of the camera are left out: their back edge lies too near the front edge
MIN_OFFSET = 0.25
#: depth hypotheses: from this many metres up to the top view's depth extent, in steps of
DEPTH_MIN = 0.3
DEPTH_STEP = 0.005
#: back-edge probabilities are clipped here before the log, so one missed edge cannot veto a hypothesis
PROB_FLOOR = 1e-3


def pool_rows(p1: torch.Tensor, p2: torch.Tensor) -> torch.Tensor:
    """`network.heads.uprights.pool_pyramid` over the columns (boards are horizontal in the canonical image):
    ``(N, 2 (c1 + c2), H/2)``."""
    return pool_pyramid(p1, p2, -1)


def row_net(cin: int, width: int = 64) -> nn.Sequential:
    """1-D network over pooled rows -> 2 logits per pooled row (two canonical rows each), at low probability."""
    net = nn.Sequential(
        nn.Conv1d(cin, width, 5, padding=2, bias=False),
        nn.BatchNorm1d(width),
        nn.ReLU(True),
        nn.Conv1d(width, width, 5, padding=4, dilation=2, bias=False),
        nn.BatchNorm1d(width),
        nn.ReLU(True),
        nn.Conv1d(width, width, 5, padding=8, dilation=4, bias=False),
        nn.BatchNorm1d(width),
        nn.ReLU(True),
        nn.Conv1d(width, 2, 1),
    )
    with torch.no_grad():  # edges are rare rows
        net[-1].bias.fill_(-3.0)
    return net


def rows_from_net(y: torch.Tensor, height: int) -> torch.Tensor:
    """``(N, 2, H/2)`` -> ``(N, H)`` logits over canonical rows."""
    return y.transpose(1, 2).reshape(y.shape[0], -1)[:, :height]


class BackEdgeHead(nn.Module):
    """Logits ``(N, H)`` over canonical rows: does a shelf board's back edge (top face below the camera,
    underside above) lie here? Reads `pool_rows` features."""

    def __init__(self, channels: int, height: int) -> None:
        super().__init__()
        self.height = height
        self.net = row_net(channels)

    def forward(self, pooled: torch.Tensor) -> torch.Tensor:
        return rows_from_net(self.net(pooled), self.height)


def back_edge_rows(
    front_rows: np.ndarray | list[float],
    view: CanonicalView,
    distance: float,
    depth: float | np.ndarray,
    thickness: float = NOMINAL_THICKNESS,
) -> np.ndarray:
    """Canonical rows ``(Z, K)`` of the back edges of boards whose front edges (board tops) lie at
    ``front_rows`` ``(K,)``, for each rack ``depth`` ``(Z,)`` (a scalar gives ``(1, K)``).

    Boards within `MIN_OFFSET` of the camera's height are dropped (``K`` counts the others); rows
    outside the image are NaN.
    """
    m, h0 = view.metres_per_pixel, view.height / 2
    y = (np.asarray(front_rows, np.float64).reshape(-1) - h0) * m  # metres below the camera
    y = y[np.abs(y) >= MIN_OFFSET]
    y = np.where(y > 0, y, y + thickness)  # above the camera the underside shows
    rho = distance / (distance + np.atleast_1d(np.asarray(depth, np.float64)))
    rows = h0 + y[None, :] * rho[:, None] / m
    return np.where((rows >= 0) & (rows < view.height), rows, np.nan)


def depth_hypotheses(z_extent: float) -> np.ndarray:
    """The rack depths `DepthReader` weighs: `DEPTH_MIN` to ``z_extent`` metres in `DEPTH_STEP` steps."""
    # capped: the float steps of arange end a hair past z_extent (1.400000000000001), which the top view refuses
    return np.minimum(np.arange(DEPTH_MIN, z_extent + 1e-9, DEPTH_STEP), z_extent)


def frame_depth_scores(
    back_prob: np.ndarray,
    front_rows: np.ndarray | list[float],
    view: CanonicalView,
    distance: float,
    depths: np.ndarray,
) -> np.ndarray | None:
    """Log-likelihood ``(Z,)`` of each rack depth given one frame's back-edge probabilities ``(H,)`` and
    board front rows, or None when no board shows a back edge.

    Per board: the log-probability (interpolated at the back-edge row the depth predicts, floored at
    `PROB_FLOOR`); where that row leaves the image, the board's mean over the other hypotheses
    (no preference). Boards are summed.
    """
    rows = back_edge_rows(front_rows, view, distance, depths)  # (Z, K)
    if rows.shape[1] == 0:
        return None
    logp = np.log(np.clip(np.asarray(back_prob, np.float64), PROB_FLOOR, 1.0))
    centres = np.arange(view.height) + 0.5
    s = np.interp(np.nan_to_num(rows, nan=-1.0), centres, logp)
    s = np.where(np.isnan(rows), np.nan, s)
    seen = ~np.isnan(s).all(0)
    if not seen.any():
        return None
    s = s[:, seen]
    s = np.where(np.isnan(s), np.nanmean(s, 0, keepdims=True), s)
    return s.sum(1)


class DepthReader:
    """The rack depth of one sequence, from each frame's back-edge probabilities and board rows and, with
    an upright head, its front and rear upright probabilities (`network.heads.uprights`).

    `add` accumulates a frame's `frame_depth_scores` (times `network.heads.uprights.BACK_EDGE_WEIGHT` when
    the frame's uprights are given) and `network.heads.uprights.upright_depth_scores`; `depth` is the best
    hypothesis so far (None before any board or upright has given evidence) plus ``offset`` metres (the
    reader's measured bias undone, `network.training.calibrate.fit_rack_depth_offset`), at most ``z_extent``. One
    reader per sequence (one rack row).
    """

    def __init__(self, view: CanonicalView, z_extent: float, offset: float = 0.0) -> None:
        self.view = view
        self.depths = depth_hypotheses(z_extent)
        self.offset = float(offset)
        self.z_extent = float(z_extent)
        self.scores = np.zeros(len(self.depths))
        self.frames = 0  #: frames that contributed

    def add(
        self,
        back_prob: np.ndarray | None,
        front_rows: np.ndarray | list[float],
        distance: float,
        uprights: np.ndarray | None = None,
    ) -> float | None:
        """One frame: back-edge probabilities ``(H,)`` (None: a model without that head), board front rows,
        camera distance and, from a model with the upright head, upright probabilities ``(2, W)`` (front,
        rear). Returns `depth`."""
        s = None if back_prob is None else frame_depth_scores(back_prob, front_rows, self.view, distance, self.depths)
        if uprights is not None:
            u = upright_depth_scores(uprights[0], uprights[1], self.view, distance, self.depths)
            s = (
                None
                if s is None and u is None
                else (0.0 if u is None else u) + BACK_EDGE_WEIGHT * (0.0 if s is None else s)
            )
        if s is not None:
            self.scores += s
            self.frames += 1
        return self.depth

    @property
    def depth(self) -> float | None:
        """The best-scoring depth; None before any evidence, and while the best lies on either end of the
        hypotheses: a maximum there is no peak (the scores still climb off the grid), and such early readings
        were the reader's worst (0.3 m or 1.4 m against true depths of 0.9-1.0 m in the tuning sets' first frames)."""
        if not self.frames:
            return None
        k = int(np.argmax(self.scores))
        if k in (0, len(self.depths) - 1):
            return None
        return min(float(self.depths[k]) + self.offset, self.z_extent)
