"""Procedural textures of the renderer: albedo at ray hits from the material's pattern and the hit point.

Patterns (`waresynth.scene.PATTERNS`): plain, noise, tape, label, perforated, tiles, bricks, panels,
wood, wrap (stretch film: sheen bands, washed-out colour), printed (a carton's printed band and logo in a
second colour), stained (blotches of wear and dirt), lines (a floor's painted aisle lines), each a function of the hit point in the world or in its part's own frame, on top of a 2 cm
grain everywhere. The noise lattices are constants (fixed seeds), so textures never depend on the run.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from waresynth.scene import PATTERNS

#: Fixed value-noise lattice (64^3) for textures: a constant, so textures never depend on the run.
_NOISE = np.random.default_rng(20240607).random(64**3, dtype=np.float32)
_NOISE_SHIFT = 1 << 20  # keeps lattice coordinates positive before the integer cast
#: colours of a printed carton's band and logo (by part index)
_PRINT = np.array(
    [[0.8, 0.1, 0.1], [0.1, 0.25, 0.6], [0.1, 0.45, 0.2], [0.15, 0.15, 0.15], [0.9, 0.6, 0.05], [0.95, 0.95, 0.95]],
    np.float32,
)
_GRAIN = np.float32(0.94) + np.float32(0.06) * np.random.default_rng(20240608).random(256 * 256, dtype=np.float32)


def value_noise(x: np.ndarray, y: np.ndarray, z: np.ndarray, freq: float) -> np.ndarray:
    """Blocky value noise in [0, 1) on a lattice of 1/freq metres."""
    ix = (x * np.float32(freq) + _NOISE_SHIFT).astype(np.int32) & 63
    iy = (y * np.float32(freq) + _NOISE_SHIFT).astype(np.int32) & 63
    iz = (z * np.float32(freq) + _NOISE_SHIFT).astype(np.int32) & 63
    return _NOISE[(ix << 12) | (iy << 6) | iz]


@dataclass
class SurfaceTables:
    """What the textures look up: per triangle (one extra last entry for "no hit") and per part."""

    pattern: np.ndarray  #: (T+1,) int8 pattern id per triangle
    part: np.ndarray  #: (T+1,) part index per triangle
    colour: list[np.ndarray]  #: 3 x (T+1,) float32 material colour per triangle
    normal_z: np.ndarray  #: (T+1,) float32 Z of the outward face normal per triangle
    center: np.ndarray  #: (P, 3) float32 part centres
    size: np.ndarray  #: (P, 3) float32 part sizes (width, height, depth)
    scale: np.ndarray  #: (P,) float32 material pattern scale, metres
    cos: np.ndarray  #: (P,) float32 cos(yaw)
    sin: np.ndarray  #: (P,) float32 sin(yaw)


def albedo(tab: SurfaceTables, prim: np.ndarray, px: np.ndarray, py: np.ndarray, pz: np.ndarray) -> list[np.ndarray]:
    """Albedo channels (3 x (N,)) at the hit points ``(px, py, pz)`` of triangles ``prim``, textured."""
    pat = np.take(tab.pattern, prim)
    present = np.bincount(pat, minlength=len(PATTERNS))
    # Fine grain everywhere: 2 cm value noise on (x + z, y), pre-scaled to a factor 0.94..1.
    gi = ((px + pz) * np.float32(50.0) + _NOISE_SHIFT).astype(np.int32) & 255
    gj = (py * np.float32(50.0) + _NOISE_SHIFT).astype(np.int32) & 255
    f = np.take(_GRAIN, (gi << 8) | gj)

    def where(name):
        return np.flatnonzero(pat == PATTERNS[name]) if present[PATTERNS[name]] else np.zeros(0, np.intp)

    def local(m):
        part = tab.part[prim[m]]
        qx, qz = px[m] - tab.center[part, 0], pz[m] - tab.center[part, 2]
        c, s = tab.cos[part], tab.sin[part]
        return part, c * qx + s * qz, py[m] - tab.center[part, 1], -s * qx + c * qz

    m = where("noise")
    if len(m):
        f[m] *= np.float32(0.82) + np.float32(0.18) * value_noise(px[m], py[m], pz[m], 8.0)
    m = where("tape")
    if len(m):
        part, lx, _, _ = local(m)
        f[m] *= np.where(np.abs(lx) < 0.04 + 0.02 * tab.size[part, 0], np.float32(1.18), np.float32(1.0))
    m = where("perforated")
    if len(m):
        part, lx, ly, _ = local(m)
        nz = np.abs(tab.normal_z[prim[m]])
        holes = ((ly * 20.0) % 1.0 < 0.35) & (np.abs(lx) < tab.size[part, 0] * 0.25) & (nz > 0.5)
        f[m] *= np.where(holes, np.float32(0.35), np.float32(1.0))
    m = where("wood")
    if len(m):
        part, _, _, lz = local(m)
        grain = value_noise(lz, np.zeros_like(lz), part.astype(np.float32), 6.0)
        f[m] *= (0.85 + 0.15 * np.sin(lz * 45.0 + 3.0 * grain)).astype(np.float32)
    m = where("tiles")
    if len(m):
        t = tab.scale[tab.part[prim[m]]]
        gx, gz = px[m] / t, pz[m] / t
        line = (np.abs(gx - np.round(gx)) * t < 0.012) | (np.abs(gz - np.round(gz)) * t < 0.012)
        tile = value_noise(np.floor(gx), np.floor(gz), np.zeros_like(gx), 1.0)
        f[m] *= np.where(line, np.float32(0.55), np.float32(0.88) + np.float32(0.12) * tile)
    m = where("bricks")
    if len(m):
        bl = 0.25 * tab.scale[tab.part[prim[m]]]
        rowf = -py[m] / (bl * 0.4)
        row = np.floor(rowf)
        bx = px[m] / bl + 0.5 * (row % 2)
        mortar = (rowf % 1.0 < 0.12) | (bx % 1.0 < 0.05)
        brick = value_noise(np.floor(bx), row, np.ones_like(bx), 1.0)
        f[m] *= np.where(mortar, np.float32(1.12), np.float32(0.8) + np.float32(0.2) * brick)
    m = where("panels")
    if len(m):
        q = px[m] / tab.scale[tab.part[prim[m]]]
        f[m] *= (np.where(q % 1.0 < 0.02, 0.6, 1.0) * (0.92 + 0.08 * np.cos(q * 2 * np.pi * 8))).astype(np.float32)
    m = where("stained")
    if len(m):
        blot = value_noise(px[m], py[m], pz[m], 1.3) * value_noise(px[m] + 0.37, py[m], pz[m], 3.1)
        f[m] *= np.float32(0.62) + np.float32(0.38) * np.sqrt(1.0 - blot).astype(np.float32)
    m = where("wrap")
    if len(m):
        part, lx, ly, _ = local(m)
        band = np.cos((ly * 9.0 + lx * 3.0) + 6.0 * value_noise(lx, ly, part.astype(np.float32), 4.0))
        f[m] *= (np.float32(0.92) + np.float32(0.18) * band).astype(np.float32)
    cols = [np.take(tab, prim) * f for tab in tab.colour]
    _overlays(tab, prim, px, py, pz, cols, where, local)
    return cols


def _overlays(tab: SurfaceTables, prim, px, py, pz, cols: list[np.ndarray], where, local) -> None:
    """Patterns that replace the colour (film, printing, paint, labels) on the albedo channels, in place."""
    m = where("wrap")
    if len(m):  # film washes the colour toward a grey-white sheen
        for ch in cols:
            ch[m] = ch[m] * np.float32(0.65) + np.float32(0.3)
    m = where("printed")
    if len(m):
        part, lx, ly, _ = local(m)
        w, hh = tab.size[part, 0], tab.size[part, 1]
        side = np.abs(tab.normal_z[prim[m]]) > 0.5
        band = side & (ly < -hh * 0.18) & (ly > -hh * 0.36)
        logo = side & (np.abs(lx + w * 0.22) < w * 0.12) & (np.abs(ly - hh * 0.12) < hh * 0.14)
        ink = _PRINT[part % len(_PRINT)]
        for k, ch in enumerate(cols):
            ch[m] = np.where(band | logo, ink[:, k] * (ch[m] * 0.25 + 0.75), ch[m]).astype(np.float32)
    m = where("lines")
    if len(m):  # a solid line along the rack front and a dashed one across the aisle, in safety yellow
        solid = np.abs(pz[m] + np.float32(0.35)) < 0.05
        dashed = (np.abs(pz[m] + np.float32(1.9)) < 0.04) & ((px[m] * 1.5) % 1.0 < 0.6)
        paint = solid | dashed
        for ch, v in zip(cols, (0.85, 0.7, 0.1)):
            ch[m] = np.where(paint, np.float32(v), ch[m]).astype(np.float32)
    m = where("label")
    if len(m):
        part, lx, ly, _ = local(m)
        w, hh = tab.size[part, 0], tab.size[part, 1]
        front = tab.normal_z[prim[m]] < -0.5
        lab = front & (np.abs(lx) < w * 0.2) & (np.abs(ly + hh * 0.1) < hh * 0.15)
        bars = lab & ((lx * 150.0) % 1.0 < 0.5) & (ly > -hh * 0.05)
        for ch in cols:
            ch[m] = np.where(lab, np.where(bars, 0.1, 0.93), ch[m]).astype(np.float32)
