"""Every N-th frame of a `FrameSource` (``--every N``): video at 30 fps moves a few cm a frame, so a run
may skip frames. The frames kept are numbered 0, 1, 2, ... (their layouts, stitching steps and map)."""

from __future__ import annotations

import itertools
from collections.abc import Iterator
from dataclasses import dataclass, fields, replace

import numpy as np

from layouts.errors import InputError
from mvracklay.frames import FrameSource


@dataclass
class _EveryNthVideo(FrameSource):
    """A video source yielding frames 0, N, 2N, ... (decoded all, kept every N-th)."""

    every: int = 1

    def _raw_frames(self, max_frames: int | None) -> Iterator[np.ndarray]:
        limit = (max_frames - 1) * self.every + 1 if max_frames else None
        yield from itertools.islice(super()._raw_frames(limit), 0, None, self.every)

    def frame_count(self, max_frames: int | None = None) -> int | None:
        if self.num_frames is None:
            return None
        n = -(-self.num_frames // self.every)
        return min(n, max_frames) if max_frames else n


def every_nth(source: FrameSource, every: int | str, option: str = "--every") -> FrameSource:
    """``source`` keeping frames 0, N, 2N, ... (itself when ``every`` is 1); one-line error unless N >= 1.
    A live source (`mvracklay.live_source`) thins itself as frames arrive (N, or ``auto``): it is returned as it is."""
    if source.kind == "live":
        return source
    if every == "auto":
        raise InputError(
            f"{option} auto keeps a live stream's frames a few cm apart; for a file give N (--every 3 on a 30 fps walk)"
        )
    if not isinstance(every, int) or isinstance(every, bool) or every < 1:
        raise InputError(f"{option} must be an integer >= 1, got {every!r}")
    if every == 1:
        return source
    if source.kind == "video":
        return _EveryNthVideo(**{f.name: getattr(source, f.name) for f in fields(source)}, every=every)
    paths = source.image_paths[::every]
    records = source.records[::every] if source.records is not None else None
    return replace(source, image_paths=paths, num_frames=len(paths), records=records)
