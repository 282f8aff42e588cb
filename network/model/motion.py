"""Camera motion along the rack row between consecutive frames, read from the canonical images alone.

A canonical image (`layouts.canonical.CanonicalView`) has square pixels of a fixed metric size on
the rack front plane, centred on the optical axis. When the camera moves by ``dx`` along the row
(X), everything on the front plane (uprights, board edges, box fronts) moves by ``-dx`` in the
image, and the camera's height does not change. Things behind the front plane move less (a point
``z`` metres behind it by ``d / (d + z)`` of that, the parallax), and in a warehouse they carry
most of the texture: on the held-out generated set half of the horizontal gradient lies on things
more than 1.7 m behind the front (the far wall, the next row through empty shelves) and only a
quarter within 5 % of the front plane's motion. One correlation of the whole image therefore
reads a blend of depths, short of the camera's motion (0.75 of its path over a sequence, median).

So the motion is read per horizontal band: each of `BANDS` bands of rows finds its own offset (the
peak of a normalised cross-correlation over the pixels inside the source image in both frames,
refined to sub-pixel by a parabola). The front plane is the nearest layer, so it moves most: the
estimate is the largest band motion among the bands that correlate well (`MIN_NCC`) and lie
between the whole image's motion and twice it (a blend cannot read less than half the front's
motion where the background lies within one camera distance behind; the range drops bands that
lock onto a wrong repeat of the uprights), once the bands at the bottom (top) whose motion grows
toward the image edge by more than `SHEAR` per band are peeled off: the floor (a ceiling), which
comes nearer the camera row by row. Below a pixel of motion the whole image's estimate stands.
On the 24 held-out sequences (`research/motion_estimate.py data/heldout128`) this is off by
0.4 cm per frame (median) and reads 0.996 of the camera's path (median), where one Hann-windowed
correlation of the whole image was off by 2.3 cm and read 0.75.
It needs no pose, so prediction on a user's footage uses it as training does. The slot memory
(`network.model.memory.SlotMemory`) shifts its state by it before each frame.
"""

from __future__ import annotations

import numpy as np
import torch

from layouts.canonical import CanonicalView

#: the largest motion looked for between two frames (metres)
MAX_SHIFT = 0.6
#: horizontal bands of rows, each of which reads its own motion
BANDS = 16
#: a band takes part only if its correlation peak reaches this normalised value
MIN_NCC = 0.3
#: a band at the bottom (top) that reads more than the band above (below) it by this many metres
#: lies on the floor (a ceiling), whose motion grows toward the camera: it is left out
SHEAR = 0.01


def motion_signature(images: torch.Tensor) -> torch.Tensor:
    """Per-frame grey image and validity ``(N, 2, H, W)`` (float32) of canonical images ``(N, 3, H, W)``.

    Canonical pixels outside the source image carry one fill colour (`layouts.canonical.FILL_RGB`,
    whatever colour change came after) over whole rows and columns; they are marked invalid so that
    the static edge of the source image does not pull the motion toward zero.
    """
    if images.ndim != 4:
        raise ValueError(f"expected images (N, 3, H, W), got shape {tuple(images.shape)}")
    x = images.detach().float()
    g = x.mean(1)
    spread = x.amax(1) - x.amin(1) + g  # constant over a fill row / column only
    rows = (spread.amax(2) - spread.amin(2)) > 1e-5  # (N, H)
    cols = (spread.amax(1) - spread.amin(1)) > 1e-5  # (N, W)
    valid = (rows[:, :, None] & cols[:, None, :]).float()
    return torch.stack([g * valid, valid], 1)


def fft_length(n: int) -> int:
    """The smallest length >= ``n`` with no prime factor above 5: the FFTs' fast sizes (at 256x256 the
    correlation's 308 becomes 320, ~1.4x faster in float64)."""
    best = n
    while True:
        m = best
        for p in (2, 3, 5):
            while m % p == 0:
                m //= p
        if m == 1:
            return best
        best += 1


def _band_index(h: int, bands: int, device: torch.device) -> torch.Tensor:
    """Band of every row ``(H,)``: ``bands`` bands of (nearly) equal height."""
    return (torch.arange(h, device=device) * bands) // h


