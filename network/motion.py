"""Camera motion along the rack row between consecutive frames, read from the canonical images alone.

A canonical image (`layouts.canonical.CanonicalView`) has square pixels of a fixed metric size on
the rack front plane, centred on the optical axis. When the camera moves by ``dx`` along the row
(X), everything on the front plane (uprights, board edges, box fronts) moves by ``-dx`` in the
image, and the camera's height does not change. So the motion is the horizontal offset that best
lines up two consecutive canonical images: a cross-correlation, computed with FFTs. Things behind
the front plane move less (parallax), which biases the estimate low.

On the held-out generated set the estimate is off by ~2 cm per frame (median), a tenth of a
slot-memory cell, but it reads short: 3.1 cm of an 11.5 cm step on average, 0.75 of the camera's
path over a sequence (median; `benchmarks/frame_fusion.py --motion images` shows what that costs a
fusion over frames). It needs no pose, so prediction on a user's footage uses it as training does.
The slot memory (`network.model.SlotMemory`) shifts its state by it before each frame.
"""

from __future__ import annotations

import torch

from layouts.canonical import CanonicalView

#: the largest motion looked for between two frames (metres)
MAX_SHIFT = 0.6
#: vertical offsets (canonical rows) tolerated around zero: the camera keeps its height
ROW_SLACK = 2


def _hann(n: int, device: torch.device, dtype: torch.dtype) -> torch.Tensor:
    return torch.hann_window(n, periodic=False, device=device, dtype=dtype)


def motion_signature(images: torch.Tensor) -> torch.Tensor:
    """Per-frame spectrum ``(N, H, W//2+1)`` complex of canonical images ``(N, 3, H, W)`` for `camera_shift`.

    Grey level, mean removed, tapered by a Hann window (so the image borders do not correlate).
    """
    if images.ndim != 4:
        raise ValueError(f"expected images (N, 3, H, W), got shape {tuple(images.shape)}")
    g = images.detach().float().mean(1)
    g = g - g.mean((-2, -1), keepdim=True)
    h, w = g.shape[-2:]
    win = _hann(h, g.device, g.dtype)[:, None] * _hann(w, g.device, g.dtype)[None, :]
    return torch.fft.rfft2(g * win)


def camera_shift(prev: torch.Tensor, cur: torch.Tensor, view: CanonicalView) -> torch.Tensor:
    """Camera motion along X (metres, ``(N,)``) from the frame of signature ``prev`` to that of ``cur``.

    The peak of the cross-correlation within +-`MAX_SHIFT` horizontally and +-`ROW_SLACK` rows,
    refined to sub-pixel precision by a parabola through the peak and its neighbours.
    """
    h, w = view.height, view.width
    corr = torch.fft.irfft2(prev * cur.conj(), s=(h, w))  # (N, H, W): corr[dy, dx] = sum prev(y+dy, x+dx) cur(y, x)
    rows = torch.cat([corr[:, : ROW_SLACK + 1], corr[:, h - ROW_SLACK :]], 1).amax(1)  # (N, W)
    m = min(int(MAX_SHIFT / view.metres_per_pixel), w // 2 - 1)
    offsets = torch.arange(-m, m + 1, device=corr.device)
    prof = rows[:, offsets % w]  # (N, 2m+1): correlation at pixel offsets -m..m
    k = prof.argmax(1)
    inner = k.clamp(1, 2 * m - 1)
    left = prof.gather(1, (inner - 1)[:, None])[:, 0]
    mid = prof.gather(1, inner[:, None])[:, 0]
    right = prof.gather(1, (inner + 1)[:, None])[:, 0]
    den = left - 2 * mid + right
    frac = torch.where(den < 0, 0.5 * (left - right) / den.clamp(max=-1e-12), torch.zeros_like(den))
    frac = torch.where(inner == k, frac.clamp(-0.5, 0.5), torch.zeros_like(frac))
    px = (k - m).to(corr.dtype) + frac
    return px * view.metres_per_pixel
