"""The camera-to-rack distance of footage that does not say it: read from its frames, or from the camera height.

`read_distance` runs the `DistanceReader` (`network.model.distance`) on a few frames: each frame is
resampled at an assumed distance, the reader says how far off that is, and the frame is resampled again
at the corrected distance (`ROUNDS` times, so the last reading is made near the truth, where the reader
is most precise). The frames' readings are combined by their median.

With ``camera_height`` (metres above the floor, as a robot's mount knows it) the distance comes from
geometry where the floor line is in view: the floor meets the rack front ``camera_height`` below the
optical axis, so ``d = camera_height * d0 / floor_y``. Where it is not in view (a high camera), the
reading falls back to the sizes, and says so.

The shipped reader is package data of `mvracklay.models` (``distance-reader.pt``); any checkpoint written by
`save_reader` loads with `load_reader`.
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from layouts import Intrinsics
from layouts.errors import InputError
from layouts.fileio import atomic_write_bytes
from network.model.distance import DistanceReader, DistanceReaderConfig
from network.preprocess import DEFAULT_DISTANCE, canonical_image, to_tensor

FORMAT = "mvracklay-distance-reader"
#: resample-and-read rounds per frame
ROUNDS = 3
#: frames read at the start of a stream (spread over the first `LEAD_FRAMES` for a file of known length)
LEAD_FRAMES = 12
#: the floor line counts as seen when the reader's floor probability passes this
FLOOR_SEEN = 0.5
#: distances the reading may return (metres): the reader's trained range, widened
DISTANCE_RANGE = (0.8, 8.0)
#: distances taken at all (metres, given or recorded): outside them no rack row is readable in a frame
DISTANCE_LIMITS = (0.05, 100.0)


def distance_warning(value: float, where: str) -> str | None:
    """The warning to print for a camera-to-rack distance outside `DISTANCE_RANGE` (the range the networks were
    trained for; such a distance is still used), else None. Check it with `check_distance` first."""
    if not DISTANCE_RANGE[0] <= value <= DISTANCE_RANGE[1]:
        return (
            f"{where}: distance {value:g} m is outside the range the model was trained for "
            f"({DISTANCE_RANGE[0]:g}-{DISTANCE_RANGE[1]:g} m); the layouts may be poor"
        )
    return None


@dataclass(frozen=True)
class DistanceReading:
    """The distance used and how it was known, as warehouse.json records it."""

    distance: float
    source: str  #: "given", "recorded", "camera height", "read", "default"
    frames: int = 0  #: frames read (0 when not read)
    spread: tuple[float, float] | None = None  #: the frames' readings, 10th and 90th percentile
    note: str = ""  #: one line on how the reading went, e.g. why the camera height could not be used

    def describe(self) -> str:
        what = {
            "given": "given (--distance)",
            "recorded": "recorded with the sequence",
            "camera height": f"from the camera height and the floor line in {self.frames} frames",
            "read": f"read from {self.frames} frames",
            "default": "the default (not read)",
        }[self.source]
        if self.spread is not None and self.source in ("read", "camera height"):
            what += f", {self.spread[0]:.2f}-{self.spread[1]:.2f} m across them"
        return f"{self.distance:.2f} m, {what}"

    def to_record(self) -> dict[str, Any]:
        rec: dict[str, Any] = {"distance": round(self.distance, 4), "distance_source": self.source}
        if self.frames:
            rec["distance_frames"] = self.frames
        if self.spread is not None:
            rec["distance_spread"] = [round(v, 4) for v in self.spread]
        if self.note:
            rec["distance_note"] = self.note
        return rec


def save_reader(path: str | os.PathLike, reader: DistanceReader, record: dict[str, Any]) -> None:
    """Write the reader's weights with its config and ``record`` (atomic)."""
    import io
    import json

    buf = io.BytesIO()
    rec = {"format": FORMAT, "config": reader.cfg.to_dict(), **record}
    torch.save({"state": reader.state_dict(), "record": json.dumps(rec, sort_keys=True)}, buf)
    atomic_write_bytes(path, buf.getvalue())


def load_reader(path: str | os.PathLike) -> tuple[DistanceReader, dict[str, Any]]:
    """A reader saved by `save_reader` (``weights_only``: no pickled code runs), in eval mode."""
    import json

    from network.checkpoint import check_finite, first_sentence, torch_load

    path = Path(path)
    payload = torch_load(path, "distance reader")
    try:
        record = json.loads(payload["record"])
        if record.get("format") != FORMAT:
            raise ValueError(f"format {record.get('format')!r}")
        reader = DistanceReader(DistanceReaderConfig.from_dict(record["config"]))
        check_finite(payload["state"], path)
        reader.load_state_dict(payload["state"])
    except InputError:
        raise
    except Exception as e:  # noqa: BLE001 - any unreadable file is one line
        raise InputError(f"{path}: not a distance reader ({type(e).__name__}: {first_sentence(e)})") from None
    return reader.eval(), record


