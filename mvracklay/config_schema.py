"""The declared schema of a command's ``--config`` file, made from the settings dataclasses it fills.

A ``--config`` file (`mvracklay.options.read_config`) holds a command's options by their long names. Its
schema is a pydantic model with one field per option: a settings field's (`mvracklay.settings`: `RunConfig`,
`InferenceSettings`) type, optionality and numeric ``range`` come from the dataclass itself, so the names,
types and ranges live in one place; an option with no settings field behind it (``--quality``, ``--out``)
takes its type from its argparse action (a switch: true / false; choices: one of them; a number). Every
number finite, unknown keys refused. `check_config` says what breaks it in one line naming the file and
the key.
"""

from __future__ import annotations

import argparse
import math
import typing
from dataclasses import fields, is_dataclass
from functools import lru_cache
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, StrictBool, StrictStr, ValidationError, create_model

from layouts.errors import InputError, first_problem


def _number(kind: type, rng: tuple[float | None, float | None] | None) -> Any:
    lo, hi = rng or (None, None)
    bounds = {k: v for k, v in (("ge", lo), ("le", hi)) if v is not None and math.isfinite(v)}
    return Annotated[kind, Field(allow_inf_nan=False, **bounds)]


def _from_annotation(hint: Any, rng: Any) -> Any:
    """A settings field's type as the file may give it (a path as text, a number within its range)."""
    args = typing.get_args(hint)
    if args and type(None) in args:  # Optional: None means "the default" in a config file
        rest = tuple(a for a in args if a is not type(None))
        inner = [_from_annotation(a, rng) for a in rest]
        return typing.Union[(*inner, None)]  # noqa: UP007 (built at run time)
    if args:
        return typing.Union[tuple(_from_annotation(a, rng) for a in args)]  # noqa: UP007
    if hint is bool:
        return StrictBool
    if hint in (int, float):
        return _number(hint, rng)
    if hint is Path or hint is str:
        return StrictStr
    return Any


def _from_action(action: argparse.Action) -> Any:
    """An option's type from its argparse action (options with no settings field behind them)."""
    if action.nargs == 0:
        return StrictBool
    if action.choices is not None:
        return Literal[tuple(action.choices)]
    if action.type in (int, float):
        return _number(action.type, None)
    return Any


def _settings_fields(classes: tuple[type, ...]) -> dict[str, tuple[Any, dict]]:
    """``{argparse dest: (type hint, metadata)}`` of every field with an option in ``classes``."""
    out: dict[str, tuple[Any, dict]] = {}
    for cls in classes:
        hints = typing.get_type_hints(cls)
        for f in fields(cls):
            if is_dataclass(hints[f.name]) or "option" not in f.metadata:
                continue
            out[f.metadata["option"][2:].replace("-", "_")] = (hints[f.name], f.metadata)
    return out


@lru_cache(maxsize=8)
def config_schema(actions: tuple[tuple[str, argparse.Action], ...], classes: tuple[type, ...]) -> type[BaseModel]:
    """The pydantic model of a config file for options ``actions`` (``(long name, action)``), typed from the
    settings dataclasses ``classes`` where an option is one of their fields."""
    known = _settings_fields(classes)
    spec: dict[str, Any] = {}
    for name, action in actions:
        hint, meta = known.get(action.dest, (None, {}))
        if hint is None:
            kind = _from_action(action)
        elif meta.get("invert"):
            kind = StrictBool
        else:
            kind = _from_annotation(hint, meta.get("range"))
            if action.nargs == "?":  # given bare on the command line: true / false in a file
                kind = typing.Union[StrictBool, kind]  # noqa: UP007
        if action.nargs not in (None, 0, "?"):
            kind = typing.Union[kind, list[kind]]  # noqa: UP007
        spec[name] = (typing.Optional[kind], None)  # noqa: UP045 (null: the option's default)
    return create_model(
        "ConfigFile", __config__=ConfigDict(extra="forbid", allow_inf_nan=False, protected_namespaces=()), **spec
    )


def check_config(data: dict, by_name: dict[str, argparse.Action], classes: tuple[type, ...], where: str) -> None:
    """Refuse (one `InputError` line naming ``where`` and the key) a config file's ``data`` that breaks the
    schema made from the options ``by_name`` and the settings dataclasses ``classes``."""
    schema = config_schema(tuple(sorted(by_name.items())), classes)
    try:
        schema.model_validate(data)
    except ValidationError as e:
        errors = e.errors()
        # a value one of several types may take: the complaint of the type it was (a number out of range, say)
        errors = [err for err in errors if err["type"] not in _MISMATCH] or errors
        # options are flat: name the key, not the member of a union the value was tried as
        raise InputError(f"{where}: {first_problem([{**errors[0], 'loc': errors[0]['loc'][:1]}])}") from None


_MISMATCH = ("string_type", "bool_type", "none_required", "list_type", "literal_error", "float_type", "int_type")
