"""The shelf-anchored decoders: feature pyramid, row head (where the boards are) and per-slot layout heads.

The row head scores every canonical row for "the top edge of a visible shelf board's front"
(`anchors_from_rows`, `board_peaks`); `SlotHeads` samples the pyramid along each slot's anchor row into
layout-space maps of both views (`SlotFeatures`) and turns them into ``R x 3`` class logits
(`network.model.net` describes the whole network).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import nn

from layouts import NUM_CLASSES
from layouts.canonical import CanonicalView
from network.fastops import up2
from network.heads.backedge import pool_rows, row_net, rows_from_net
from network.heads.boxdepth import window_rows
from network.model.config import ModelConfig

#: the top view's band of image rows around a board: this far above the front window, and below the board (metres)
BAND_ABOVE = 0.15
BAND_BELOW = 0.30
#: row head decoding: probability threshold and the least distance between two boards (metres)
ROW_THRESHOLD = 0.5
MIN_BOARD_GAP = 0.35


def conv_bn_relu(cin: int, cout: int, k: int = 3) -> nn.Sequential:
    return nn.Sequential(nn.Conv2d(cin, cout, k, padding=k // 2, bias=False), nn.BatchNorm2d(cout), nn.ReLU(True))


def up(x: torch.Tensor, like: torch.Tensor | None = None) -> torch.Tensor:
    if like is not None:
        return F.interpolate(x, size=like.shape[-2:], mode="nearest")
    return up2(x)


class ColumnTransform(nn.Module):
    """``(N, C, h, w) -> (N, cout, rows, w)``: per image column, channels x rows -> cout x rows'.

    A 1x1 convolution on the column-stacked features: every column gets the same learned
    mapping from (slot-anchored) image rows to layout rows, and columns never mix (X stays aligned).
    """

    def __init__(self, cin: int, hin: int, cout: int, rows: int) -> None:
        super().__init__()
        self.cout, self.rows = cout, rows
        self.proj = nn.Sequential(
            nn.Conv2d(cin * hin, cout * rows, 1, bias=False), nn.BatchNorm2d(cout * rows), nn.ReLU(True)
        )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        n, c, h, w = x.shape
        y = self.proj(x.reshape(n, c * h, 1, w))
        return y.reshape(n, self.cout, self.rows, w)


#: Encoder features of a batch of frames: the 1/2 (stem), 1/4, 1/8, 1/16 maps and the reduced 1/32 map.
Features = tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]


@dataclass
class SlotFeatures:
    """Per-slot features of N frames (slots flattened into the batch: ``N*R``) before the output heads."""

    top: torch.Tensor  #: (N*R, dw, D/2, D/2) coarse top-view map
    front: torch.Tensor  #: (N*R, dw, D/2, D/2) coarse front-view map
    fine: torch.Tensor  #: (N*R, c1, D, D) fine front-window samples of the 1/2 map
    valid: torch.Tensor  #: (N, R) bool: the slot has an anchor
    motion: torch.Tensor | None = None  #: (N, 2, H, W) `network.model.motion.motion_signature` of the images
    back: torch.Tensor | None = (
        None  #: (N, H) back-edge logits (`network.heads.backedge.BackEdgeHead`), if the model has the head
    )
    window: torch.Tensor | None = (
        None  #: (N, R, c1, rows, W) front windows of the 1/2 map, for `network.heads.boxdepth`
    )
    uprights: torch.Tensor | None = (
        None  #: (N, 2, W) upright logits (`network.heads.uprights.UprightHead`), with the head
    )

    def select(self, n: int, i: int) -> SlotFeatures:
        """Frame ``i`` of ``n`` consecutive frames' features flattened as (frame, batch) -> that frame's."""

        def pick(t: torch.Tensor | None) -> torch.Tensor | None:
            return None if t is None else t.unflatten(0, (n, -1))[i]

        return SlotFeatures(**{k: pick(getattr(self, k)) for k in SLOT_FEATURES})


#: `SlotFeatures`' fields, in order
SLOT_FEATURES = ("top", "front", "fine", "valid", "motion", "back", "window", "uprights")


class Pyramid(nn.Module):
    """Top-down feature pyramid from the 1/32 map (after its single-frame block) to a 1/4 map (``2 dw`` channels) and a 1/2 map."""

    def __init__(self, cfg: ModelConfig, c1: int, c2: int, c3: int, c4: int) -> None:
        super().__init__()
        f = 2 * cfg.decoder_width
        self.lat5 = conv_bn_relu(cfg.hidden, f, 1)
        self.lat4 = conv_bn_relu(c4, f, 1)
        self.lat3 = conv_bn_relu(c3, f, 1)
        self.lat2 = conv_bn_relu(c2, f, 1)
        self.m4 = conv_bn_relu(f, f)
        self.m3 = conv_bn_relu(f, f)
        self.m2 = conv_bn_relu(f, f)
        self.fine_in = conv_bn_relu(f, self.fine_channels(cfg), 1)
        self.m1 = conv_bn_relu(self.fine_channels(cfg) + c1, self.fine_channels(cfg))
        self.channels = (self.fine_channels(cfg), f)

    @staticmethod
    def fine_channels(cfg: ModelConfig) -> int:
        return max(cfg.decoder_width // 2, 4)

    def forward(self, feats: Features, t5: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        s1, f2, f3, f4, _ = feats
        p = self.lat5(t5)
        p = self.m4(up(p, f4) + self.lat4(f4))
        p = self.m3(up(p, f3) + self.lat3(f3))
        p2 = self.m2(up(p, f2) + self.lat2(f2))
        p1 = self.m1(torch.cat([up(self.fine_in(p2), s1), s1], 1))
        return p1, p2


class RowHead(nn.Module):
    """Logits ``(N, H)`` over canonical rows: does the top edge of a visible shelf board's front lie here?

    Boards are horizontal in the canonical image (the camera does not roll), so the evidence is
    pooled across columns (mean and max, `network.heads.backedge.pool_rows`) and reasoned about along the rows.
    """

    def __init__(self, c1: int, c2: int, height: int) -> None:
        super().__init__()
        self.height = height
        self.net = row_net(2 * (c1 + c2))

    def from_pooled(self, pooled: torch.Tensor) -> torch.Tensor:
        """Logits from `pool_rows` features (shared with the back-edge head)."""
        return rows_from_net(self.net(pooled), self.height)

    def forward(self, p1: torch.Tensor, p2: torch.Tensor) -> torch.Tensor:
        return self.from_pooled(pool_rows(p1, p2))


def anchors_from_rows(
    logits: torch.Tensor, view: CanonicalView, slots: int, threshold: float = ROW_THRESHOLD
) -> torch.Tensor:
    """Decode row-head logits ``(N, H)`` into slot anchors ``(N, R)``: continuous canonical rows, NaN = no slot.

    Peaks above ``threshold`` at least `MIN_BOARD_GAP` apart (strongest first), each refined to
    the probability-weighted centre of its +-2 rows; the lowest R (largest rows) become slots 0..R-1.
    """
    p = torch.sigmoid(logits.detach().float()).cpu()
    out = torch.full((p.shape[0], slots), float("nan"))
    for i in range(p.shape[0]):
        for s, c in enumerate(board_peaks(p[i], view, threshold)[:slots]):
            out[i, s] = c
    return out.to(logits.device)


def board_peaks(prob: torch.Tensor, view: CanonicalView, threshold: float = ROW_THRESHOLD) -> list[float]:
    """Continuous canonical rows of the boards in one frame's row-head probabilities ``(H,)``, lowest first.

    Peaks above ``threshold`` at least `MIN_BOARD_GAP` apart (strongest first), each refined to the
    probability-weighted centre of its +-2 rows.
    """
    p = prob.detach().float().cpu().reshape(-1)
    h = p.shape[0]
    gap = MIN_BOARD_GAP / view.metres_per_pixel
    left = F.pad(p, (1, 0), value=-1.0)[:-1]
    right = F.pad(p, (0, 1), value=-1.0)[1:]
    peak = (p >= left) & (p > right) & (p > threshold)
    idx = torch.arange(h, dtype=torch.float32)
    cand = torch.nonzero(peak).flatten().tolist()
    cand.sort(key=lambda r: -float(p[r]))
    kept: list[float] = []
    for r in cand:
        lo, hi = max(0, r - 2), min(h, r + 3)
        w = p[lo:hi]
        c = float((w * idx[lo:hi]).sum() / w.sum()) + 0.5
        if all(abs(c - k) >= gap for k in kept):
            kept.append(c)
    return sorted(kept, reverse=True)


class SlotHeads(nn.Module):
    """Both views of every shelf slot from pyramid features sampled along the slot's anchor row."""

    def __init__(self, cfg: ModelConfig, c1: int, c2: int) -> None:
        super().__init__()
        spec, view = cfg.spec, cfg.view
        self.view, self.spec = view, spec
        d, dw = spec.size, cfg.decoder_width
        self.dc = d // 2
        self.band_rows = self._band_rows(4)  # ~1.3 samples per 1/4-map row
        cs = dw
        self.reduce = conv_bn_relu(c2, cs, 1)
        self.col = ColumnTransform(cs, self.band_rows, dw, self.dc)
        self.front_c = nn.Sequential(conv_bn_relu(cs + 1, dw), conv_bn_relu(dw, dw))
        self.top_c = nn.Sequential(conv_bn_relu(dw + 1, dw), conv_bn_relu(dw, dw))
        half = max(dw // 2, 4)
        self.front_f = nn.Sequential(conv_bn_relu(dw + c1, half), nn.Conv2d(half, NUM_CLASSES, 1))
        self.top_f = nn.Sequential(conv_bn_relu(dw + c1, half), nn.Conv2d(half, NUM_CLASSES, 1))
        # front-window heights (row 0 = top) and the top view's band, as offsets in canonical rows
        self.register_buffer("front_coarse", self._heights(self.dc), persistent=False)
        self.register_buffer("front_fine", self._heights(d), persistent=False)
        self.register_buffer("band", self._band(self.band_rows), persistent=False)

    def _band_rows(self, stride: int) -> int:
        """Rows sampled on the top view's band from a map of ``stride`` canonical pixels per row (~1.3 each)."""
        band = self.spec.h_extent + BAND_ABOVE + BAND_BELOW
        return max(4, math.ceil(1.3 * band / (stride * self.view.metres_per_pixel)))

    def _band(self, rows: int) -> torch.Tensor:
        """The top view's band (`BAND_ABOVE` over the front window to `BAND_BELOW` under the board) as
        ``rows`` offsets in canonical rows from the anchor."""
        band = self.spec.h_extent + BAND_ABOVE + BAND_BELOW
        k = torch.arange(rows, dtype=torch.float32)
        return (-(self.spec.h_extent + BAND_ABOVE) + (k + 0.5) / rows * band) / self.view.metres_per_pixel

    def _heights(self, n: int) -> torch.Tensor:
        h = (n - torch.arange(n, dtype=torch.float32) - 0.5) / n * self.spec.h_extent
        return -h / self.view.metres_per_pixel

    def _sample(self, fmap: torch.Tensor, anchors: torch.Tensor, offsets: torch.Tensor, cols: int) -> torch.Tensor:
        """``(N, C, h, w)`` sampled at rows ``anchor + offset`` x ``cols`` even columns -> ``(N*R, C, rows, cols)``."""
        n, r = anchors.shape
        rows = offsets.numel()
        y = (anchors[:, :, None] + offsets[None, None, :]) * (2.0 / self.view.height) - 1.0  # (N, R, rows)
        x = (torch.arange(cols, device=fmap.device, dtype=fmap.dtype) + 0.5) * (2.0 / cols) - 1.0
        grid = torch.stack(
            [x.view(1, 1, 1, cols).expand(n, r, rows, cols), y[..., None].expand(n, r, rows, cols)], -1
        ).reshape(n, r * rows, cols, 2)
        s = F.grid_sample(fmap, grid.to(fmap.dtype), mode="bilinear", padding_mode="zeros", align_corners=False)
        c = fmap.shape[1]
        return s.view(n, c, r, rows, cols).transpose(1, 2).reshape(n * r, c, rows, cols)

    def coarse(self, p1: torch.Tensor, p2: torch.Tensor, anchors: torch.Tensor) -> SlotFeatures:
        """Per-slot coarse layout-space maps of both views (and the fine samples) of a batch of frames."""
        n, r = anchors.shape
        d, dc = self.spec.size, self.dc
        valid = torch.isfinite(anchors)
        a = torch.where(valid, anchors, torch.full_like(anchors, self.view.height / 2)).to(p2.dtype)
        elev = (a.reshape(n * r, 1, 1, 1) - self.view.height / 2) * (self.view.metres_per_pixel / 1.5)
        q = self.reduce(p2)
        fc = self._sample(q, a, self.front_coarse, dc)
        fc = self.front_c(torch.cat([fc, elev.expand(-1, 1, dc, dc)], 1))
        tb = self.col(self._sample(q, a, self.band, dc))
        tc = self.top_c(torch.cat([tb, elev.expand(-1, 1, dc, dc)], 1))
        ff = self._sample(p1, a, self.front_fine, d)  # (N*R, c1, D, D)
        return SlotFeatures(tc, fc, ff, valid)

    def window(self, p1: torch.Tensor, anchors: torch.Tensor) -> torch.Tensor:
        """The 1/2 map ``(N, c1, H/2, W/2)`` over each slot's front window, every column of it:
        ``(N, R, c1, rows, W/2)`` (rows: the front view's in groups, `network.heads.boxdepth.WINDOW_ROWS`; a slot
        without an anchor samples the image's middle)."""
        n, r = anchors.shape
        a = torch.where(torch.isfinite(anchors), anchors, torch.full_like(anchors, self.view.height / 2))
        rows = window_rows(self.spec.size)
        offs = self.front_fine.view(rows, -1).mean(1)
        return self._sample(p1, a, offs, p1.shape[-1]).unflatten(0, (n, r))

    def finish(self, f: SlotFeatures) -> dict[str, torch.Tensor]:
        """``R x 3`` logits of both views from (possibly memory-refined) slot features."""
        n, r = f.valid.shape
        d = self.spec.size
        front = self.front_f(torch.cat([up(f.front), f.fine], 1))
        edges = f.fine.amax(2, keepdim=True).expand(-1, -1, d, -1)  # the front face's X evidence, along depth
        top = self.top_f(torch.cat([up(f.top), edges], 1))
        out = {}
        bg = torch.tensor([8.0] + [-8.0] * (NUM_CLASSES - 1), device=front.device, dtype=front.dtype)
        for name, o in (("top", top), ("front", front)):
            o = o.view(n, r, NUM_CLASSES, d, d)
            out[name] = torch.where(f.valid[:, :, None, None, None], o, bg.view(1, 1, -1, 1, 1))
        return out

    def forward(self, p1: torch.Tensor, p2: torch.Tensor, anchors: torch.Tensor) -> dict[str, torch.Tensor]:
        return self.finish(self.coarse(p1, p2, anchors))
