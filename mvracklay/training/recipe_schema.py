"""The declared schema of a training recipe (the TOML of ``mvracklay train --recipe``), checked before anything runs.

`recipe_problems` validates a recipe as read (after ``--set`` overrides) with pydantic and says every problem,
one line each, naming the file, the part (``data 'train'``, ``stage 2 (fit-box-depth)``, ``[budget]``) and
the key: unknown keys, values of the wrong type, numbers that are not finite (TOML writes ``nan``, ``inf``),
sizes and counts < 1, seeds and minutes < 0, a stage id with dots, no stages. What needs the recipe as a
whole (ids unique, groups contiguous, which stages take minutes, the budget's stage names, the stages'
options) is checked by `mvracklay.training.recipe` and the stages themselves.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, StrictBool, StrictInt, StrictStr, ValidationError

from layouts.errors import first_problem

Minutes = Annotated[float, Field(strict=True, allow_inf_nan=False, ge=0)]
Count = Annotated[StrictInt, Field(ge=1)]
ByPrecision = dict[Literal["bf16", "fp32"], Minutes]


class _Doc(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)


class DataDoc(_Doc):
    """One ``[data.NAME]`` table: the arguments of ``mvracklay generate``."""

    folder: StrictStr
    sequences: Count
    frames: Count
    size: Count
    seed: Annotated[StrictInt, Field(ge=0)]
    config: StrictStr = ""
    layout_size: Count | None = None


class StageDoc(_Doc):
    """One ``[[stages]]`` entry."""

    stage: StrictStr
    id: Annotated[StrictStr, Field(min_length=1, pattern=r"^[^.]*$")] | None = None
    minutes: Minutes | ByPrecision | Literal["budget"] | None = None
    group: StrictStr | None = None
    lane: StrictInt | None = None
    skip: StrictBool = False
    unless_exists: StrictStr | None = None
    log: StrictStr | None = None
    args: list[Any] = []
    options: dict[str, Any] = {}


class BudgetDoc(_Doc):
    """``[budget]``: the training minutes a recipe may spend."""

    total: Minutes
    margin: Minutes = 0.0
    fit_ratio: Minutes | ByPrecision = 0.0
    prior: list[StrictStr] = []
    count: list[StrictStr] = []


class RecipeDoc(_Doc):
    description: StrictStr = ""
    precision: Literal["auto", "bf16", "fp32"] = "auto"
    workers: Count = 1
    requires: list[StrictStr] = []
    vars: dict[str, Any] = {}
    data: dict[str, DataDoc] = {}
    budget: BudgetDoc | None = None
    defaults: dict[str, dict[str, Any]] = {}
    stages: Annotated[list[StageDoc], Field(min_length=1)]


_KNOWN = {
    "": RecipeDoc.model_fields,
    "data": DataDoc.model_fields,
    "stages": StageDoc.model_fields,
    "budget": BudgetDoc.model_fields,
}
#: complaints of the other members of a union when the value is one of its types (the member's own complaint wins)
_MISMATCH = ("string_type", "bool_type", "int_type", "float_type", "dict_type", "literal_error", "none_required")


def _part(loc: tuple, raw: dict) -> tuple[str, str, tuple]:
    """``(section, where, rest of loc)``: where in the recipe an error's location points, in its own words."""
    if loc[:1] == ("data",) and len(loc) >= 3:
        return "data", f"data {loc[1]!r}", loc[2:]
    if loc[:1] == ("stages",) and len(loc) >= 3 and isinstance(loc[1], int):
        entry = raw["stages"][loc[1]]
        sid = entry.get("id", entry.get("stage")) if isinstance(entry, dict) else None
        return "stages", f"stage {loc[1] + 1}" + (f" ({sid})" if isinstance(sid, str) else ""), loc[2:]
    if loc[:1] == ("budget",) and len(loc) >= 2:
        return "budget", "[budget]", loc[1:]
    return "", "", loc


def recipe_problems(raw: dict, path: Path) -> list[str]:
    """Every way ``raw`` (a recipe as read) breaks `RecipeDoc`, one line each naming ``path``, the part and the key."""
    try:
        RecipeDoc.model_validate(raw)
    except ValidationError as e:
        errors = e.errors()
    else:
        return []
    by_key: dict[tuple, list[dict]] = {}
    for err in errors:
        section, where, rest = _part(tuple(err["loc"]), raw)
        by_key.setdefault((section, where, rest[:1]), []).append({**err, "loc": rest})
    lines = []
    for (section, where, key), errs in by_key.items():
        err = next((x for x in errs if x["type"] not in _MISMATCH), errs[0])
        head = f"{path}: {where}: " if where else f"{path}: "
        if err["type"] == "extra_forbidden":
            lines.append(f"{head}unknown key {key[0]!r} (known: {', '.join(_KNOWN[section])})")
        elif err["type"] == "missing" and key:
            lines.append(f"{head}missing key {key[0]!r}")
        else:
            rest = err["loc"][1:] if len(err["loc"]) > 1 and isinstance(err["loc"][1], int) else ()
            said = first_problem([{**err, "loc": rest}])
            lines.append(f"{head}key {key[0]!r}: {said}" if key else f"{head}{said}")
    return lines
