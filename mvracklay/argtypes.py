"""Argument types checked against the annotations, so a wrong type is one `InputError` line, not a `TypeError`
deep inside (``mvracklay.reconstruct(frames, distance="2.5")``, ``RunConfig(threads="two")``).

Checked: ``float`` (an int or float, numpy's too; not a bool), ``int`` (not a bool), ``bool``, ``str`` and
paths (``Path`` / ``os.PathLike``: a str or a path object), and unions of them with None. Other annotations
(arrays, iterables, dicts, classes) are left to the code that uses them.
"""

from __future__ import annotations

import dataclasses
import numbers
import os
import types
import typing
from pathlib import Path
from typing import Any

from layouts.errors import InputError

_NAMES = {
    float: "a number",
    int: "an integer",
    bool: "True or False",
    str: "a string",
    Path: "a path",
    os.PathLike: "a path",
}


def _accepts(kind: Any, value: Any) -> bool | None:
    """Whether ``value`` fits the plain type ``kind``; None when ``kind`` is not one this module checks."""
    if kind is type(None):
        return value is None
    if kind is float:
        return isinstance(value, numbers.Real) and not isinstance(value, bool)
    if kind is int:
        return isinstance(value, numbers.Integral) and not isinstance(value, bool)
    if kind is bool:
        return isinstance(value, bool) or type(value).__name__ == "bool_"
    if kind is str:
        return isinstance(value, str)
    if kind in (Path, os.PathLike):
        return isinstance(value, (str, os.PathLike))
    return None


def check_value(name: str, annotation: Any, value: Any) -> None:
    """One line when ``value`` does not fit ``annotation`` (a checked type or a union of them)."""
    union = typing.get_origin(annotation) in (typing.Union, types.UnionType)
    kinds = typing.get_args(annotation) if union else (annotation,)
    verdicts = [_accepts(k, value) for k in kinds]
    if None in verdicts or any(verdicts):
        return  # fits, or a type checked elsewhere
    want = " or ".join(dict.fromkeys(_NAMES.get(k, "None") for k in kinds))
    raise InputError(f"{name}: want {want}, got {type(value).__name__} {value!r}"[:200])


def check_dataclass(obj: Any) -> None:
    """Check every field of a dataclass instance against its annotation."""
    hints = typing.get_type_hints(type(obj))
    for f in dataclasses.fields(obj):
        check_value(f.name, hints[f.name], getattr(obj, f.name))


def check_call(func: Any, values: dict[str, Any]) -> None:
    """Check the arguments ``values`` (``locals()`` at the top of ``func``) against ``func``'s annotations."""
    hints = typing.get_type_hints(func)
    for name, value in values.items():
        if name in hints and name != "return":
            check_value(name, hints[name], value)
