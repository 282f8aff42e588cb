"""The declared schema of a checkpoint's record (the JSON embedded in ``NAME.pt`` and repeated in ``NAME.json``
beside it), checked whenever a checkpoint is loaded (`network.checkpoint.load_checkpoint`).

Declared: the keys the loaders read. The model config's own rules are `ModelConfig.from_dict`'s; here its
being an object. Refused, in one line naming the file and the key: numbers that are not finite, a step,
epoch or training minutes < 0, the training camera's focal lengths <= 0 or image size outside
[1, 16384], a field-of-view range not within [1, 170] degrees or reversed, a nominal distance outside
(0, 100] m, box decision offsets beyond +-`LIMIT` or with other views than top and front, a rack-depth
offset beyond +-`DEPTH_OFFSET_LIMIT` m. Other keys (metrics, notes, how it was trained) are kept as they are.
"""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, StrictInt, StrictStr, ValidationError, model_validator

from layouts.errors import InputError, first_problem
from network.inference.decision import DEPTH_OFFSET_LIMIT, LIMIT

Finite = Annotated[float, Field(strict=True, allow_inf_nan=False)]
NonNeg = Annotated[float, Field(strict=True, allow_inf_nan=False, ge=0)]
Focal = Annotated[float, Field(strict=True, allow_inf_nan=False, gt=0)]
Side = Annotated[StrictInt, Field(ge=1, le=16384)]
Offset = Annotated[float, Field(strict=True, allow_inf_nan=False, ge=-LIMIT, le=LIMIT)]
Degrees = Annotated[float, Field(strict=True, allow_inf_nan=False, ge=1, le=170)]


class IntrinsicsRecord(BaseModel):
    """The camera the model was trained with (`layouts.Intrinsics` fields)."""

    model_config = ConfigDict(extra="forbid")

    fx: Focal
    fy: Focal
    cx: Finite
    cy: Finite
    width: Side
    height: Side


class BoxOffsets(BaseModel):
    """Box decision offsets per view (`network.inference.decision.check_offsets`)."""

    model_config = ConfigDict(extra="forbid")

    top: Offset
    front: Offset


class CheckpointRecord(BaseModel):
    model_config = ConfigDict(extra="allow", allow_inf_nan=False, protected_namespaces=())

    format: Literal["mvracklay-checkpoint"]
    format_version: Literal[1]
    model_config_: dict[str, Any] | None = Field(default=None, alias="model_config")
    variant: StrictStr | None = None
    step: Annotated[StrictInt, Field(ge=0)] | None = None
    epoch: Annotated[StrictInt, Field(ge=0)] | None = None
    train_wall_minutes: NonNeg | None = None
    train_cpu_minutes: NonNeg | None = None
    intrinsics: IntrinsicsRecord | None = None
    hfov_range_deg: tuple[Degrees, Degrees] | None = None
    nominal_distance: Annotated[float, Field(strict=True, allow_inf_nan=False, gt=0, le=100)] | None = None
    box_logit_offset: BoxOffsets | None = None
    rack_depth_offset: (
        Annotated[float, Field(strict=True, allow_inf_nan=False, ge=-DEPTH_OFFSET_LIMIT, le=DEPTH_OFFSET_LIMIT)] | None
    ) = None
    dtype: Literal["float16", "float32"] | None = None

    @model_validator(mode="after")
    def _ordered(self) -> CheckpointRecord:
        if self.hfov_range_deg is not None and self.hfov_range_deg[0] > self.hfov_range_deg[1]:
            raise ValueError(f"hfov_range_deg {list(self.hfov_range_deg)} is reversed (low must come first)")
        return self


def check_record(record: Any, source: str) -> None:
    """Refuse (one `InputError` line naming ``source`` and the key) a checkpoint record that breaks the schema."""
    try:
        CheckpointRecord.model_validate(record)
    except ValidationError as e:
        raise InputError(f"{source}: checkpoint record: {first_problem(e.errors())}") from None