@torch.no_grad()
def reader_outputs(
    reader: DistanceReader, frames: Sequence[np.ndarray], intr: Intrinsics | None, assumed: Sequence[float]
) -> np.ndarray:
    """``(N, 3)``: the reader's raw outputs for each frame resampled at its assumed distance."""
    view = reader.cfg.view
    imgs = np.stack([canonical_image(f, view, intr, d) for f, d in zip(frames, assumed)])
    p = next(reader.parameters())
    return reader.read(to_tensor(imgs).to(p.device, p.dtype)).float().cpu().numpy()


def _clip(d: np.ndarray) -> np.ndarray:
    return np.clip(d, *DISTANCE_RANGE)


def read_distances(
    reader: DistanceReader,
    frames: Sequence[np.ndarray],
    intr: Intrinsics | None,
    start: float = DEFAULT_DISTANCE,
    rounds: int = ROUNDS,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per frame: the distance read from sizes, the floor line's drop below the optical axis per metre of
    distance (``camera height / distance``, free of scale) and the floor's probability of being in view."""
    d = np.full(len(frames), float(start))
    out = np.zeros((len(frames), 3))
    d_assumed = d
    for _ in range(max(1, rounds)):
        d_assumed = d
        out = reader_outputs(reader, frames, intr, d_assumed)
        d = _clip(d_assumed * np.exp(out[:, 0]))
    # floor_y of the last resampling is camera height * d_assumed / d_true metres: divided by d_assumed, a ratio
    return d, out[:, 1] / d_assumed, 1.0 / (1.0 + np.exp(-out[:, 2]))


def read_distance(
    reader: DistanceReader,
    frames: Sequence[np.ndarray],
    intr: Intrinsics | None,
    camera_height: float | None = None,
    start: float = DEFAULT_DISTANCE,
) -> DistanceReading:
    """The distance of ``frames`` (one camera, one distance): their readings' median (`DistanceReading`)."""
    if not frames:
        raise InputError("no frames to read the camera distance from")
    d, floor_ratio, p_floor = read_distances(reader, frames, intr, start)
    spread = (float(np.percentile(d, 10)), float(np.percentile(d, 90)))
    if camera_height is not None:
        seen = (p_floor >= FLOOR_SEEN) & (floor_ratio > 0.02)
        if seen.sum() * 2 >= len(frames):
            dh = _clip(camera_height / floor_ratio[seen])
            return DistanceReading(
                float(np.median(dh)),
                "camera height",
                int(seen.sum()),
                (float(np.percentile(dh, 10)), float(np.percentile(dh, 90))),
            )
        note = (
            f"the floor line below the racks is out of view in {len(frames) - int(seen.sum())} of {len(frames)} "
            f"frames, so --camera-height {camera_height:g} was not used"
        )
        return DistanceReading(float(np.median(d)), "read", len(frames), spread, note)
    return DistanceReading(float(np.median(d)), "read", len(frames), spread)


def _metres(value: Any) -> float:
    """``value`` as a float (NaN when it is no number: a bool, text, None)."""
    try:
        return math.nan if isinstance(value, bool) else float(value)
    except (TypeError, ValueError):
        return math.nan


def check_distance(value: Any, option: str = "--distance") -> float | None:
    """None, or a camera-to-rack distance in metres: a positive finite number within `DISTANCE_LIMITS` (one-line
    error otherwise; outside them no rack row is readable in a frame)."""
    d = _metres(value)
    if value is not None and not (math.isfinite(d) and d > 0):
        raise InputError(f"{option} must be a positive number of metres, got {value}")
    lo, hi = DISTANCE_LIMITS
    if value is not None and not lo <= d <= hi:
        raise InputError(f"{option}: distance {d:g} m is out of range (a rack row is filmed from {lo:g}-{hi:g} m)")
    return None if value is None else d


def check_camera_height(value: Any, option: str = "--camera-height") -> float | None:
    """None, or a camera height above the floor in metres (one-line error otherwise)."""
    h = _metres(value)
    if value is not None and math.isnan(h):
        raise InputError(f"{option} must be a number of metres, got {value!r}")
    if value is not None and not (math.isfinite(h) and 0.05 <= h <= 20):
        raise InputError(f"{option} must be the camera's height above the floor in metres (0.05-20), got {value!r}")
    return None if value is None else h