def _spectra(sig: torch.Tensor, length: int) -> torch.Tensor:
    """Row spectra ``(N, 3, H, F)`` (float64, FFTs of ``length``) of a signature's validity, grey and grey squared:
    every sum over an overlap of two frames is a row-wise correlation of two such maps (sums of w, a, b, a*a, b*b,
    a*b, where w = valid in both)."""
    g, valid = sig[:, 0].double(), sig[:, 1].double()  # grey is zero where invalid already
    return torch.fft.rfft(torch.stack([valid, g, g * g], 1), n=length)


#: (previous frame's map, current frame's map) of the six sums, in `_correlate`'s order
_PREV_MAPS, _CUR_MAPS = (0, 1, 0, 2, 0, 1), (0, 0, 1, 0, 2, 1)


def _correlate(
    fp: torch.Tensor, fc: torch.Tensor, length: int, m: int, bands: int
) -> tuple[torch.Tensor, torch.Tensor]:
    """Normalised cross-correlation of two frames from their `_spectra`: the current frame against the previous
    one moved by -m..m columns, per band ``(N, bands, 2m+1)`` and for the whole image ``(N, 2m+1)``, over the
    pixels valid in both; offset k means ``cur(y, x)`` matches ``prev(y, x + k)`` (the content moved k columns
    left: the camera moved right). The six sums' products are summed per band before going back."""
    n, _, h, _ = fp.shape
    prod = fp[:, _PREV_MAPS] * fc[:, _CUR_MAPS].conj()  # (N, 6, H, F)
    if h % bands == 0:  # bands of equal height: a sum over a reshape (~3x faster than index_add_)
        per_band_f = prod.view(n, 6, bands, h // bands, -1).sum(3)
    else:
        per_band_f = prod.new_zeros(n, 6, bands, prod.shape[-1]).index_add_(2, _band_index(h, bands, fp.device), prod)
    corr = torch.fft.irfft(per_band_f, n=length)  # (N, 6, bands, length): [k] = sum_x prev(x + k) cur(x)
    offsets = torch.arange(-m, m + 1, device=fp.device) % length
    per_band = corr[..., offsets]  # (N, 6, bands, 2m+1)

    def ncc(t: torch.Tensor) -> torch.Tensor:
        num, sa, sb, saa, sbb, sab = t.unbind(1)
        cnt = num.clamp(min=1.0)
        cov = sab - sa * sb / cnt
        var = (saa - sa * sa / cnt).clamp(min=0) * (sbb - sb * sb / cnt).clamp(min=0)
        return (cov / (var.sqrt() + 1e-6 * cnt)).float()

    return ncc(per_band), ncc(per_band.sum(2))


def _peak(prof: torch.Tensor, m: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Sub-pixel offset (pixels) and height of the highest peak of profiles ``(..., 2m+1)``."""
    k = prof.argmax(-1, keepdim=True)
    inner = k.clamp(1, 2 * m - 1)
    left, mid, right = (prof.gather(-1, inner + d)[..., 0] for d in (-1, 0, 1))
    den = left - 2 * mid + right
    frac = torch.where(den < 0, 0.5 * (left - right) / den.clamp(max=-1e-12), torch.zeros_like(den))
    frac = torch.where(inner[..., 0] == k[..., 0], frac.clamp(-0.5, 0.5), torch.zeros_like(frac))
    return (k[..., 0] - m).to(prof.dtype) + frac, prof.gather(-1, k)[..., 0]


def _front(
    shifts: np.ndarray, heights: np.ndarray, whole: float, px_per_metre: float, whole_h: float = 0.0
) -> tuple[float, float]:
    """The front plane's motion (pixels) from one pair's band motions and the whole image's, and a confidence
    in [0, 1]: the mean correlation peak of the bands that read it times the share of the bands they are (the
    whole image's peak where it stands alone), low where dim, noisy or blurred frames correlate poorly and where
    fewer than four bands read close to the largest motion."""
    if abs(whole) < 1.0:
        return whole, max(0.0, whole_h)
    sign = 1.0 if whole > 0 else -1.0
    lo, hi = sorted([0.9 * whole - sign, whole / 0.5 + sign])
    idx = np.flatnonzero((heights > MIN_NCC) & (shifts >= lo) & (shifts <= hi))
    mag = np.abs(shifts)
    step = SHEAR * px_per_metre
    while len(idx) > 1 and mag[idx[-1]] > mag[idx[-2]] + step:  # the floor, from the bottom up
        idx = idx[:-1]
    while len(idx) > 1 and mag[idx[0]] > mag[idx[1]] + step:  # a ceiling, from the top down
        idx = idx[1:]
    if not len(idx):
        return whole, max(0.0, whole_h)
    best = float(mag[idx].max())
    # the share of the bands that read it: a few bands far above the rest (a floor the shear test missed) are doubtful
    near = np.count_nonzero(mag[idx] >= 0.85 * best)
    conf = float(np.mean(heights[idx])) * min(1.0, 2.0 * len(idx) / max(len(heights), 1)) * min(1.0, near / 4.0)
    return sign * best, float(np.clip(conf, 0.0, 1.0))


def camera_shift(prev: torch.Tensor, cur: torch.Tensor, view: CanonicalView) -> torch.Tensor:
    """Camera motion along X (metres, ``(N,)``) from the frame of signature ``prev`` to that of ``cur``.

    Within +-`MAX_SHIFT`; the front plane's motion as the bands read it (module docstring).
    """
    return camera_motion(prev, cur, view)[0]


def camera_motion(prev: torch.Tensor, cur: torch.Tensor, view: CanonicalView) -> tuple[torch.Tensor, torch.Tensor]:
    """`camera_shift` and its confidence ``(N,)`` in [0, 1] (the correlation peaks behind it, see `_front`):
    what a stitcher weighs the step by against the layouts' own estimate."""
    if prev.shape != cur.shape or prev.ndim != 4 or prev.shape[1] != 2:
        raise ValueError(
            f"expected two signatures (N, 2, H, W) of one shape, got {tuple(prev.shape)} and {tuple(cur.shape)}"
        )
    length, m, bands = _sizes(prev.shape[-2], prev.shape[-1], view)
    return _motion(_spectra(prev, length), _spectra(cur, length), length, m, bands, view)


class StepReader:
    """`camera_motion` along one stream of frames: call it with each frame's signature in turn; each frame's
    spectra are made once (not again as the previous frame of the next), a tenth of a 256x256 frame's work."""

    def __init__(self, view: CanonicalView) -> None:
        self.view = view
        self._prev: torch.Tensor | None = None  #: the last frame's `_spectra`

    def __call__(self, sig: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The camera's step (metres, ``(N,)``) and its confidence from the last frame given to ``sig``'s; for the
        first frame 0 and 1."""
        if sig.ndim != 4 or sig.shape[1] != 2:
            raise ValueError(f"expected a signature (N, 2, H, W), got shape {tuple(sig.shape)}")
        length, m, bands = _sizes(sig.shape[-2], sig.shape[-1], self.view)
        spectra, prev = _spectra(sig, length), self._prev
        self._prev = spectra
        if prev is None or prev.shape != spectra.shape:
            return sig.new_zeros(sig.shape[0]), sig.new_ones(sig.shape[0])
        return _motion(prev, spectra, length, m, bands, self.view)


def _sizes(h: int, w: int, view: CanonicalView) -> tuple[int, int, int]:
    """FFT length, largest offset (pixels) and bands of `camera_motion` on ``h x w`` signatures."""
    m = max(1, min(int(MAX_SHIFT / view.metres_per_pixel), w // 2 - 1))
    return fft_length(w + m + 1), m, max(1, min(BANDS, h))


def _motion(
    fp: torch.Tensor, fc: torch.Tensor, length: int, m: int, bands: int, view: CanonicalView
) -> tuple[torch.Tensor, torch.Tensor]:
    """`camera_motion` from the two frames' `_spectra`."""
    band_prof, whole_prof = _correlate(fp, fc, length, m, bands)
    whole, whole_h = (t.cpu().double().numpy() for t in _peak(whole_prof, m))
    shifts, heights = (t.cpu().double().numpy() for t in _peak(band_prof, m))
    read = [
        _front(shifts[i], heights[i], float(whole[i]), 1.0 / view.metres_per_pixel, float(whole_h[i]))
        for i in range(len(whole))
    ]
    px = torch.tensor([r[0] for r in read], dtype=torch.float32, device=fp.device)
    conf = torch.tensor([r[1] for r in read], dtype=torch.float32, device=fp.device)
    return px * view.metres_per_pixel, conf
