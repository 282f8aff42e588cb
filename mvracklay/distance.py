"""The camera-to-rack distance a run uses, and where it came from (printed, and kept in warehouse.json).

In order: ``--distance`` (given); the camera height ``--camera-height`` with the floor line read from the
first frames; a generated sequence's recorded distances; else read from the first frames' sizes by the
shipped distance reader (`network.inference.distance`). Without a reader file (a copy made without the
weights), or from frames too small to read (`MIN_READ_SIDE`), the default distance is used, and said.

A wrong distance scales the whole map: every length (box sizes, positions along the row, shelf heights)
is off by the same factor. Counts, the order of boxes and free *fractions* are unchanged by the scale.
"""

from __future__ import annotations

import itertools
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from layouts import Intrinsics
from mvracklay.frames import FrameSource
from mvracklay.models import distance_reader_path
from network.inference.distance import (
    LEAD_FRAMES,
    DistanceReading,
    check_distance,
    distance_warning,
    load_reader,
    read_distance,
)
from network.preprocess import DEFAULT_DISTANCE

#: pixels a frame's shorter side must have for its distance to be read: the reader resamples each frame to its
#: 128-pixel view, and from fewer pixels it reads noise (the default distance is used, and said)
MIN_READ_SIDE = 32


def default_distance(record: dict[str, Any]) -> float:
    """The distance used when none is given, recorded or read: the checkpoint record's ``nominal_distance``
    (its training data's mean), else `network.preprocess.DEFAULT_DISTANCE`."""
    nominal = record.get("nominal_distance")
    return float(nominal) if isinstance(nominal, (int, float)) and nominal > 0 else DEFAULT_DISTANCE


class FrameDistances:
    """Frame index -> distance, known before the first frame is predicted (`lead` reads it when it must)."""

    def __init__(
        self,
        source: FrameSource,
        intr: Intrinsics,
        given: float | None = None,
        camera_height: float | None = None,
        default: float = DEFAULT_DISTANCE,
        reader: str | Path | None = None,
        prog: str = "mvracklay run",
    ) -> None:
        self.source, self.intr, self.given, self.camera_height = source, intr, given, camera_height
        self.default, self.reader_path, self.prog = default, Path(reader) if reader else None, prog
        self.reading: DistanceReading | None = None
        self.warnings: list[str] = []
        recorded: list[float | None] = []
        if given is not None:
            self.reading = DistanceReading(float(given), "given")
        elif camera_height is None and source.distance(0) is not None:
            recorded = [source.distance(i) for i in range(len(source.records or []))]
            self.reading = DistanceReading(float(np.median([d for d in recorded if d])), "recorded")
        self._check_range(given, recorded if self.recorded else [])

    def _check_range(self, given: float | None, recorded: list[float | None]) -> None:
        """A given or recorded distance outside the limits refused, outside the trained range warned of."""
        checks = [(given, "--distance")] if given is not None else []
        known = [d for d in recorded if d]
        if known:
            where = f"{self.source.path / 'meta.json'}"
            checks += [(min(known), where), (max(known), where)]
        for value, where in checks:
            check_distance(float(value), where)
            said = distance_warning(float(value), where)
            if said and said not in self.warnings:
                self.warnings.append(said)
                print(f"{self.prog}: warning: {said}", file=sys.stderr)

    @property
    def recorded(self) -> bool:
        return self.reading is not None and self.reading.source == "recorded"

    def __call__(self, index: int) -> float:
        if self.recorded:
            return self.source.distance(index) or self.reading.distance
        return self.reading.distance if self.reading is not None else self.default

    def lead(self, frames: Iterator[np.ndarray]) -> Iterator[np.ndarray]:
        """``frames`` unchanged; when the distance must be read, the first `LEAD_FRAMES` are read first."""
        if self.reading is not None:
            yield from frames
            return
        first = list(itertools.islice(frames, LEAD_FRAMES))
        if first:
            self.reading = self._read(first)
        yield from first
        yield from frames

    def _read(self, frames: list[np.ndarray]) -> DistanceReading:
        path = self.reader_path or distance_reader_path()
        height, width = min(f.shape[0] for f in frames), min(f.shape[1] for f in frames)
        if min(height, width) < MIN_READ_SIDE:
            return self._default(
                f"frames of {width}x{height} pixels are too small to read the distance from (under {MIN_READ_SIDE} "
                f"a side)"
            )
        if not path.is_file():
            return self._default(f"no distance reader ({path} is absent)")
        reader, _ = load_reader(path)
        reading = read_distance(reader, frames, self.intr, self.camera_height, start=self.default)
        if reading.note:
            self.warnings.append(reading.note)
            print(f"{self.prog}: warning: {reading.note}", file=sys.stderr)
        return reading

    def _default(self, why: str) -> DistanceReading:
        """The default distance where none can be read, said with ``why``."""
        said = f"{why}: the default {self.default:.2f} m is used; pass --distance"
        self.warnings.append(said)
        print(f"{self.prog}: warning: {said}", file=sys.stderr)
        return DistanceReading(self.default, "default", note=said)
