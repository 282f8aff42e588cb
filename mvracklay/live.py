"""Live runs: a camera or a stream mapped as its frames arrive (``mvracklay run rtsp://...``, `reconstruct_live`).

The frames come through a `mvracklay.live_source.LiveSource` (a reader thread, a bounded buffer: the network
never queues frames without bound, it drops the oldest waiting and counts them) and go down the file runs' path,
`mvracklay.pipeline.run_pipeline`, frame by frame: predicted, written, stitched, logged. `LiveRun` follows each
frame into the map (its latency from received to mapped; the camera's speed for ``--every auto``) and gives map
updates to a callback. The run ends when the stream ends, stays quiet ``--idle-timeout`` seconds, or on Ctrl-C /
SIGTERM (`stop_on_signals`); each way the map of what was seen is saved as a file run saves it (staged, then
published: warehouse.json, .glb, .rrd). `viewer_sinks` streams the recording to a viewer while it grows.
"""

from __future__ import annotations

import contextlib
import signal
import socket
import threading
import time
from collections import deque
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from layouts.errors import InputError
from mvracklay.live_source import LiveSource, open_live
from mvracklay.settings import SERVE_PORT, LiveSettings, RunConfig

if TYPE_CHECKING:
    from mvracklay.inference import PredictedFrame
    from mvracklay.pipeline import RunResult
    from stitching.pipeline import Stitcher
    from stitching.warehouse_map import WarehouseMap

#: latencies kept for the percentiles (the last frames: memory stays flat over a long stream)
LATENCY_WINDOW = 10_000


@dataclass(frozen=True)
class MapUpdate:
    """One frame in the map: its index among the frames mapped, seconds from its arrival to now, and the map so far."""

    index: int
    latency: float
    map: WarehouseMap


@dataclass(frozen=True)
class LiveReport:
    """What a live run saw: frames received, mapped, dropped (the network behind), skipped (``every auto``), the
    latency from a frame received to the map updated (seconds, p50 / p95), the buffer's fullest, why it ended."""

    received: int
    mapped: int
    dropped: int
    skipped: int
    latency_p50: float
    latency_p95: float
    buffer_most: int
    buffer_capacity: int
    ended: str

    @property
    def dropped_share(self) -> float:
        return self.dropped / self.received if self.received else 0.0

    def lines(self) -> list[str]:
        """The run's report, as printed."""
        skip = f", {self.skipped} skipped (every auto: too close)" if self.skipped else ""
        return [
            f"live: {self.received} frames received, {self.mapped} mapped, {self.dropped} dropped "
            f"({100 * self.dropped_share:.1f} %){skip}; ended: {self.ended}",
            f"latency, frame received -> map updated: p50 {1000 * self.latency_p50:.0f} ms, "
            f"p95 {1000 * self.latency_p95:.0f} ms",
        ]

    def to_dict(self) -> dict[str, Any]:
        d = {k: getattr(self, k) for k in self.__dataclass_fields__}
        return {**d, "dropped_share": self.dropped_share}


class LiveRun:
    """Follows a live source's frames into the map (`mapped`, the pipeline's ``on_frame``): latency, the camera's
    speed for the source's spacing, and ``on_update`` called with each `MapUpdate`."""

    def __init__(self, source: LiveSource, on_update: Callable[[MapUpdate], None] | None = None) -> None:
        self.source, self.on_update = source, on_update
        self.latencies: deque[float] = deque(maxlen=LATENCY_WINDOW)
        self._last: float | None = None

    def mapped(self, frame: PredictedFrame, stitcher: Stitcher) -> None:
        received, stream_time = self.source.arrival(frame.index)
        latency = time.monotonic() - received
        self.latencies.append(latency)
        t = stream_time if stream_time is not None else received
        spacing = self.source.spacing
        if spacing is not None and self._last is not None:
            spacing.moved(frame.prediction.camera_step, t - self._last)
        self._last = t
        if self.on_update is not None:
            self.on_update(MapUpdate(frame.index, latency, stitcher.map()))

    def report(self) -> LiveReport:
        s = self.source.stats()
        lat = np.asarray(self.latencies, float)
        p50, p95 = (float(np.percentile(lat, q)) for q in (50, 95)) if lat.size else (float("nan"),) * 2
        return LiveReport(s["received"], s["given"], s["dropped"], s["skipped"], p50, p95, s["buffer_most"],
                          s["buffer_capacity"], self.source.ended or "stream ended")  # fmt: skip


@contextlib.contextmanager
def stop_on_signals(source: LiveSource) -> Iterator[None]:
    """Ctrl-C and SIGTERM end the stream (the map of what was seen is then saved); a second one acts as before
    (Ctrl-C: `KeyboardInterrupt`, the outputs left as they were). Only in the main thread (signals go there)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    names = {signal.SIGINT: "Ctrl-C", signal.SIGTERM: "SIGTERM"}
    previous = {s: signal.getsignal(s) for s in names}

    def handler(signum: int, frame: Any) -> None:
        if source._stop.is_set():  # a second one: as without us
            prev = previous[signum]
            if callable(prev):
                prev(signum, frame)
                return
            raise KeyboardInterrupt
        source.stop(names[signum])

    for s in names:
        signal.signal(s, handler)
    try:
        yield
    finally:
        for s, prev in previous.items():
            signal.signal(s, prev)


def check_viewer(spawn: bool, serve: bool, rrd: bool, live: bool) -> None:
    """One line when the viewer options (``--spawn``, ``--serve``) cannot go with the run's other options."""
    if spawn and not rrd:
        raise InputError("--spawn opens OUT/warehouse.rrd; it cannot be combined with --no-rrd")
    if serve and not live:
        raise InputError("--serve serves a live run's recording; a file run's: rerun OUT/warehouse.rrd")
    if serve and not rrd:
        raise InputError("--serve serves the recording; it cannot be combined with --no-rrd")


