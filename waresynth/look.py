"""The camera's and the building's look of a frame: light level, white balance, vignetting, signal-dependent
sensor noise, tone curve, lens distortion and compression: JPEG, an H.264-like stand-in, or a real H.264 / H.265
stream (`waresynth.stream_codec`).

`draw_look` draws a sequence's look from the scene's generator after everything else, each value only from
a range that is not one value, so a neutral config (the default) draws nothing and renders the bytes it
always did; `SensorLook` applies it to each frame's linear colours (8-bit levels, before the tone curve)
and compresses the result. Per-frame draws (the noise window, the JPEG quality) come from the frame's
noise generator, so a sequence's seed fixes every byte; a streamed sequence's frames go through one encoder
in the order they are rendered.
"""

from __future__ import annotations

import io
import math
from typing import Any

import numpy as np
from PIL import Image, ImageFilter

from layouts.camera import Intrinsics
from layouts.errors import InputError
from layouts.lens import Lens
from waresynth.draws import uniform
from waresynth.stream_codec import CODECS, VideoStream

#: the colour temperature (K) the camera is balanced for: lights at it render untinted
BALANCED_K = 6500.0
#: Pillow's ``subsampling`` codes of the JPEG chroma subsampling names
SUBSAMPLING = {"4:4:4": 0, "4:2:2": 1, "4:2:0": 2}
COMPRESSIONS = ("none", "jpeg", "h264", *CODECS)
#: the new keys' values that reproduce a dataset written before they existed (`waresynth.generate` resumes)
NEUTRAL: dict[str, dict[str, Any]] = {
    "lighting": {
        "level": [1.0, 1.0],
        "falloff": [0.015, 0.015],
        "extra_lights": [0, 0],
        "extra_intensity": [0.5, 1.0],
        "colour_temperature": [BALANCED_K, BALANCED_K],
    },
    "sensor": {
        "exposure_ev": [0.0, 0.0],
        "auto_exposure": [0.0, 0.0],
        "white_balance_jitter": 0.0,
        "shot_noise": [0.0, 0.0],
        "read_noise": [0.0, 0.0],
        "gamma": [1.0, 1.0],
        "vignetting": [0.0, 0.0],
        "lens_k1": [0.0, 0.0],
        "lens_k2": [0.0, 0.0],
        "motion_blur_probability": 1.0,
        "compression": ["none"],
        "jpeg_quality": [60, 95],
        "jpeg_subsampling": ["4:2:0"],
        "h264_quality": [25, 50],
        "h264_blur": [0.5, 0.5],
        "stream_mbps": [1.0, 8.0],
    },
}


def _pick(rng: np.random.Generator, items: list[str]) -> str:
    return items[int(rng.integers(len(items)))] if len(items) > 1 else items[0]


def draw_motion_blur(rng: np.random.Generator, sensor: dict[str, Any]) -> float:
    """A sequence's motion-blur share of the camera's step: drawn only from a range that is not one value, and
    the chance of any blur drawn only below a probability of 1 (so a sharp config draws nothing)."""
    p = sensor["motion_blur_probability"]
    blurred = p >= 1.0 or rng.random() < p
    return uniform(rng, sensor["motion_blur"]) if blurred else 0.0


def temperature_gains(kelvin: float) -> tuple[float, float, float]:
    """Channel gains of light at ``kelvin`` seen by a camera balanced for `BALANCED_K` (a blackbody's sRGB
    colour, Tanner Helland's fit, over the balanced one's; mean 1 so the level stays)."""

    def rgb(k: float) -> np.ndarray:
        t = k / 100.0
        r = 255.0 if t <= 66 else 329.698727446 * (t - 60) ** -0.1332047592
        g = 99.4708025861 * math.log(t) - 161.1195681661 if t <= 66 else 288.1221695283 * (t - 60) ** -0.0755148492
        b = 255.0 if t >= 66 else (0.0 if t <= 19 else 138.5177312231 * math.log(t - 10) - 305.0447927307)
        return np.clip([r, g, b], 1.0, 255.0)

    gains = rgb(kelvin) / rgb(BALANCED_K)
    gains /= gains.mean()
    return (float(gains[0]), float(gains[1]), float(gains[2]))


