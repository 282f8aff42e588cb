"""A building's route record: the floor plan (each rack face's front line, extent along X and boards' heights)
and every pass's start pose, read and checked (``route.json``, as `mvracklay generate --building` writes it or a
user writes it for own footage), and the seeded perturbation of the poses that tests a map against a poor route.

Pass fields used: ``sequence`` (its folder or video, relative to the route file), ``aisle``, ``side``, ``start``
(``x``, ``z`` of the first frame's camera and ``heading_deg``, the optical axis from +X toward +Z) and the levels
its view holds (``levels``, from 1; or ``first_level``, the level of the lowest shelf in view, default 1);
optional ``height``, the camera above the floor (for drawing its path). Other
fields are kept but never read: the map finds the bays and boxes itself.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field, replace
from typing import Annotated, Any

import numpy as np
from pydantic import (
    AfterValidator,
    BaseModel,
    BeforeValidator,
    ConfigDict,
    Field,
    StrictInt,
    TypeAdapter,
    ValidationError,
    field_validator,
)
from pydantic_core import PydanticCustomError

from layouts.errors import InputError, first_problem
from layouts.fileio import load_json

Finite = Annotated[float, Field(allow_inf_nan=False, ge=-1e5, le=1e5)]
Aisle = Annotated[StrictInt, Field(ge=1, le=9999)]
Side = Annotated[str, Field(pattern="^[LR]$")]
Level = Annotated[StrictInt, Field(ge=1, le=99)]


def _rising(values: Any) -> Any:
    """Levels or boards' heights: from the lowest up, each once (a repeated or turned-round list puts boxes on
    the wrong level)."""
    for a, b in zip(values or [], (values or [])[1:]):
        if b <= a:
            raise ValueError(f"must rise from the lowest up, each once, got {list(values or [])}")
    return values


class _Start(BaseModel):
    model_config = ConfigDict(extra="ignore")
    x: Finite
    z: Finite
    heading_deg: Finite


class _Pass(BaseModel):
    model_config = ConfigDict(extra="ignore")
    sequence: str = Field(min_length=1)
    aisle: Aisle
    side: Side
    start: _Start
    height: Annotated[float, Field(allow_inf_nan=False, gt=0, le=100)] | None = None
    levels: list[Level] | None = None
    first_level: Level = 1

    _levels = field_validator("levels")(_rising)


class OnFace:
    """What the ``aisle`` and ``side`` of a face, or of a thing on one, give: its face's key and the sign of its
    face frame in the building."""

    aisle: int
    side: str

    @property
    def key(self) -> tuple[int, str]:
        return (self.aisle, self.side)

    @property
    def sign(self) -> float:
        """+1 for an R face, -1 for an L face: building X = sign * face X, building Z = front + sign * face Z."""
        return 1.0 if self.side == "R" else -1.0


def _boards(v: Any) -> Any:
    """A face record's ``levels_m``: a list (null: unknown, none)."""
    if v is None:
        return ()
    if not isinstance(v, (list, tuple)):
        raise PydanticCustomError("list_type", "Input should be a valid list")
    return v


def _record(v: Any) -> Any:
    """A face record: a JSON object (or a `FacePlan` already made)."""
    if not isinstance(v, (dict, FacePlan)):
        raise PydanticCustomError("model_type", "Input should be a valid dictionary or instance of PlanFace")
    return v


Board = Annotated[float, Field(allow_inf_nan=False, ge=0, le=100)]


@dataclass(frozen=True)
class FacePlan(OnFace):
    """A face as the floor plan gives it: front line, extent along building X (None: unknown), board heights. Its
    record (a route's ``faces`` entry, a building map's ``plan`` entry) is validated as this dataclass itself
    (`PlanFace`, `plan_face`: unknown keys ignored)."""

    __pydantic_config__ = ConfigDict(extra="ignore")

    aisle: Aisle
    side: Side
    front_z: Finite
    x_min: Finite | None = None
    x_max: Finite | None = None
    #: boards' top heights above the floor, lowest first; () unknown
    levels_m: Annotated[tuple[Board, ...], BeforeValidator(_boards), AfterValidator(_rising)] = ()

    def __post_init__(self) -> None:
        if self.x_min is not None and self.x_max is not None and self.x_min >= self.x_max:
            raise ValueError(f"x_min {self.x_min} must lie below x_max {self.x_max}")


#: a face record of the floor plan, validated as a `FacePlan`
PlanFace = Annotated[FacePlan, BeforeValidator(_record)]
_PLAN_FACE: TypeAdapter[FacePlan] = TypeAdapter(FacePlan)


class _Route(BaseModel):
    model_config = ConfigDict(extra="ignore")
    faces: list[PlanFace] = Field(min_length=1)
    passes: list[_Pass] = Field(min_length=1)


