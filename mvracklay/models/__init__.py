"""The shipped inference models (package data beside this file) and the one place that finds them.

``--checkpoint`` takes a shipped model's name (``mvracklay-disc-4``, ``mvracklay-disc-4-256``) or a path
to a ``.pt`` file; with none, `run`, `predict` and the demo use `DEFAULT_MODEL`. The files are found through
`importlib.resources`, so an installed copy needs no checkout. How each was trained: README.md here.
This module imports no torch (``--help`` stays fast).
"""

from __future__ import annotations

import os
from importlib import resources
from pathlib import Path

from layouts.errors import InputError

#: the models shipped in this package, by name (each ``NAME.pt`` with its record ``NAME.json``)
SHIPPED = ("mvracklay-disc-4", "mvracklay-disc-4-256")
#: what `mvracklay run`, `mvracklay predict` and `make demo` use without ``--checkpoint``
DEFAULT_MODEL = "mvracklay-disc-4"
#: the distance reader (`network.inference.distance`): reads the camera-to-rack distance from footage
DISTANCE_READER = "distance-reader"
CHECKPOINT_HELP = f"a .pt checkpoint (its .json beside) or a shipped model's name: {', '.join(SHIPPED)}"


def shipped_path(name: str) -> Path:
    """Where the shipped model ``name`` lies (whether or not the file is there)."""
    if name not in SHIPPED:
        raise InputError(f"no shipped model named {name!r}: the shipped ones are {', '.join(SHIPPED)}")
    return Path(os.fspath(resources.files(__name__).joinpath(f"{name}.pt")))


def distance_reader_path() -> Path:
    """Where the shipped distance reader lies (whether or not the file is there)."""
    return Path(os.fspath(resources.files(__name__).joinpath(f"{DISTANCE_READER}.pt")))


def default_checkpoint() -> Path:
    """The default model's file (it may be absent in a copy made without the weights)."""
    return shipped_path(DEFAULT_MODEL)


def checkpoint_arg(value: str) -> Path:
    """An argparse ``type``: a shipped model's name becomes its file, anything else stays a path.

    A file of that name in the working folder wins over the shipped model; whether a path exists is
    checked where it is loaded, with the command's own message.
    """
    if value in SHIPPED and not Path(value).exists():
        return shipped_path(value)
    return Path(value)


def resolve_checkpoint(
    name_or_path: str | os.PathLike | None, option: str = "--checkpoint", default: Path | None = None
) -> Path:
    """The checkpoint file to load: a shipped model's name, a path, or None for the default model (``default``,
    else `default_checkpoint`).

    Fails with one line naming ``option`` when the file is not there.
    """
    if name_or_path is None:
        path = default or default_checkpoint()
        if not path.is_file():
            raise InputError(
                f"no trained model shipped ({path.name} is absent from {path.parent}): train one with "
                f"'mvracklay train' (see docs/network.md) and pass {option} PATH"
            )
        return path
    path = checkpoint_arg(os.fspath(name_or_path))
    if path.is_dir():
        raise InputError(f"{option} {name_or_path}: is a folder, not a checkpoint file")
    if not path.is_file():
        raise InputError(f"{option} {name_or_path}: file not found (nor a shipped model: {', '.join(SHIPPED)})")
    return path
