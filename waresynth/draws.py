"""The generator's draws from a range, a palette or a list: one definition each, so that every sampler draws
the same numbers from the same generator (a sequence seed fixes its scene, byte for byte)."""

from __future__ import annotations

import numpy as np


def uniform(rng: np.random.Generator, r: list[float]) -> float:
    """A float from ``[low, high]``; a range of one value draws nothing."""
    return float(rng.uniform(r[0], r[1])) if r[1] > r[0] else float(r[0])


def integer(rng: np.random.Generator, r: list[int]) -> int:
    """An integer from ``[low, high]``, both included."""
    return int(rng.integers(int(r[0]), int(r[1]) + 1))


def colour(rng: np.random.Generator, palette: list[list[float]], jitter: float) -> tuple[float, float, float]:
    """A palette colour (0-255) as 0-1 RGB, each channel jittered by up to ``jitter`` of itself."""
    base = np.asarray(palette[int(rng.integers(len(palette)))], np.float64) / 255.0
    c = np.clip(base * (1.0 + rng.uniform(-jitter, jitter, 3)), 0.0, 1.0)
    return (float(c[0]), float(c[1]), float(c[2]))


def choice(rng: np.random.Generator, items: list[str]) -> str:
    """One of ``items``."""
    return items[int(rng.integers(len(items)))]
