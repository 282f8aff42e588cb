"""Reading a camera record: the one place that turns a recorded camera (a sequence's ``meta.json``, a
``--camera`` file, an export's ``cameras.json`` entry) into its rotation angles and lens distortion.

The generator writes these records, the network's data readers and the pipeline read them; each reads
them through here so a record means the same thing everywhere. A ``--camera`` file's own schema (its keys,
types and ranges) is `mvracklay.camera_schema`'s.
"""

from __future__ import annotations

from typing import Any

from layouts.camera import Intrinsics
from layouts.canonical import MAX_ROLL_DEG
from layouts.errors import InputError, LayoutError
from layouts.lens import Lens

#: the camera rotation's keys (``camera.*`` ranges of a generator config, and each sequence's camera record)
CAMERA_ANGLE_KEYS = ("roll_deg", "pitch_deg", "yaw_deg")


def camera_angles(record: Any, source: str) -> tuple[float, float, float]:
    """A camera's rotation (roll, pitch, yaw) in degrees from its record; 0 where a key is missing (written
    when the camera could not rotate: it was level). Bad values: `InputError` naming ``source``."""
    record = record if isinstance(record, dict) else {}
    out = []
    for k in CAMERA_ANGLE_KEYS:
        v = record.get(k, 0.0)
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not abs(v) <= MAX_ROLL_DEG:
            raise InputError(f"{source}: camera {k} must be a number of degrees within +-{MAX_ROLL_DEG:g}, got {v!r}")
        out.append(float(v))
    return out[0], out[1], out[2]


def lens_from_record(d: dict[str, Any], where: str) -> Lens | None:
    """The distortion an intrinsics record gives beside fx..cy (None: none, or all zero); bad values:
    `InputError` naming ``where``."""
    try:
        lens = Lens.from_dict(d, where)
    except LayoutError as e:
        raise InputError(str(e)) from None
    return None if lens is None or lens.is_pinhole else lens


_ASPECT_TOL = 0.01
"""Relative difference of width / height ratios still taken as the same aspect (rounding of scaled sizes)."""


def check_camera_fits(intr: Intrinsics, width: int, height: int, where: str) -> None:
    """Refuse a camera record that cannot describe ``width x height`` frames: its image of another aspect ratio
    (scaling it would stretch the camera). Its own ranges (fields of view, principal point) are `Intrinsics`'s."""
    if (intr.width, intr.height) == (width, height):
        return
    ratio, frames = intr.width / intr.height, width / height
    if abs(ratio - frames) > _ASPECT_TOL * frames:
        raise InputError(
            f"{where}: its image is {intr.width}x{intr.height} (aspect {ratio:.3f}), the frames {width}x{height} "
            f"(aspect {frames:.3f}): scaling would stretch the camera; give the intrinsics at the frames' size"
        )
