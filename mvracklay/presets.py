"""``--quality`` presets of `mvracklay run` and `mvracklay.reconstruct`: the settings each sets, by field name of
`mvracklay.settings.RunConfig` and `InferenceSettings` (`preset_fields`), and as parser defaults under a
``--config`` file and the command line (`preset_defaults`).

default: today's online settings (streaming; the depths read from the frames so far); offline: every frame's
depths, test-time flip and neighbouring frames fused (layouts once the whole input is read, about half the
frame rate); fast: the decoder's own depths (no back-edge / box-depth reading, ~1.3x the frame rate measured
at 256x256), the recording without RGB and its map every 10th frame.
"""

from __future__ import annotations

from dataclasses import fields
from typing import Any

from layouts.errors import InputError
from mvracklay.options import FUSE_TAU

#: preset -> the settings it sets, by field name
PRESETS: dict[str, dict[str, object]] = {
    "fast": {"read_depth": False, "rgb": False, "map_every": 10},
    "default": {},
    "offline": {"whole_sequence": True, "flip": True, "fuse_tau": FUSE_TAU},
}


def preset_fields(quality: str) -> dict[str, Any]:
    """The ``quality`` preset's settings as field names (`RunConfig` and `mvracklay.settings.InferenceSettings`)."""
    if quality not in PRESETS:
        raise InputError(f"quality must be one of {', '.join(PRESETS)}, got {quality!r}")
    return dict(PRESETS[quality])


def preset_defaults(quality: str) -> dict[str, Any]:
    """The ``quality`` preset as parser defaults (``{dest: value}``; a switch that turns a field off set to
    ``not value``), read from the fields' option declarations."""
    from mvracklay.settings import InferenceSettings, RunConfig, dest

    declared = {f.name: f for cls in (RunConfig, InferenceSettings) for f in fields(cls) if dest(f) is not None}
    out = {}
    for name, value in preset_fields(quality).items():
        f = declared[name]
        out[dest(f)] = not value if f.metadata["invert"] else value
    return out
