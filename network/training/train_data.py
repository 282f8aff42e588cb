"""The training data: a dataset folder opened (`open_data`, `open_generated`), what a generated frame's
images show that a fit needs (`require_level_camera`, `upright_faces`), and what a run's record says of its
cameras. The one module of `network` that imports `waresynth` (DESIGN.md; tests/test_arrows.py)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from layouts.camera import Intrinsics
from layouts.errors import InputError


def open_data(root: str | Path):
    """Open a training/evaluation data folder: a WareSynth dataset, a RackLay/MVRackLay export
    written by `mvracklay export --format racklay` (recognised by its manifest), or a folder in the
    authors' published layout (`waresynth.racklay_published`; it prints one line on stderr saying
    which camera it assumes). All give ``spec``, ``image_size`` and ``sequences(split)``; one-line
    error if it is none of them."""
    import sys

    # the dataset readers are the one allowed waresynth import
    from waresynth.dataset import open_dataset
    from waresynth.exporters.racklay import RACKLAY_MANIFEST, load_racklay_export
    from waresynth.racklay_published import is_published_layout, open_published

    root = Path(root)
    if not root.is_dir():
        raise InputError(f"{root}: dataset folder not found")
    if (root / RACKLAY_MANIFEST).is_file():
        return load_racklay_export(root)
    if is_published_layout(root):
        data = open_published(root)
        print(f"note: {data.note}", file=sys.stderr)
        return data
    return open_dataset(root)


def open_generated(root: str | Path):
    """A WareSynth dataset folder (`waresynth.dataset.open_dataset`): a fit that reads the generator's records
    (distances, camera positions) beside the images."""
    from waresynth.dataset import open_dataset

    return open_dataset(root)


def require_level_camera(seq: Any, what: str) -> None:
    """A one-line refusal when ``what`` reads a generated frame's depth or semantic images as a level camera's
    and the sequence's camera was turned (`waresynth.dataset.require_level_camera`)."""
    from waresynth.dataset import require_level_camera as require

    require(seq, what)


def upright_faces(semantic: np.ndarray, depth: np.ndarray, distance: float, rack_depth: float):
    """The columns of a generated frame that show front and rear uprights (`waresynth.visibility.upright_faces`)."""
    from waresynth.visibility import upright_faces as faces

    return faces(semantic, depth, distance, rack_depth)


def hfov_range(seqs: list[Any]) -> list[float] | None:
    """The narrowest and widest horizontal field of view (degrees) of the training sequences' cameras
    (None when a sequence has no intrinsics), so `run` can tell a camera the model has seen."""
    fovs = [getattr(s, "intrinsics", None) for s in seqs]
    if not fovs or any(f is None for f in fovs):
        return None
    vals = [f.hfov_deg for f in fovs]
    return [float(min(vals)), float(max(vals))]


def nominal_distance(seqs: list[Any]) -> float | None:
    """The mean camera-to-rack distance over the first 50 training sequences' frames (None when a frame has none)."""
    vals = []
    for s in seqs[:50]:
        try:
            vals.extend(float(s.frame(i)["distance"]) for i in range(s.num_frames))
        except (AttributeError, KeyError, TypeError, ValueError):
            return None
    return float(np.mean(vals)) if vals else None


def data_record(train_seqs: list[Any], data_info: dict[str, Any] | None, train_frames: int) -> dict[str, Any]:
    """What a run's record says of its training data: where it came from (``data_info``), the camera (the middle
    one of a range the cameras were drawn from), the range of fields of view, the nominal distance, the counts."""
    intr = getattr(train_seqs[0], "intrinsics", None)
    fov_range = hfov_range(train_seqs)
    if intr is not None and fov_range is not None and fov_range[1] - fov_range[0] > 0.01:
        # cameras drawn from a range: the record's camera is the range's middle one
        intr = Intrinsics.from_fov(intr.width, intr.height, (fov_range[0] + fov_range[1]) / 2)
    return {
        "data": data_info or {},
        "intrinsics": intr.to_dict() if intr is not None else None,
        "hfov_range_deg": fov_range,
        "nominal_distance": nominal_distance(train_seqs),
        "train_frames": train_frames,
        "train_sequences": len(train_seqs),
    }
