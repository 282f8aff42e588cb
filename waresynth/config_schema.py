"""The declared schema of a generator config, made from the embedded defaults and `waresynth.config`'s table
of ranges, and checked on every config `load_config` returns.

`config_model` builds one pydantic model: an object per section (unknown keys refused), and per key the
type its default has (a number, a ``[low, high]`` range with low <= high, a non-empty list of names, a
non-empty list of ``[r, g, b]`` colours 0-255), every number finite and within the key's range
(`waresynth.config._BOUNDS`), integers where the range says so. `check_config` says what breaks it in one
line naming the source and the key. The per-key checks `waresynth.config` runs while merging a user's
config say the same in their own words, key by key as it is merged; this schema is the whole of it, in one
place, for the merged config.
"""

from __future__ import annotations

from functools import lru_cache
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, create_model, field_validator

from layouts.errors import InputError, first_problem


def _number(bounds: tuple[float, float, bool] | None) -> Any:
    lo, hi, integer = bounds if bounds else (None, None, False)
    limits = {k: v for k, v in (("ge", lo), ("le", hi)) if v is not None and abs(v) != float("inf")}
    return Annotated[float, Field(strict=True, allow_inf_nan=False, multiple_of=1 if integer else None, **limits)]


def _ordered(v: Any) -> Any:
    if isinstance(v, tuple) and len(v) == 2 and v[0] > v[1]:
        raise ValueError(f"[low, high] with low <= high, got {list(v)}")
    return v


def _leaf(key: str, default: Any) -> Any:
    """The type of the config key ``key`` (dotted), from its ``default`` and the range table."""
    from waresynth.config import _NAME_LISTS, _NUMBER_OR_RANGE, TEXTURES, _bounds_for

    section = key.split(".")[0]
    if key in _NAME_LISTS or key.endswith(".textures"):
        names = _NAME_LISTS.get(key) or TEXTURES[section]
        return Annotated[list[Literal[tuple(names)]], Field(min_length=1)]
    if key.endswith("colours"):
        channel = Annotated[float, Field(strict=True, allow_inf_nan=False, ge=0, le=255)]
        return Annotated[list[tuple[channel, channel, channel]], Field(min_length=1)]
    number = _number(_bounds_for(key))
    if isinstance(default, list):
        return tuple[number, number]
    if key in _NUMBER_OR_RANGE:
        return number | tuple[number, number]
    return number


def _model(name: str, defaults: dict[str, Any], prefix: str = "") -> type[BaseModel]:
    fields: dict[str, Any] = {}
    pairs: list[str] = []
    for k, v in defaults.items():
        key = f"{prefix}{k}"
        if isinstance(v, dict):
            fields[k] = (_model(f"{name}_{k}", v, key + "."), ...)
        else:
            kind = _leaf(key, v)
            fields[k] = (kind, ...)
            if "tuple" in str(kind):
                pairs.append(k)
    validators = {"ordered": field_validator(*pairs)(_ordered)} if pairs else {}
    config = ConfigDict(extra="forbid", allow_inf_nan=False)
    return create_model(name, __config__=config, __validators__=validators, **fields)


@lru_cache(maxsize=1)
def config_model() -> type[BaseModel]:
    """The pydantic model of a whole (merged) generator config."""
    from waresynth.config import default_config

    return _model("GeneratorConfig", default_config())


def check_config(cfg: dict[str, Any], source: str) -> None:
    """Refuse (one `InputError` line naming ``source`` and the key) a merged config that breaks the schema."""
    try:
        config_model().model_validate(cfg)
    except ValidationError as e:
        errors = e.errors()
        # a value one of two types may take: the complaint of the type it was (a number out of range, say)
        errors = [err for err in errors if err["type"] not in ("float_type", "tuple_type")] or errors
        # the key's path, without the union members' tags (``constrained-float``, ``tuple[...]``)
        loc = [p for p in errors[0]["loc"] if isinstance(p, int) or not ("[" in p or "-" in p)]
        raise InputError(f"{source}: {first_problem([{**errors[0], 'loc': tuple(loc)}])}") from None
