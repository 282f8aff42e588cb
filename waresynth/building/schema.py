"""The building config of ``mvracklay generate --building [FILE]``: its defaults and declared schema.

A building file is a JSON object overriding any subset of `BUILDING_DEFAULTS` (keys starting with ``_`` are
comments). Ranges are ``[low, high]`` drawn per face or per bay by the building's seed; lengths in metres.
`load_building` refuses, in one line naming the file and the key, unknown keys, values of the wrong type,
numbers outside their range and ``[low, high]`` with low > high. ``changes`` (a rescan's change rates) is not
among the defaults: a building config holds it only for ``--rescan``. Nor are ``rack_build`` and ``run_bays``
(how the racks are built, `waresynth.building.rack_build`): without them every rack stands apart.
"""

from __future__ import annotations

import copy
import os
from pathlib import Path
from typing import Annotated, Any

from pydantic import BaseModel, ConfigDict, Field, StrictInt, ValidationError, field_validator, model_validator

from layouts.errors import InputError, first_problem
from layouts.fileio import load_json
from layouts.locations import check_code_format

#: the default building: what each key means is in docs/waresynth.md ("Buildings")
BUILDING_DEFAULTS: dict[str, Any] = {
    "aisles": 4,
    "bays": [6, 10],
    "bay_width": [1.6, 3.0],
    "bay_gap": [0.1, 0.3],
    "levels": [2, 3],
    "depth": [0.8, 1.2],
    "aisle_width": [3.0, 3.6],
    "back_gap": [0.1, 0.3],
    "cross_aisle": 3.0,
    "pass_length": 12.0,
    "overlap": [1.5, 3.0],
    "twice_share": 0.25,
    "positions": 1,
    "code": "{aisle:02d}-{side}-{bay:02d}-{level:02d}",
}

#: a rescan's change rates (``changes``, docs/waresynth.md "Rescans"): shares of the building's stacks before the
#: changes that are removed, added, moved to another location, shifted along their level, replaced by another size
CHANGE_DEFAULTS: dict[str, float] = {"removed": 0.05, "added": 0.05, "moved": 0.03, "shifted": 0.05, "replaced": 0.02}
#: the keys that fix the racks, stacks and location codes: a rescan keeps them
RACK_KEYS = ("aisles", "bays", "bay_width", "bay_gap", "levels", "depth", "aisle_width", "back_gap", "cross_aisle",
             "positions", "code", "rack_build", "run_bays")  # fmt: skip
#: the keys a building config may hold beside `BUILDING_DEFAULTS`
OPTIONAL_KEYS = ("rack_build", "run_bays", "changes")

Share = Annotated[float, Field(strict=True, ge=0, le=1)]
Length = Annotated[float, Field(strict=True, allow_inf_nan=False, gt=0, le=1000)]
Count = Annotated[StrictInt, Field(ge=1, le=99)]


def _ordered(v: Any) -> Any:
    if v is not None and v[0] > v[1]:
        raise ValueError(f"[low, high] with low <= high, got {list(v)}")
    return v


class ChangesDoc(BaseModel):
    """A rescan's change rates (any subset of `CHANGE_DEFAULTS`)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    removed: Share = CHANGE_DEFAULTS["removed"]
    added: Share = CHANGE_DEFAULTS["added"]
    moved: Share = CHANGE_DEFAULTS["moved"]
    shifted: Share = CHANGE_DEFAULTS["shifted"]
    replaced: Share = CHANGE_DEFAULTS["replaced"]

    @model_validator(mode="after")
    def _once(self) -> ChangesDoc:
        if self.removed + self.moved + self.shifted + self.replaced > 1.0 + 1e-9:
            raise ValueError("removed + moved + shifted + replaced must stay at most 1 (a stack changes once)")
        return self


class RackBuildDoc(BaseModel):
    """The shares of faces built each way (`waresynth.building.rack_build.KINDS`); missing ones are 0, their sum above 0."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    apart: Share = 0.0
    run: Share = 0.0
    units: Share = 0.0

    @model_validator(mode="after")
    def _some(self) -> RackBuildDoc:
        if self.apart + self.run + self.units <= 0:
            raise ValueError("apart, run and units shares must not all be 0")
        return self


