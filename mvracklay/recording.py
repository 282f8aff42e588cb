"""A run's Rerun recording (``OUT/warehouse.rrd``), frame by frame: each frame's thumbnail kept from when it is read
until its layouts come (`RunRecording.keep`), then logged with its layouts, the camera path and, every N-th
frame, the growing map (`RunRecording.log`); the finished map last (`RunRecording.close`)."""

from __future__ import annotations

from collections import deque
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from stitching import rerun_log

if TYPE_CHECKING:
    from mvracklay.inference import PredictedFrame
    from stitching.pipeline import Stitcher
    from stitching.warehouse_map import WarehouseMap

#: the widest RGB frame the recording keeps (wider ones are shrunk: .rrd files of HD video stay small)
RRD_MAX_WIDTH = 640


def thumbnail(rgb: np.ndarray) -> np.ndarray:
    """RGB for the recording, at most `RRD_MAX_WIDTH` wide."""
    h, w = rgb.shape[:2]
    if w <= RRD_MAX_WIDTH:
        return rgb
    from PIL import Image

    size = (RRD_MAX_WIDTH, max(1, round(h * RRD_MAX_WIDTH / w)))
    return np.asarray(Image.fromarray(rgb).resize(size, Image.Resampling.BILINEAR))


#: the camera path's points logged with each frame (`decimate`)
PATH_POINTS = 256


def thin(path: list, limit: int | None = None) -> None:
    """Every other point of ``path`` dropped in place (the first and the newest kept) once it holds over ``2 * limit``
    (default `PATH_POINTS`): a bounded path over the whole walk, still ``limit`` points or more to decimate from."""
    limit = limit or PATH_POINTS
    if len(path) > 2 * limit:
        path[:] = path[:-1:2] + path[-1:]


def decimate(path: list, limit: int | None = None) -> list:
    """At most ``limit`` (default `PATH_POINTS`) points of the camera path (first and last kept), so long videos log a
    bounded path per frame."""
    limit = limit or PATH_POINTS
    if len(path) <= limit:
        return path
    idx = np.unique(np.linspace(0, len(path) - 1, limit).round().astype(int))
    return [path[i] for i in idx]


class RunRecording:
    """The recording of one run, saved to ``save``; ``camera_yz``: the camera's height and depth in the map frame
    (None: unknown), ``rgb``: log the frames' pixels, ``map_every``: log the growing map every N-th frame;
    ``sinks``: Rerun sinks streamed to while the run goes (a live run's viewer, `mvracklay.live.viewer_sinks`);
    ``bounded``: memory bounded over an endless stream (a live run): the camera path kept thinned (`thin`) rather than
    whole, the .rrd written without Rerun's footer (its chunk manifest grows in memory with every frame logged)."""

    def __init__(
        self,
        name: str,
        save: Path,
        num_slots: int,
        camera_yz: tuple[float | None, float | None],
        rgb: bool = True,
        map_every: int = 1,
        sinks: tuple = (),
        bounded: bool = False,
    ) -> None:
        self.rec: Any = rerun_log.start(name, save=save, num_slots=num_slots, sinks=sinks, footer=not bounded)
        self.num_slots, self.camera_yz, self.rgb, self.map_every = num_slots, camera_yz, rgb, map_every
        self.pending: deque[np.ndarray | None] = deque()  # each frame's thumbnail until its layouts come
        self.path: list[tuple[float, float, float]] = []
        self.bounded = bounded

    def keep(self, rgb: np.ndarray) -> None:
        """A frame as it is read (its thumbnail, when the recording shows RGB)."""
        self.pending.append(thumbnail(rgb) if self.rgb else None)

    def log(self, frame: PredictedFrame, frame_rec: Any, offset: float, stitcher: Stitcher) -> None:
        """One predicted frame: its layouts and reconstruction where the camera stood, and every ``map_every``-th
        frame the map so far."""
        self.path.append(rerun_log.camera_point(offset, *self.camera_yz))
        if self.bounded:
            thin(self.path)
        self.rec.check()  # a failed write into the .rrd (a full disk) ends the run here, not after every frame
        rgb = self.pending.popleft()
        rerun_log.log_frame(self.rec, frame.index, frame.layouts, frame_rec, offset, rgb, decimate(self.path))
        if frame.index % self.map_every == 0:
            rerun_log.log_map(self.rec, stitcher.map(), frame.index, self.num_slots)

    def close(self, wmap: WarehouseMap, frames: int) -> None:
        """The finished map (unless the last frame logged it already), written out and read back
        (`stitching.rerun_log.Recording.disconnect`: a failed write is an `OSError` naming the file)."""
        if (frames - 1) % self.map_every:
            rerun_log.log_map(self.rec, wmap, frames - 1, self.num_slots)
        self.rec.disconnect()

    def abort(self) -> None:
        """Stop recording without finishing (a failed run)."""
        self.rec.abort()
