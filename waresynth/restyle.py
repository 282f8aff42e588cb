"""A look drawn from a config, applied to a default-look frame in image space (`restyle`).

A default-look render is the renderer's shaded 8-bit levels at light level 1, balanced light, no tone
curve and a little Gaussian noise. `Restyler` draws a look as the generator does (`waresynth.look.draw_look`
over the config's ranges) and applies what the camera and the light do to those levels: the light level
times an uneven field (the falloff and the extra lights as a smooth gain over the image), the exposure and
auto-exposure, motion blur along the row, white balance, vignetting, shot + read noise and the tone curve
(`SensorLook.linear`), the Gaussian noise and the codec (`SensorLook.compress`). Given the frame's label
images, each object (a semantic class and instance) is also recoloured: its levels times a gain per channel
(a surface of another colour under the same light; `RECOLOUR_BRIGHTNESS` x `RECOLOUR_TINT` span what
wide_look's palettes add to the default ones). The scene's geometry stays pixel for pixel the same, so a
network's features on the copy can be held to its own on the original (`network.training.fit_look`). What
image space cannot change (shadows, textures, the lens) comes from rendering with the config itself.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy.ndimage import correlate1d

from layouts.camera import Intrinsics
from layouts.errors import InputError
from waresynth.config import load_config
from waresynth.draws import uniform
from waresynth.look import NEUTRAL, SensorLook, amplification, draw_look, draw_motion_blur

#: the uneven field's blobs: their width (a share of the image width) and the most of them
BLOB_WIDTH = (0.15, 0.45)
MAX_BLOBS = 4
#: an object's recolouring: one brightness factor and a factor per channel, each log-uniform over its range
RECOLOUR_BRIGHTNESS = (0.4, 1.6)
RECOLOUR_TINT = (0.6, 1.6)
#: the share of drawn looks that recolour the objects (given the labels)
RECOLOUR_PROBABILITY = 0.7
#: the falloff a default-look frame was rendered with (only more than it tilts the field)
NEUTRAL_FALLOFF = NEUTRAL["lighting"]["falloff"][0]


def light_field(rng: np.random.Generator, h: int, w: int, falloff: float, lights: int, strength: float) -> np.ndarray:
    """A smooth gain ``(H, W)`` with mean 1: a tilt that grows with ``falloff`` beyond the default render's
    (light from one side) plus ``lights`` bright blobs of relative ``strength`` (extra lights along the aisle)."""
    v, u = np.mgrid[0:h, 0:w].astype(np.float32)
    u, v = u / w - 0.5, v / h - 0.5
    angle = rng.uniform(0, 2 * np.pi)
    tilt = np.float32(min(8.0 * max(falloff - NEUTRAL_FALLOFF, 0.0), 0.9))
    field = 1.0 + tilt * (np.cos(angle) * u + np.sin(angle) * v) * 2.0
    for _ in range(min(lights, MAX_BLOBS)):
        cu, cv = rng.uniform(-0.5, 0.5), rng.uniform(-0.6, 0.2)
        s = uniform(rng, list(BLOB_WIDTH))
        field = field + strength * np.exp(-((u - cu) ** 2 + (v - cv) ** 2) / (2 * s * s))
    field = np.clip(field, 0.05, None)
    return (field / field.mean()).astype(np.float32)


def box_blur_rows(cols: list[np.ndarray], h: int, w: int, length: float) -> None:
    """Average each channel (``(H*W,)`` float32, in place) over ``length`` pixels along the rows (the camera
    moving along X during the exposure); fractional lengths weight the two end taps."""
    if length <= 1.0:
        return
    n = int(np.ceil(length))
    taps = np.ones(n, np.float32)
    if n > length and n >= 2:  # the two end taps share what the length lacks of n
        taps[0] = taps[-1] = (length - n + 2) / 2
    taps /= taps.sum()
    for k, c in enumerate(cols):
        cols[k] = correlate1d(c.reshape(h, w), taps, axis=1, mode="nearest").reshape(-1)


def _log_u(rng: np.random.Generator, r: tuple[float, float], n: int | None = None) -> np.ndarray:
    return np.exp(rng.uniform(np.log(r[0]), np.log(r[1]), n))


def recolour_gains(semantic: np.ndarray, instance: np.ndarray, seed: int) -> np.ndarray:
    """Per pixel ``(H*W, 3)`` float32 gains: one colour factor per object (semantic class x instance id),
    drawn from ``seed`` and the object's key (an object keeps its colour across frames)."""
    sem = np.asarray(semantic, np.int64).reshape(-1)
    inst = np.asarray(instance, np.int64).reshape(-1)
    keys, inverse = np.unique(inst * 16 + sem, return_inverse=True)
    gains = np.empty((len(keys), 3), np.float32)
    for j, k in enumerate(keys):
        rng = np.random.default_rng([seed, int(k)])
        gains[j] = _log_u(rng, RECOLOUR_BRIGHTNESS) * _log_u(rng, RECOLOUR_TINT, 3)
    return gains[inverse.reshape(-1)]


