"""Hand-held camera walks: a fine-step sequence re-sampled as a person with a phone walks it.

A generated sequence moves its camera by a steady step. People do not: they stop for a few
frames, speed up and slow down, step back, pause and then jump on. `handheld_indices` draws such a
walk over the frames of a fine-step sequence (its usual stride ``stride`` frames: the steady walk
takes every ``stride``-th frame); `resample_sequence` writes the walk as a sequence folder of its
own (frames, ground-truth layouts and per-frame records taken together, files hard-linked), which
every reader takes like any other sequence. Seeded: the same walk and seed give the same frames.
"""

from __future__ import annotations

import json
import math
import os
import shutil
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from layouts.errors import InputError

FRAME_FOLDERS = ("rgb", "depth", "semantic", "instance")  #: per-frame image folders, named 000000.png ...


@dataclass(frozen=True)
class HandheldWalk:
    """How a hand-held camera walks over a fine-step sequence (frames of the source sequence)."""

    stride: int = 2  #: the usual step, in source frames (the steady walk takes every stride-th frame)
    step_range: tuple[float, float] = (0.5, 2.0)  #: a step's length, in strides (uneven: up to twice the usual)
    stop_probability: float = 0.12  #: the chance that the camera stops after a step
    stop_frames: tuple[int, int] = (3, 6)  #: frames a stop lasts (the same view repeated)
    back_steps: int = 1  #: steps back (one stride to twice that) somewhere in the middle third of the walk

    def __post_init__(self) -> None:
        if isinstance(self.stride, bool) or not isinstance(self.stride, int) or self.stride < 1:
            raise InputError(f"HandheldWalk.stride must be an integer >= 1, got {self.stride!r}")
        lo, hi = self.step_range
        if not (0 < lo <= hi and math.isfinite(hi)):
            raise InputError(f"HandheldWalk.step_range must be 0 < low <= high, got {self.step_range!r}")
        if not 0 <= self.stop_probability < 1:
            raise InputError(f"HandheldWalk.stop_probability must be in [0, 1), got {self.stop_probability!r}")
        a, b = self.stop_frames
        if not (isinstance(a, int) and isinstance(b, int) and 1 <= a <= b):
            raise InputError(f"HandheldWalk.stop_frames must be integers 1 <= low <= high, got {self.stop_frames!r}")
        if isinstance(self.back_steps, bool) or not isinstance(self.back_steps, int) or self.back_steps < 0:
            raise InputError(f"HandheldWalk.back_steps must be an integer >= 0, got {self.back_steps!r}")


def handheld_indices(num_frames: int, seed: int = 0, walk: HandheldWalk | None = None) -> list[int]:
    """Source frame indices of one hand-held walk over ``num_frames`` fine-step frames (starting at 0).

    Each step moves ``round(stride * U(step_range))`` frames (at least one); after a step the camera stops
    with ``stop_probability`` (the frame repeated ``stop_frames`` times in all); ``back_steps`` steps go back
    one to two strides, at places drawn in the middle third. Indices stay in ``[0, num_frames)``.
    """
    if isinstance(num_frames, bool) or not isinstance(num_frames, int) or num_frames < 1:
        raise InputError(f"num_frames must be an integer >= 1, got {num_frames!r}")
    w = walk or HandheldWalk()
    rng = np.random.default_rng(seed)
    expected = max(1, int(num_frames / (w.stride * sum(w.step_range) / 2)))
    backs = set(rng.integers(expected // 3, max(expected // 3 + 1, 2 * expected // 3), size=w.back_steps).tolist())
    out, pos, k = [0], 0, 0
    while True:
        k += 1
        if k in backs and pos > 2 * w.stride:
            pos -= int(rng.integers(w.stride, 2 * w.stride + 1))
        else:
            pos += max(1, int(round(w.stride * rng.uniform(*w.step_range))))
        if pos >= num_frames:
            break
        out.append(pos)
        if rng.random() < w.stop_probability:
            out.extend([pos] * (int(rng.integers(w.stop_frames[0], w.stop_frames[1] + 1)) - 1))
    return out


def steady_indices(num_frames: int, stride: int = 2) -> list[int]:
    """The steady walk over the same frames: every ``stride``-th one."""
    return list(range(0, num_frames, stride))


def _link(src: Path, dst: Path) -> None:
    try:
        os.link(src, dst)
    except OSError:  # another filesystem, or links not allowed: a copy
        shutil.copy2(src, dst)


def resample_sequence(src: str | os.PathLike, dst: str | os.PathLike, indices: list[int], note: Any = None) -> Path:
    """Write the sequence ``src`` walked through ``indices`` (source frames, repeats and steps back allowed) as
    the sequence folder ``dst``: frame k of ``dst`` is frame ``indices[k]`` of ``src`` (images and layouts
    hard-linked, records copied with their index renumbered); ``scene.json`` and the sequence's settings are the
    source's, ``meta.json`` records ``resampled_from`` (the source frames and ``note``, e.g. the walk)."""
    src, dst = Path(src), Path(dst)
    meta_path = src / "meta.json"
    if not meta_path.is_file():
        raise InputError(f"{src}: not a sequence folder (no meta.json)")
    meta = json.loads(meta_path.read_text())
    n = int(meta.get("num_frames", len(meta.get("frames", []))))
    if not indices or any(isinstance(i, bool) or not isinstance(i, int) or not 0 <= i < n for i in indices):
        raise InputError(f"indices must be a non-empty list of frame indices in [0, {n}) of {src}")
    if dst.exists() and any(dst.iterdir()):
        raise InputError(f"{dst}: exists and is not empty")
    dst.mkdir(parents=True, exist_ok=True)
    if (src / "scene.json").is_file():
        _link(src / "scene.json", dst / "scene.json")
    for folder in (*FRAME_FOLDERS, "layouts"):
        if not (src / folder).is_dir():
            continue
        (dst / folder).mkdir()
        ext = ".npz" if folder == "layouts" else ".png"
        for k, i in enumerate(indices):
            f = src / folder / f"{i:06d}{ext}"
            if f.is_file():
                _link(f, dst / folder / f"{k:06d}{ext}")
        for extra in (src / folder).iterdir():  # the layout folder's spec and the like
            if extra.is_file() and not extra.stem.isdigit():
                _link(extra, dst / folder / extra.name)
    frames = []
    for k, i in enumerate(indices):
        rec = dict(meta["frames"][i])
        rec["index"] = k
        frames.append(rec)
    meta.update(frames=frames, num_frames=len(indices), name=dst.name)
    meta["resampled_from"] = {"frames": list(indices), "note": note}
    (dst / "meta.json").write_text(json.dumps(meta, indent=1, sort_keys=True))
    return dst


def walk_note(walk: HandheldWalk, seed: int) -> dict[str, Any]:
    """What ``meta.json``'s ``resampled_from.note`` records of a hand-held walk."""
    return {"walk": "handheld", "seed": seed, **asdict(walk)}
