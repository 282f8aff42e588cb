"""What a frame goes through before the network, in training and inference alike: its camera (a sequence's
intrinsics and per-frame distance, `frame_camera`; its recorded rotation, `sequence_angles`), the warp into the
model's canonical view (`canonical_image`) and the tensor the network reads (`to_tensor`).

`network.data` builds the training windows on top of this; `network.inference.predictor` reads frames through
it without the training data.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch

from layouts import Intrinsics
from layouts.canonical import CanonicalView
from layouts.errors import InputError, LayoutError

#: camera-to-rack distance assumed when neither the data nor the user give one (the default generator's middle)
DEFAULT_DISTANCE = 2.6


def frame_camera(seq: Any, i: int, default_distance: float = DEFAULT_DISTANCE) -> tuple[Intrinsics | None, float]:
    """The intrinsics (None if the sequence has none) and camera-to-rack distance of frame ``i``."""
    intr = getattr(seq, "intrinsics", None)
    dist = default_distance
    frame = getattr(seq, "frame", None)
    if callable(frame):
        try:
            d = float(frame(i).get("distance"))
            if np.isfinite(d) and d > 0:
                dist = d
        except (TypeError, ValueError, AttributeError):
            pass
    return intr, dist


def sequence_angles(seq: Any) -> tuple[float, float, float]:
    """A generated sequence's camera rotation (roll, pitch, yaw) in degrees, as recorded
    (`waresynth.dataset.Sequence.camera_angles`); (0, 0, 0) for one that records none."""
    angles = getattr(seq, "camera_angles", None)
    return (0.0, 0.0, 0.0) if angles is None else (float(angles[0]), float(angles[1]), float(angles[2]))


def image_intrinsics(intr: Intrinsics | None, width: int, height: int) -> Intrinsics:
    """The intrinsics of a ``width x height`` image: ``intr`` scaled to it, or a 60 deg camera if None."""
    if intr is None:
        return Intrinsics.from_fov(width, height, 60.0)
    return intr if (intr.width, intr.height) == (width, height) else intr.scaled(width, height)


def canonical_image(
    rgb: np.ndarray,
    view: CanonicalView,
    intr: Intrinsics | None,
    distance: float,
    roll_deg: float = 0.0,
    pitch_deg: float = 0.0,
    yaw_deg: float = 0.0,
) -> np.ndarray:
    """uint8 RGB of any size -> the model's canonical ``(H, W, 3)`` view (60 deg camera if ``intr`` is None).

    ``roll_deg`` / ``pitch_deg`` / ``yaw_deg``: the camera's roll about its optical axis, the tilt of
    that axis (up > 0) and its turn (right > 0), levelled in the same resampling (`layouts.canonical`)."""
    rgb = np.asarray(rgb)
    if rgb.ndim == 2:
        rgb = np.repeat(rgb[..., None], 3, axis=2)
    if rgb.ndim != 3 or rgb.shape[2] not in (3, 4) or rgb.dtype != np.uint8:
        raise InputError(f"image must be uint8 (H, W, 3), got {rgb.dtype} {rgb.shape}")
    rgb = np.ascontiguousarray(rgb[..., :3])
    intr = image_intrinsics(intr, rgb.shape[1], rgb.shape[0])
    try:
        return view.warp(rgb, intr, distance, roll_deg, pitch_deg, yaw_deg)
    except LayoutError as e:
        raise InputError(str(e)) from None


def to_tensor(images: np.ndarray) -> torch.Tensor:
    """uint8 ``(..., H, W, 3)`` -> float ``(..., 3, H, W)`` in [0, 1]."""
    t = torch.from_numpy(np.array(images, dtype=np.float32)).div_(255.0)
    return t.movedim(-1, -3).contiguous()