class Restyler:
    """Looks drawn from ``config`` (a dict, a file or a shipped config's name; `load_config`) applied to
    default-look frames."""

    def __init__(self, config: str | Any = "wide_look") -> None:
        self.cfg = load_config(config)
        self.sensor = self.cfg["sensor"]

    def draw(self, rng: np.random.Generator, intr: Intrinsics) -> dict[str, Any]:
        """One look (`draw_look`'s, the lens left out: it moves pixels) with the sensor's gain, noise and
        motion-blur share (of the camera's step) drawn too."""
        look = draw_look(rng, self.cfg, intr, np.zeros(1))
        look.pop("lens_k1", None)
        look.pop("lens_k2", None)
        sc = self.sensor
        extra = look.get("extra_lights", [])
        return {
            "look": look,
            "gain": uniform(rng, sc["gain"]),
            "noise_sigma": uniform(rng, sc["noise_sigma"]),
            "motion_blur": draw_motion_blur(rng, sc),
            "lights": len(extra),
            "light_strength": float(np.mean([e["intensity"] for e in extra])) if extra else 0.0,
            "recolour": bool(rng.random() < RECOLOUR_PROBABILITY),
            "seed": int(rng.integers(2**31)),
        }

    def apply(
        self,
        rgb: np.ndarray,
        drawn: dict[str, Any],
        intr: Intrinsics,
        step_px: float = 0.0,
        labels: tuple[np.ndarray, np.ndarray] | None = None,
    ) -> np.ndarray:
        """``rgb`` (uint8 ``(H, W, 3)``, a default-look frame) in the look ``drawn`` (`draw`); ``step_px``: the
        camera's step between frames in pixels at the racks (the motion blur is its ``motion_blur`` share);
        ``labels``: the frame's semantic and instance images, to recolour its objects (`recolour_gains`)."""
        rgb = np.asarray(rgb)
        if rgb.dtype != np.uint8 or rgb.ndim != 3 or rgb.shape[2] != 3:
            raise InputError(f"restyle: expected a uint8 (H, W, 3) frame, got {rgb.dtype} {rgb.shape}")
        h, w = rgb.shape[:2]
        if (intr.width, intr.height) != (w, h):
            intr = intr.scaled(w, h)
        look = drawn["look"]
        rng = np.random.default_rng(drawn["seed"])
        level, camera = amplification(look)
        field = light_field(
            rng, h, w, float(look.get("falloff", NEUTRAL_FALLOFF)), drawn["lights"], drawn["light_strength"]
        )
        scale = (np.float32(level * camera * drawn["gain"]) * field).reshape(-1)
        if labels is not None and drawn.get("recolour"):
            if labels[0].shape != (h, w) or labels[1].shape != (h, w):
                raise InputError(f"restyle: labels of shape {labels[0].shape} do not fit a {w}x{h} frame")
            per = recolour_gains(labels[0], labels[1], drawn["seed"])
            scales = [scale * per[:, k] for k in range(3)]
        else:
            scales = [scale] * 3
        cols = [
            np.ascontiguousarray(rgb[..., k], np.float32).reshape(-1) * scales[k] + np.float32(0.5) for k in range(3)
        ]
        box_blur_rows(cols, h, w, drawn["motion_blur"] * abs(step_px))
        sensor = SensorLook(look, intr, drawn["gain"], drawn["seed"])
        sensor.linear(cols, rng)
        sigma = np.float32(drawn["noise_sigma"])
        out = np.empty((h, w, 3), np.uint8)
        for k, c in enumerate(cols):
            if sigma > 0:
                c = c + sigma * rng.standard_normal(c.shape, dtype=np.float32)
            out[..., k] = np.clip(c, 0, 255).reshape(h, w)
        return sensor.compress(out, rng)
