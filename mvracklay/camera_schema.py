"""The declared schema of a ``--camera`` JSON file, checked before a camera is believed (`camera_file_record`).

A camera file holds `layouts.Intrinsics` fields (fx, fy, cx, cy in pixels; width, height of the image they
refer to) and optionally the lens's distortion (OpenCV's k1, k2, p1, p2, k3), at the top level or nested
under ``"intrinsics"`` (the lens typically beside it), and nothing else. Refused, in one line naming the file
and the field: unknown keys, a key given both inside and beside ``"intrinsics"``, fx, fy, cx or cy missing,
numbers that are not finite or not numbers, focal lengths <= 0, an image size outside [1, 16384] pixels,
a lens coefficient beyond +-2. The camera's physical ranges (each field of view within
`layouts.camera.FOV_RANGE_DEG`, the principal point inside its image) are `layouts.Intrinsics`'s, and whether it
fits the frames (the same aspect ratio) `layouts.camera_record.check_camera_fits`'s, for files and inline cameras
alike.
"""

from __future__ import annotations

from typing import Annotated, Any

from pydantic import BaseModel, ConfigDict, Field, StrictInt, ValidationError, field_validator, model_validator

from layouts.errors import InputError, first_problem
from layouts.lens import LENS_KEYS

Number = Annotated[float, Field(strict=True, allow_inf_nan=False)]
Focal = Annotated[float, Field(strict=True, allow_inf_nan=False, gt=0)]
Side = Annotated[StrictInt, Field(ge=1, le=16384)]
Coefficient = Annotated[float, Field(strict=True, allow_inf_nan=False, ge=-2.0, le=2.0)]

#: the keys a camera file may hold (at its top level, or nested under ``"intrinsics"``)
INTRINSICS_KEYS = ("fx", "fy", "cx", "cy", "width", "height")
CAMERA_FILE_KEYS = INTRINSICS_KEYS + LENS_KEYS
_REQUIRED = ("fx", "fy", "cx", "cy")


class IntrinsicsDoc(BaseModel):
    """Intrinsics and lens keys, each optional here (the file as a whole must give fx, fy, cx, cy)."""

    model_config = ConfigDict(extra="forbid")

    fx: Focal | None = None
    fy: Focal | None = None
    cx: Number | None = None
    cy: Number | None = None
    width: Side | None = None
    height: Side | None = None
    k1: Coefficient | None = None
    k2: Coefficient | None = None
    p1: Coefficient | None = None
    p2: Coefficient | None = None
    k3: Coefficient | None = None


class CameraFileDoc(IntrinsicsDoc):
    intrinsics: IntrinsicsDoc | None = None

    @field_validator("intrinsics", mode="before")
    @classmethod
    def _object(cls, v: Any) -> Any:
        if v is not None and not isinstance(v, dict):
            raise ValueError('"intrinsics" must be a JSON object with fx, fy, cx, cy (and width, height)')
        return v

    @model_validator(mode="after")
    def _once_and_whole(self) -> CameraFileDoc:
        nested = self.intrinsics.model_fields_set if self.intrinsics is not None else set()
        both = [k for k in CAMERA_FILE_KEYS if k in nested and k in self.model_fields_set]
        if both:
            raise ValueError(f'{", ".join(both)} given both inside "intrinsics" and beside it; give each once')
        given = nested | self.model_fields_set
        missing = [k for k in _REQUIRED if k not in given]
        if missing:
            raise ValueError(f"missing {', '.join(missing)} (a camera file gives fx, fy, cx, cy in pixels)")
        return self


def _unknown(errors: list[dict], where: str) -> str | None:
    """The schema's refusal of unknown keys in the form users know: every unknown key at one level at once."""
    extra = [e for e in errors if e.get("type") == "extra_forbidden"]
    if not extra:
        return None
    level = extra[0]["loc"][:-1]
    keys = [str(e["loc"][-1]) for e in extra if e["loc"][:-1] == level]
    inside = ' "intrinsics"' if level else ""
    return (
        f"{where}{inside}: unknown key{'s' if len(keys) > 1 else ''} {', '.join(repr(k) for k in keys)} "
        f'(known: {", ".join(CAMERA_FILE_KEYS)}, and "intrinsics" nesting them)'
    )


def camera_file_record(doc: Any, where: str) -> dict[str, Any]:
    """A camera file's parsed JSON, checked against `CameraFileDoc`, as one flat record of `CAMERA_FILE_KEYS`
    (the keys given, nested ones lifted beside the others). Anything the schema refuses: one `InputError`
    line naming ``where`` and the field."""
    if not isinstance(doc, dict):
        raise InputError(f"{where}: want a JSON object with fx, fy, cx, cy (and width, height)")
    try:
        CameraFileDoc.model_validate(doc)
    except ValidationError as e:
        errors = e.errors()
        raise InputError(_unknown(errors, where) or f"{where}: {first_problem(errors)}") from None
    flat = {k: v for k, v in doc.items() if k != "intrinsics"}
    return {**(doc.get("intrinsics") or {}), **flat}