def viewer_sinks(spawn: bool, serve: int | None) -> tuple[tuple, list[str]]:
    """The Rerun sinks a live run streams its recording to besides the .rrd file, and what to tell the user:
    ``spawn`` starts a viewer and streams into it; ``serve`` (a port) runs Rerun's gRPC server, which keeps the
    recording for viewers that connect later (from another machine: ``rerun --connect rerun+http://HOST:PORT/proxy``)."""
    from stitching.rerun_log import sdk

    rr = sdk()
    sinks: list[Any] = []
    said: list[str] = []
    if serve is not None:
        try:
            sinks.append(rr.GrpcServerSink(port=serve))
        except Exception as e:  # noqa: BLE001 (a port taken: one line)
            raise InputError(f"--serve {serve}: cannot serve the recording there ({e})") from None
        said.append(f"serving the recording: rerun --connect rerun+http://{socket.gethostname()}:{serve}/proxy")
    if spawn:
        port = SERVE_PORT + 1 if serve == SERVE_PORT else SERVE_PORT
        try:
            rr.spawn(port=port, connect=False)
        except Exception as e:  # noqa: BLE001 (no viewer installed, no display: one line)
            raise InputError(f"--spawn: cannot start the Rerun viewer ({e})") from None
        sinks.append(rr.GrpcSink(f"rerun+http://127.0.0.1:{port}/proxy"))
    return tuple(sinks), said


@dataclass
class LiveResult:
    """A live run's `mvracklay.pipeline.RunResult` and its `LiveReport`."""

    run: RunResult
    report: LiveReport


def run_live(
    source: LiveSource,
    out: str | Path,
    cfg: RunConfig,
    *,
    loaded: Any = None,
    sinks: tuple = (),
    on_update: Callable[[MapUpdate], None] | None = None,
) -> LiveResult:
    """Map ``source`` as it streams into OUT (`mvracklay.pipeline.run_pipeline`, the file runs' path) until it ends,
    goes quiet or is stopped (`stop_on_signals`); the source is closed after. ``loaded``: the model, loaded before
    the stream was opened (so its frames do not wait on it)."""
    from mvracklay.pipeline import run_pipeline

    if cfg.inference.whole_sequence:
        source.close()
        raise InputError(
            "--whole-sequence (--quality offline) reads every frame before the first map: not for a live source"
        )
    live = LiveRun(source, on_update)
    try:
        with stop_on_signals(source):
            res = run_pipeline(source, out, cfg, loaded=loaded, on_frame=live.mapped, sinks=sinks, bounded=True)
    finally:
        source.close()
    return LiveResult(res, live.report())


def map_live_source(url: str, out: Path, cfg: RunConfig, settings: LiveSettings, spawn: bool = False):
    """`mvracklay run` on a live source: the model loaded, the stream opened, the viewer's sinks made (their
    lines printed), mapped until it ends. Returns the `LiveResult` and the source."""
    from mvracklay.pipeline import load_model
    from network.inference.predictor import warm_up

    settings.validate()
    if cfg.inference.whole_sequence:
        raise InputError(
            "--whole-sequence (--quality offline) reads every frame before the first map: not for a live source"
        )
    loaded = load_model(cfg)  # before the stream opens: its frames do not wait on the model
    warm_up(loaded[1])  # nor on the graphs its first frames would build
    source = open_live(url, idle_timeout=settings.idle_timeout, retries=settings.retries,
                       buffer=settings.live_buffer, every=cfg.every, prog="mvracklay run")  # fmt: skip
    try:
        sinks, said = viewer_sinks(spawn, settings.serve)
    except BaseException:
        source.close()
        raise
    for line in said:
        print(line, flush=True)
    if cfg.progress:
        print(f"mapping {source.url} ({source.width}x{source.height}) as it streams; Ctrl-C ends it", flush=True)
    return run_live(source, out, cfg, loaded=loaded, sinks=sinks), source


def reconstruct_live(
    frames: Iterable[np.ndarray] | str,
    out: str | Path | None = None,
    *,
    on_update: Callable[[MapUpdate], None] | None = None,
    settings: LiveSettings | None = None,
    every: int | str = 1,
    intrinsics: Any = None,
    **options: Any,
) -> LiveResult:
    """The live run for Python: ``frames`` an iterator yielding uint8 RGB frames as they arrive (read by a thread into
    the bounded buffer) or a stream URL / camera; ``on_update`` sees each frame as it lands in the map. See
    `mvracklay.api.reconstruct_live`."""
    import tempfile

    from mvracklay.live_source import iter_live
    from mvracklay.pipeline import load_model
    from network.inference.predictor import warm_up

    settings = settings or LiveSettings()
    settings.validate()
    cfg = RunConfig.build(**{"progress": False, **options, "every": every})
    cfg.validate()
    loaded = load_model(cfg)
    warm_up(loaded[1])
    kw = {"idle_timeout": settings.idle_timeout, "buffer": settings.live_buffer, "every": every}
    if isinstance(frames, str):
        source = open_live(frames, retries=settings.retries, prog="mvracklay.reconstruct_live", **kw)
    else:
        source = iter_live(frames, intrinsics=intrinsics, **kw)
    if out is not None:
        return run_live(source, out, cfg, loaded=loaded, on_update=on_update)
    with tempfile.TemporaryDirectory(prefix="mvracklay-") as tmp:
        return run_live(source, Path(tmp) / "run", replace(cfg, rrd=False), loaded=loaded, on_update=on_update)
