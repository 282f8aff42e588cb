"""Inference: streaming (state carried frame to frame) and windowed (the paper's) modes.

Streaming runs the encoder once per frame and advances the ConvLSTM one step, so frame t sees
the whole prefix ``0..t``. Windowed mode reproduces training: frame t is predicted from the
window ``t-T+1..t`` (first frame repeated at the start) from a fresh ConvLSTM state. Encoder
features are cached across windows, so it also costs one encoder pass per frame; pass
``recompute=True`` for the naive form that re-encodes the whole window every frame.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Iterable, Iterator
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F

from layouts import VIEWS
from network.data import resize_image, to_tensor
from network.model import MVRackLay

MODES = ("stream", "window")


class Predictor:
    """Wraps a model for frame-by-frame prediction from uint8 RGB images of any size."""

    def __init__(self, model: MVRackLay) -> None:
        self.model = model.eval()
        self.cfg = model.cfg
        self.device = next(model.parameters()).device  # frames go where the weights are (CPU or a GPU)

    def preprocess(self, rgb: np.ndarray) -> torch.Tensor:
        img = resize_image(np.asarray(rgb), self.cfg.input_width, self.cfg.input_height)
        return to_tensor(img)[None].to(self.device)

    @torch.no_grad()
    def stream(self, frames: Iterable[np.ndarray]) -> Iterator[dict[str, torch.Tensor]]:
        """Logits ``{view: (R, 3, D, D)}`` per frame, carrying the ConvLSTM state."""
        state = None
        for rgb in frames:
            out, state = self.model.step(self.preprocess(rgb), state)
            yield {v: o[0] for v, o in out.items()}

    @torch.no_grad()
    def window(self, frames: Iterable[np.ndarray], recompute: bool = False) -> Iterator[dict[str, torch.Tensor]]:
        """Logits per frame from the window of ``seq_len`` frames ending there (fresh state each)."""
        m, t_len = self.model, self.cfg.seq_len
        images: deque[torch.Tensor] = deque(maxlen=t_len)
        feats: deque[torch.Tensor] = deque(maxlen=t_len)
        for rgb in frames:
            x = self.preprocess(rgb)
            if recompute:
                if not images:
                    images.extend([x] * t_len)
                images.append(x)
                out = m(torch.stack(list(images), 1))
                yield {v: o[0, -1] for v, o in out.items()}
                continue
            f2, f3, f4, f5 = m.encode(x)
            if not feats:
                feats.extend([f5] * t_len)
            feats.append(f5)
            if self.cfg.use_lstm:
                top = m.temporal_window(torch.stack(list(feats), 1))[:, -1]
            else:
                top = m.temporal(f5)
            out = m.decode((f2, f3, f4, top))
            yield {v: o[0] for v, o in out.items()}

    def run(self, frames: Iterable[np.ndarray], mode: str = "stream") -> Iterator[dict[str, torch.Tensor]]:
        if mode == "stream":
            return self.stream(frames)
        if mode == "window":
            return self.window(frames)
        raise ValueError(f"mode must be one of {MODES}, got {mode!r}")


def logits_to_layout(logits: torch.Tensor, size: int | None = None) -> np.ndarray:
    """``(R, 3, D, D)`` logits -> ``(R, size, size)`` uint8 class ids (bilinear on logits when resizing)."""
    if size is not None and size != logits.shape[-1]:
        logits = F.interpolate(logits.float(), size=(size, size), mode="bilinear", align_corners=False)
    return logits.argmax(1).to(torch.uint8).cpu().numpy()


def rescale_x(out: dict[str, torch.Tensor], scale: float) -> dict[str, torch.Tensor]:
    """Resample one frame's logits ``{view: (R, 3, D, D)}`` along X: content at x moves to ``scale * x``.

    One image cannot tell the camera-to-rack distance (rack, shelf and box sizes all vary), so
    the network lays a frame out as if seen from the training data's mean distance. When the
    true distance d is known, ``scale = d / nominal`` puts the layout at its metric width again;
    columns that come from outside the predicted extent become background.
    """
    if not (math.isfinite(scale) and scale > 0):
        raise ValueError(f"scale must be a positive number, got {scale}")
    if abs(scale - 1.0) < 1e-6:
        return out
    res = {}
    for v, lg in out.items():
        d = lg.shape[-1]
        g = ((torch.arange(d, dtype=torch.float64, device=lg.device) + 0.5) * 2 / d - 1) / scale
        src = (g + 1) * d / 2 - 0.5  # continuous source column of each output column
        lo = src.floor().clamp(0, d - 1).long()
        hi = (lo + 1).clamp(max=d - 1)
        w = (src - lo).clamp(0, 1).to(lg.dtype)
        r = lg.index_select(-1, lo) * (1 - w) + lg.index_select(-1, hi) * w
        outside = g.abs() > 1
        if bool(outside.any()):
            r[..., outside] = 0
            r[:, 0][..., outside] = 1  # background wins outside the predicted extent
        res[v] = r
    return res


def frame_layouts(out: dict[str, torch.Tensor], size: int | None = None) -> dict[str, Any]:
    """Both views' class-id stacks from one frame's logits."""
    return {v: logits_to_layout(out[v], size) for v in VIEWS}


def predict_layouts(
    model: MVRackLay, frames: Iterable[np.ndarray], mode: str = "stream", size: int | None = None
) -> Iterator[dict[str, np.ndarray]]:
    """``{"top", "front"}`` uint8 ``(R, size, size)`` class ids per frame of uint8 RGB images (any size)."""
    for out in Predictor(model).run(frames, mode):
        yield frame_layouts(out, size)