@dataclass(frozen=True)
class PassPose(OnFace):
    """One pass: its sequence, face, the first camera's building X and Z, heading (degrees), its slots' levels."""

    sequence: str
    aisle: int
    side: str
    x: float
    z: float
    heading_deg: float
    levels: tuple[int, ...] | None = None  #: level (from 1) of each slot; None: from ``first_level`` up
    first_level: int = 1
    height: float | None = None  #: the camera above the floor, when the route gives it

    def slot_level(self, slot: int) -> int:
        """The level (from 1) a slot of this pass's layouts holds."""
        if self.levels is not None and slot < len(self.levels):
            return self.levels[slot]
        base = self.levels[-1] + 1 - len(self.levels) if self.levels else self.first_level
        return base + slot


@dataclass
class Route:
    faces: dict[tuple[int, str], FacePlan]
    passes: list[PassPose]
    source: str = "route"
    extra: dict[str, Any] = field(default_factory=dict)


def parse_route(doc: Any, source: str = "route") -> Route:
    """A route record from its JSON content; one line naming the source and the first problem when wrong."""
    try:
        r = _Route.model_validate(doc)
    except ValidationError as e:
        raise InputError(f"{source}: {first_problem(e.errors())}") from None
    faces: dict[tuple[int, str], FacePlan] = {}
    for f in r.faces:
        if (f.aisle, f.side) in faces:
            raise InputError(f"{source}: face {f.aisle:02d}-{f.side} is listed twice")
        faces[(f.aisle, f.side)] = f
    passes, names = [], set()
    for k, p in enumerate(r.passes):
        face = faces.get((p.aisle, p.side))
        if face is None:
            raise InputError(
                f"{source}: pass {p.sequence!r} is on face {p.aisle:02d}-{p.side}, which faces does not list"
            )
        if p.sequence in names:
            raise InputError(f"{source}: pass {p.sequence!r} is listed twice")
        names.add(p.sequence)
        levels = tuple(p.levels) if p.levels else None
        n = len(face.levels_m)
        key, top = ("levels", max(levels)) if levels else ("first_level", p.first_level)
        if n and top > n:
            raise InputError(
                f"{source}: passes[{k}].{key}: level {top} of pass {p.sequence!r} is above the {n} levels of "
                f"face {face.aisle:02d}-{face.side} (its levels_m)"
            )
        passes.append(
            PassPose(p.sequence, p.aisle, p.side, p.start.x, p.start.z, p.start.heading_deg, levels, p.first_level)
        )
    return Route(faces, passes, source)


def plan_face(f: FacePlan | dict[str, Any]) -> FacePlan:
    """A face of the floor plan from its record (a route's ``faces`` entry, a building map's ``plan`` entry)."""
    return f if isinstance(f, FacePlan) else _PLAN_FACE.validate_python(f)


def plan_dict(f: FacePlan) -> dict[str, Any]:
    """The record of a face of the floor plan, as a route holds it (unknown fields left out)."""
    out: dict[str, Any] = {"aisle": f.aisle, "side": f.side, "front_z": f.front_z}
    out.update({k: v for k, v in (("x_min", f.x_min), ("x_max", f.x_max)) if v is not None})
    return out | ({"levels_m": list(f.levels_m)} if f.levels_m else {})


def load_route(path: str | os.PathLike) -> Route:
    return parse_route(load_json(path), str(path))


def parse_pose_noise(text: str) -> tuple[float, float]:
    """``--pose-noise METRES,DEGREES`` -> (metres, degrees), both >= 0."""
    parts = str(text).split(",")
    try:
        if len(parts) != 2:
            raise ValueError
        metres, degrees = float(parts[0]), float(parts[1])
    except ValueError:
        raise InputError(f"--pose-noise must be METRES,DEGREES (e.g. 0.3,3), got {text!r}") from None
    if not (0 <= metres <= 5 and 0 <= degrees <= 30):
        raise InputError(f"--pose-noise must be within 0-5 metres and 0-30 degrees, got {text!r}")
    return metres, degrees


def perturb(route: Route, metres: float, degrees: float, seed: int = 0) -> Route:
    """The route with every pass's start moved ``metres`` in a random direction on the floor and its heading
    turned by ``degrees`` either way (seeded): a robot's odometry or a hand-drawn plan that is that far off."""
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 0x905E]))
    out = []
    for p in route.passes:
        a = rng.uniform(0, 2 * math.pi)
        turn = degrees * (1.0 if rng.random() < 0.5 else -1.0)
        out.append(
            replace(p, x=p.x + metres * math.cos(a), z=p.z + metres * math.sin(a), heading_deg=p.heading_deg + turn)
        )
    return replace(route, passes=out)