class BuildingDoc(BaseModel):
    """A whole (merged) building config."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    aisles: Count
    bays: tuple[Count, Count]
    bay_width: tuple[
        Annotated[float, Field(strict=True, ge=0.5, le=10)], Annotated[float, Field(strict=True, ge=0.5, le=10)]
    ]
    bay_gap: tuple[Annotated[float, Field(strict=True, ge=0, le=5)], Annotated[float, Field(strict=True, ge=0, le=5)]]
    levels: tuple[Annotated[StrictInt, Field(ge=1, le=12)], Annotated[StrictInt, Field(ge=1, le=12)]]
    depth: tuple[Annotated[float, Field(strict=True, ge=0.3, le=3)], Annotated[float, Field(strict=True, ge=0.3, le=3)]]
    aisle_width: tuple[Length, Length]
    back_gap: tuple[Annotated[float, Field(strict=True, ge=0, le=5)], Annotated[float, Field(strict=True, ge=0, le=5)]]
    cross_aisle: Annotated[float, Field(strict=True, ge=0, le=100)]
    pass_length: Length
    overlap: tuple[
        Annotated[float, Field(strict=True, ge=0, le=100)], Annotated[float, Field(strict=True, ge=0, le=100)]
    ]
    twice_share: Annotated[float, Field(strict=True, ge=0, le=1)]
    positions: Annotated[StrictInt, Field(ge=1, le=20)]
    code: str
    changes: ChangesDoc | None = None  #: a rescan's change rates (only with --rescan)
    rack_build: RackBuildDoc | None = None  #: shares of faces built apart, as runs, as units
    run_bays: tuple[Count, Count] | None = None  #: bays of one run or one line of units, between gaps

    _pairs = field_validator(
        "bays", "bay_width", "bay_gap", "levels", "depth", "aisle_width", "back_gap", "overlap", "run_bays"
    )(_ordered)

    @field_validator("code")
    @classmethod
    def _code(cls, v: str) -> str:
        """A format whose fields tell every location apart (`layouts.locations.check_code_format`)."""
        try:
            return check_code_format(v)
        except InputError as e:
            raise ValueError(str(e)) from None

    @model_validator(mode="after")
    def _whole(self) -> BuildingDoc:
        if self.overlap[1] >= self.pass_length:
            raise ValueError(f"overlap must stay below pass_length ({self.pass_length:g} m), got {list(self.overlap)}")
        if self.positions > 1 and "{position" not in self.code:
            raise ValueError("code must hold {position} when a level has more than one position")
        return self


def load_building(building: dict[str, Any] | str | os.PathLike | None) -> dict[str, Any]:
    """The effective building config: `BUILDING_DEFAULTS` overridden by ``building`` (a dict, a JSON file or
    None); one `InputError` line naming the source and the key when it breaks the schema."""
    cfg = copy.deepcopy(BUILDING_DEFAULTS)
    if building is None:
        return cfg
    src = "building"
    if isinstance(building, (str, os.PathLike)):
        src = str(building)
        if not Path(building).is_file():
            raise InputError(f"{src}: building file not found")
        building = load_json(building)
    if not isinstance(building, dict):
        raise InputError(f"{src}: a building config must be a JSON object, got {type(building).__name__}")
    cfg.update({k: v for k, v in building.items() if not (isinstance(k, str) and k.startswith("_"))})
    try:
        BuildingDoc.model_validate(cfg)
    except ValidationError as e:
        errors = e.errors()
        if errors[0]["type"] == "extra_forbidden":
            loc = errors[0]["loc"]
            nested = {"changes": CHANGE_DEFAULTS, "rack_build": RackBuildDoc.model_fields}
            known = nested.get(str(loc[0]), []) if len(loc) > 1 else [*BUILDING_DEFAULTS, *OPTIONAL_KEYS]
            raise InputError(f"{src}: unknown key {'.'.join(map(str, loc))!r} (known: {', '.join(known)})") from None
        raise InputError(f"{src}: {first_problem(errors)}") from None
    return cfg


def change_rates(rates: Any, source: str = "changes") -> dict[str, float]:
    """The effective change rates: `CHANGE_DEFAULTS` overridden by ``rates`` (a dict or None); one `InputError`
    line naming ``source`` and the key when they break `ChangesDoc`."""
    if rates is None:
        return dict(CHANGE_DEFAULTS)
    if not isinstance(rates, dict):
        raise InputError(f"{source}: an object of {', '.join(CHANGE_DEFAULTS)}, got {type(rates).__name__}")
    try:
        doc = ChangesDoc.model_validate(rates)
    except ValidationError as e:
        errors = e.errors()
        raise InputError(f"{source}{'.' if errors[0]['loc'] else ': '}{first_problem(errors)}") from None
    return {k: float(getattr(doc, k)) for k in CHANGE_DEFAULTS}
