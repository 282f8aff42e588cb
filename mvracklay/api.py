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


def reconstruct_live(
    frames: Iterable[np.ndarray] | str,
    camera: Intrinsics | dict | str | os.PathLike | None = None,
    distance: float | None = None,
    camera_height: float | None = None,
    checkpoint: str | os.PathLike | None = None,
    quality: str = "default",
    out: str | os.PathLike | None = None,
    on_update: Any = None,
    idle_timeout: float = 5.0,
    buffer: int = 2,
    every: int | str = 1,
    **options: Any,
) -> Any:
    """Map frames as they arrive, as ``mvracklay run`` maps a camera or a stream: ``frames`` an iterator yielding
    uint8 RGB ``(H, W, 3)`` arrays as they come (read by a thread into a buffer of ``buffer`` frames: when the network
    falls behind the oldest waiting is dropped and counted), or a stream URL / camera (``"rtsp://..."``, ``"0"``).

    ``on_update(update)`` is called with each frame as it lands in the map (`mvracklay.live.MapUpdate`: its index,
    seconds from received to mapped, the map so far); `live_updates` gives the same as a generator. The run ends when
    the iterator ends or yields nothing for ``idle_timeout`` seconds. ``every``: every N-th frame, or ``"auto"`` (a
    few cm apart at the speed read). Other arguments as `reconstruct`. Returns a `mvracklay.live.LiveResult`
    (``.run.map`` the `WarehouseMap`, ``.report`` frames received / mapped / dropped and the latency).
    """
    from mvracklay.argtypes import check_call

    check_call(reconstruct_live, locals())
    from mvracklay.live import reconstruct_live as run
    from mvracklay.presets import preset_fields
    from mvracklay.settings import LiveSettings

    if on_update is not None and not callable(on_update):
        raise InputError(f"on_update: want a callable, got {type(on_update).__name__}")
    settings = LiveSettings(idle_timeout=idle_timeout, live_buffer=buffer)
    cfg = dict(
        checkpoint=Path(checkpoint) if checkpoint is not None else None,
        camera=Path(camera) if isinstance(camera, (str, os.PathLike)) else None,
        distance=distance,
        camera_height=camera_height,
        **{**preset_fields(quality), **options},
    )
    if out is not None:
        from mvracklay.outputs import check_out

        check_out(Path(out), overwrite=False)
    return run(frames, out, on_update=on_update, settings=settings, every=every, intrinsics=_intrinsics(camera), **cfg)


class LiveUpdates:
    """`reconstruct_live` as a generator: iterate for each `mvracklay.live.MapUpdate` as the map grows (the run goes
    on in a thread; at most ``pending`` updates wait for the reader, then the run waits); ``.result`` is the
    `mvracklay.live.LiveResult` once the iteration ended. Leaving the loop early abandons the run (nothing saved)."""

    def __init__(self, frames: Any, pending: int = 4, **kwargs: Any) -> None:
        self.frames, self.pending, self.kwargs = frames, pending, kwargs
        self.result: Any = None

    def __iter__(self) -> Any:
        import queue
        import threading

        q: queue.Queue = queue.Queue(maxsize=self.pending)
        done, left = object(), threading.Event()
        failed: list[BaseException] = []

        def hand(update: Any) -> None:  # blocks while the reader is behind; gives up once the reader left
            while not left.is_set():
                try:
                    return q.put(update, timeout=0.2)
                except queue.Full:
                    continue
            raise _Abandoned

        def work() -> None:
            try:
                self.result = reconstruct_live(self.frames, on_update=hand, **self.kwargs)
            except _Abandoned:
                pass
            except BaseException as e:  # noqa: BLE001 (raised again in the reader's thread)
                failed.append(e)
            finally:
                if not left.is_set():
                    q.put(done)

        thread = threading.Thread(target=work, name="live-updates", daemon=True)
        thread.start()
        try:
            while (item := q.get()) is not done:
                yield item
        finally:
            left.set()
        thread.join()
        if failed:
            raise failed[0]


class _Abandoned(Exception):
    """The reader of `LiveUpdates` left the loop: the run stops."""


def live_updates(frames: Any, **kwargs: Any) -> LiveUpdates:
    """Map updates as a generator: ``for update in (live := mvracklay.live_updates(frames)): ...``, then
    ``live.result.run.map`` (arguments as `reconstruct_live`)."""
    return LiveUpdates(frames, **kwargs)
