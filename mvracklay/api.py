"""The Python API: frames in memory -> `WarehouseMap`, the same job as ``mvracklay run``.

>>> import mvracklay
>>> wmap = mvracklay.reconstruct(frames, distance=2.5)          # doctest: +SKIP
>>> for row in mvracklay.free_space(wmap): print(row.to_dict()) # doctest: +SKIP

Errors: every bad argument raises `layouts.errors.InputError` (a `ValueError`) with one line naming it:
``frames`` not an iterable of uint8 ``(H, W, 3)`` arrays of one size, or empty; ``camera`` with a principal
point outside the image or another aspect ratio; ``distance`` / ``camera_height`` not positive; an unknown
``quality`` or ``checkpoint``; an ``out`` that is a file or holds other files.
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Iterable
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from layouts import Intrinsics
from layouts.errors import InputError
from stitching.warehouse_map import WarehouseMap


def _intrinsics(camera: Any) -> Intrinsics | None:
    """``camera``: None (the default 60 deg camera), `Intrinsics`, a dict of its fields, or a camera JSON file."""
    if camera is None or isinstance(camera, Intrinsics):
        return camera
    if isinstance(camera, dict):
        w, h = camera.get("width"), camera.get("height")
        if w is None or h is None:
            raise InputError("camera: a dict needs width and height beside fx, fy, cx, cy")
        return Intrinsics.from_dict(camera, "camera")
    if isinstance(camera, (str, os.PathLike)):
        return None  # a file: read by the pipeline as --camera
    raise InputError(f"camera: want Intrinsics, a dict or a JSON file path, got {type(camera).__name__}")


def reconstruct(
    frames: Iterable[np.ndarray],
    camera: Intrinsics | dict | str | os.PathLike | None = None,
    distance: float | None = None,
    camera_height: float | None = None,
    checkpoint: str | os.PathLike | None = None,
    quality: str = "default",
    out: str | os.PathLike | None = None,
    progress: bool = False,
    **options: Any,
) -> WarehouseMap:
    """Reconstruct the rack row a camera filmed from ``frames`` (uint8 RGB ``(H, W, 3)`` arrays in order,
    streamed once: a generator of video frames holds one at a time).

    ``camera``: intrinsics (default: 60 deg horizontal field of view, centred); ``distance``: camera to
    rack front in metres (default: read from the first frames; ``camera_height`` above the floor: from the
    floor line); ``quality``: ``fast`` / ``default`` / ``offline`` as ``mvracklay run --quality``;
    ``options``: any other `mvracklay.pipeline.RunConfig` field or `mvracklay.settings.InferenceSettings` field
    (e.g. ``threads=1``, ``rack_depth=1.0``).
    ``out``: also keep the run's files there (layouts, warehouse.json/.glb/.rrd; default: none kept).
    The map's ``meta`` records the distance used and its source, the camera and the model.
    """
    from mvracklay.argtypes import check_call

    check_call(reconstruct, locals())  # each argument's type: one InputError line, not a TypeError further on
    from mvracklay.frames import array_source
    from mvracklay.pipeline import RunConfig, run_pipeline
    from mvracklay.presets import preset_fields

    cfg = RunConfig.build(
        checkpoint=Path(checkpoint) if checkpoint is not None else None,
        camera=Path(camera) if isinstance(camera, (str, os.PathLike)) else None,
        distance=distance,
        camera_height=camera_height,
        progress=progress,
        **{**preset_fields(quality), **options},
    )
    cfg.validate()
    source = array_source(frames, _intrinsics(camera))
    if out is not None:
        from mvracklay.outputs import check_out

        check_out(Path(out), overwrite=False)
        return run_pipeline(source, out, cfg).map
    with tempfile.TemporaryDirectory(prefix="mvracklay-") as tmp:
        return run_pipeline(source, Path(tmp) / "run", replace(cfg, rrd=False)).map