def _check_lens(lens: Lens, intr: Intrinsics) -> None:
    """Refuse a drawn lens that folds the image over before its corners (the radius stops growing)."""
    r2 = ((intr.width / 2) / intr.fx) ** 2 + ((intr.height / 2) / intr.fy) ** 2
    for s in np.linspace(0.0, 1.0, 33) * r2:
        if 1.0 + 3.0 * lens.k1 * s + 5.0 * lens.k2 * s * s <= 0.05:
            raise InputError(
                f"config: sensor.lens_k1 = {lens.k1:.3f}, lens_k2 = {lens.k2:.3f} fold the image over inside its "
                f"corners at this field of view; narrow the ranges"
            )


def draw_look(rng: np.random.Generator, cfg: dict[str, Any], intr: Intrinsics, xs: np.ndarray) -> dict[str, Any]:
    """A sequence's look: only what differs from the neutral look (an empty dict for a neutral config).

    ``xs``: the camera path's X (extra lights hang along it). Draws from ``rng`` in a fixed order.
    """
    lc, sc = cfg["lighting"], cfg["sensor"]
    look: dict[str, Any] = {
        "level": uniform(rng, lc["level"]),
        "falloff": uniform(rng, lc["falloff"]),
        "temperature": uniform(rng, lc["colour_temperature"]),
        "ev": uniform(rng, sc["exposure_ev"]),
        "auto_exposure": uniform(rng, sc["auto_exposure"]),
    }
    lights = []
    n_extra = int(rng.integers(int(lc["extra_lights"][0]), int(lc["extra_lights"][1]) + 1))
    if n_extra:
        x0, x1 = float(xs.min()) - 3.0, float(xs.max()) + 3.0
        for k in range(n_extra):
            x = x0 + (x1 - x0) * (k + rng.uniform(0.2, 0.8)) / n_extra
            y, z = -uniform(rng, lc["light_height"]), -uniform(rng, lc["light_offset_z"])
            lights.append({"position": [x, y, z], "intensity": uniform(rng, lc["extra_intensity"])})
    look["extra_lights"] = lights
    j = float(sc["white_balance_jitter"])
    wb = np.asarray(temperature_gains(look["temperature"]), np.float64)
    if j > 0:
        wb = wb * (1.0 + rng.uniform(-j, j, 3))
    look["white_balance"] = [float(g) for g in wb]
    for key in ("shot_noise", "read_noise", "gamma", "vignetting", "lens_k1", "lens_k2"):
        look[key] = uniform(rng, sc[key])
    look["compression"] = _pick(rng, sc["compression"])
    if look["compression"] == "jpeg":
        look["jpeg_subsampling"] = _pick(rng, sc["jpeg_subsampling"])
        look["quality"] = [int(q) for q in sc["jpeg_quality"]]
    elif look["compression"] == "h264":
        look["h264_blur"] = uniform(rng, sc["h264_blur"])
        look["quality"] = [int(q) for q in sc["h264_quality"]]
    elif look["compression"] in CODECS:
        look["stream_mbps"] = uniform(rng, sc["stream_mbps"])
    if look["lens_k1"] or look["lens_k2"]:
        _check_lens(Lens(k1=look["lens_k1"], k2=look["lens_k2"]), intr)
    return _active(look)


_NEUTRAL = {
    "level": 1.0, "falloff": 0.015, "temperature": BALANCED_K, "ev": 0.0, "auto_exposure": 0.0, "extra_lights": [],
    "white_balance": [1.0, 1.0, 1.0], "shot_noise": 0.0, "read_noise": 0.0, "gamma": 1.0, "vignetting": 0.0,
    "lens_k1": 0.0, "lens_k2": 0.0, "compression": "none",
}  # fmt: skip


def _active(look: dict[str, Any]) -> dict[str, Any]:
    """``look`` without its neutral entries (so a neutral look is ``{}``)."""
    return {k: v for k, v in look.items() if k not in _NEUTRAL or v != _NEUTRAL[k]}


def lens_of(look: dict[str, Any]) -> Lens | None:
    """The sequence's lens (None: a pinhole)."""
    if not (look.get("lens_k1") or look.get("lens_k2")):
        return None
    return Lens(k1=look.get("lens_k1", 0.0), k2=look.get("lens_k2", 0.0))


