"""``--quality`` presets of `mvracklay run` and `mvracklay.reconstruct`: the settings each sets, by option name
(under a ``--config`` file and the command line), and as `mvracklay.pipeline.RunConfig` fields (`preset_fields`).

default: today's online settings (streaming; the depths read from the frames so far); offline: every frame's
depths, test-time flip and neighbouring frames fused (layouts once the whole input is read, about half the
frame rate); fast: the decoder's own depths (no back-edge / box-depth reading, ~1.3x the frame rate measured
at 256x256), the recording without RGB and its map every 10th frame.
"""

from __future__ import annotations

from typing import Any

from layouts.errors import InputError
from mvracklay.options import FUSE_TAU

#: preset -> the options it sets, by their argparse names (``no_depth_read``: ``--no-depth-read``)
PRESETS: dict[str, dict[str, object]] = {
    "fast": {"no_depth_read": True, "no_rgb": True, "map_every": 10},
    "default": {},
    "offline": {"whole_sequence": True, "flip_average": True, "fuse_frames": FUSE_TAU},
}
#: an option's argparse name -> the settings field it sets, where they differ (a ``no_`` switch turns it off)
FIELDS = {"flip_average": "flip", "fuse_frames": "fuse_tau", "no_depth_read": "read_depth"}


def preset_fields(quality: str) -> dict[str, Any]:
    """The ``quality`` preset's settings as field names (`RunConfig` and `mvracklay.settings.InferenceSettings`)."""
    if quality not in PRESETS:
        raise InputError(f"quality must be one of {', '.join(PRESETS)}, got {quality!r}")
    out: dict[str, Any] = {}
    for k, v in PRESETS[quality].items():
        if k.startswith("no_"):
            out[FIELDS.get(k, k[3:])] = not v
        else:
            out[FIELDS.get(k, k)] = v
    return out
