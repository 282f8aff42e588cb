"""The declared schema of a sequence's ``meta.json``, checked whenever one is read (`check_meta`).

Only what readers use is declared; every field stays optional where older or hand-made sequences may lack
it, and unknown fields are kept. Refused, in one line naming the file and the field: numbers that are not
finite, a distance or image size <= 0, a visible fraction outside [0, 1], a negative clear height or frame
index, lists of the wrong length. The intrinsics' own rules (principal point, sizes) are `layouts.Intrinsics`'s
and the camera angles' `layouts.camera_record.camera_angles`'s; a distance's range is checked where it is used
(`network.inference.distance.check_distance`).
"""

from __future__ import annotations

from typing import Annotated, Any

from pydantic import BaseModel, ConfigDict, Field, StrictInt, ValidationError

from layouts.errors import InputError, first_problem

Finite = Annotated[float, Field(allow_inf_nan=False)]
Positive = Annotated[float, Field(allow_inf_nan=False, gt=0)]
Vec3 = tuple[Finite, Finite, Finite]


class _Doc(BaseModel):
    model_config = ConfigDict(extra="allow", allow_inf_nan=False)


class SlotDoc(_Doc):
    board_top_y: Finite | None = None
    clear_height: Annotated[float, Field(allow_inf_nan=False, ge=0)] | None = None
    level: StrictInt | None = None
    origin: Vec3 | None = None


class FrameDoc(_Doc):
    index: Annotated[StrictInt, Field(ge=0)] | None = None
    camera_position: Vec3 | None = None
    distance: Positive | None = None
    rack_mid_z: Finite | None = None
    slots: list[SlotDoc] | None = None
    visible_fraction: Annotated[float, Field(allow_inf_nan=False, ge=0, le=1)] | None = None


class CameraDoc(_Doc):
    distance: Positive | None = None
    height: Finite | None = None
    hfov_deg: Annotated[float, Field(allow_inf_nan=False, ge=1, le=170)] | None = None


class SequenceMetaDoc(_Doc):
    name: str | None = None
    num_frames: Annotated[StrictInt, Field(ge=0)] | None = None
    image_size: tuple[Annotated[StrictInt, Field(gt=0)], Annotated[StrictInt, Field(gt=0)]] | None = None
    camera: CameraDoc | None = None
    frames: list[FrameDoc] | None = None


def check_meta(doc: Any, source: str) -> None:
    """Refuse (one `InputError` line naming ``source``) a parsed meta.json that breaks the schema."""
    if not isinstance(doc, dict):
        raise InputError(f"{source}: not a WareSynth meta.json (want a JSON object)")
    try:
        SequenceMetaDoc.model_validate(doc)
    except ValidationError as e:
        raise InputError(f"{source}: malformed meta.json: {first_problem(e.errors())}") from None