def amplification(look: dict[str, Any]) -> tuple[float, float]:
    """(light, camera): what multiplies the rendered radiance in the building (the light level) and in the
    camera (exposure in stops and auto-exposure, which raises the gain by level^-auto_exposure)."""
    level = float(look.get("level", 1.0))
    camera = 2.0 ** float(look.get("ev", 0.0)) * level ** -float(look.get("auto_exposure", 0.0))
    return level, camera


class SensorLook:
    """The per-frame look of one renderer (image size and the sequence's look fixed)."""

    def __init__(self, look: dict[str, Any], intr: Intrinsics, gain: float, seed: int):
        self.look = look
        self.w, self.h = intr.width, intr.height
        wb = np.asarray(look.get("white_balance", [1.0, 1.0, 1.0]), np.float32)
        vig = float(look.get("vignetting", 0.0))
        if vig > 0:
            u, v = np.meshgrid(np.arange(self.w) + 0.5 - intr.cx, np.arange(self.h) + 0.5 - intr.cy)
            r2 = (u / intr.fx) ** 2 + (v / intr.fy) ** 2
            factor = (1.0 - vig * r2 / r2.max()).astype(np.float32).reshape(-1)
        else:
            factor = np.ones(self.w * self.h, np.float32)
        #: per channel, the linear factor of each pixel (white balance x vignetting), or None when all 1
        self.factors = None if vig == 0 and (wb == 1).all() else [factor * wb[k] for k in range(3)]
        #: the camera's total gain (the noise grows with it: var = g k s + (g r)^2)
        self.gain = float(gain) * amplification(look)[1]
        self.shot = float(look.get("shot_noise", 0.0))
        self.read = float(look.get("read_noise", 0.0))
        self.gamma = float(look.get("gamma", 1.0))
        self._stream: VideoStream | None = None  #: a streamed sequence's codec, made at its first frame
        n = 3 * self.w * self.h
        self._unit = None
        if self.shot > 0 or self.read > 0:
            self._unit = np.random.default_rng([seed, 1]).standard_normal(n + 65536, dtype=np.float32)

    def linear(self, cols: list[np.ndarray], rng: np.random.Generator) -> None:
        """White balance, vignetting, shot + read noise and the tone curve on the colour channels (in place;
        8-bit levels with the renderer's +0.5 rounding offset, kept)."""
        half = np.float32(0.5)
        n_px = self.w * self.h
        unit = None
        if self._unit is not None:
            off = int(rng.integers(65536))
            unit = self._unit[off : off + 3 * n_px]
        for k, c in enumerate(cols):
            c -= half
            if self.factors is not None:
                c *= self.factors[k]
            if unit is not None:
                np.maximum(c, 0.0, out=c)
                var = c * np.float32(self.gain * self.shot) + np.float32((self.gain * self.read) ** 2)
                c += np.sqrt(var) * unit[k * n_px : (k + 1) * n_px]
            if self.gamma != 1.0:
                np.clip(c, 0.0, None, out=c)
                c *= np.float32(1.0 / 255.0)
                np.power(c, np.float32(1.0 / self.gamma), out=c)
                c *= np.float32(255.0)
            c += half

    def compress(self, rgb: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """The frame through the sequence's codec: JPEG at a quality drawn per frame, the H.264-like
        stand-in (a slight Gaussian blur, then JPEG with 4:2:0 chroma at the lower ``h264_quality``), or the
        next frame of an H.264 / H.265 stream at the sequence's ``stream_mbps`` (frames in the order sent)."""
        kind = self.look.get("compression", "none")
        if kind == "none":
            return rgb
        if kind in CODECS:
            if self._stream is None:
                self._stream = VideoStream(kind, self.w, self.h, float(self.look["stream_mbps"]))
            return self._stream.send(rgb)
        img = Image.fromarray(rgb)
        if kind == "jpeg":
            sub = SUBSAMPLING[self.look["jpeg_subsampling"]]
        else:
            sub = SUBSAMPLING["4:2:0"]
            if self.look["h264_blur"] > 0:
                img = img.filter(ImageFilter.GaussianBlur(self.look["h264_blur"]))
        q = self.look["quality"]
        quality = int(rng.integers(q[0], q[1] + 1))
        buf = io.BytesIO()
        img.save(buf, "JPEG", quality=quality, subsampling=sub)
        buf.seek(0)
        with Image.open(buf) as dec:
            return np.asarray(dec.convert("RGB"))
