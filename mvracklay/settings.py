"""Settings as data: each field of a settings dataclass carries its option's name, help, range and argparse
details in its metadata, and the command-line options are made from them (`add_options`, `from_args`).

`InferenceSettings` holds what a model's prediction is asked to do (test-time flip, rack depth, whole
sequence, fusion, the camera's roll / pitch / yaw), the one list `mvracklay run`, `predict` and the Python
API share. Like `mvracklay.options`, this module imports no torch (``--help`` stays fast); the checks that
need the libraries import them when they run.
"""

from __future__ import annotations

import argparse
import math
from dataclasses import MISSING, asdict, dataclass, field, fields
from typing import Any

from layouts.errors import InputError
from mvracklay.options import (
    FLIP_HELP,
    FUSE_HELP,
    FUSE_TAU,
    NO_DEPTH_READ_HELP,
    PITCH_HELP,
    RACK_DEPTH_HELP,
    ROLL_HELP,
    WHOLE_SEQUENCE_HELP,
    YAW_HELP,
    add,
)


def option(name: str, help: str, *, invert: bool = False, range: tuple[float | None, float | None] | None = None,
           **argparse_kwargs: Any) -> dict[str, Any]:  # fmt: skip
    """A field's metadata: its option ``name`` (``--flip-average``), ``help``, ``invert`` (a switch that turns the
    field off, as ``--no-depth-read`` turns ``read_depth`` off), the numeric ``range`` it takes (None = open)
    and any other `argparse.ArgumentParser.add_argument` keyword."""
    return {"option": name, "help": help, "invert": invert, "range": range, "argparse": argparse_kwargs}


def _angle(name: str, text: str) -> Any:
    return field(default=None, metadata=option(f"--{name}", text, metavar="auto|DEG", range=(-45.0, 45.0)))


@dataclass(frozen=True)
class InferenceSettings:
    """What a model's prediction is asked to do, frame by frame (`network.inference.predictor.Predictor`)."""

    #: average each frame with its mirror image (test-time flip)
    flip: bool = field(default=False, metadata=option("--flip-average", FLIP_HELP, boolean=True))
    #: a known rack depth, metres (`layouts.rackdepth`); None = read, or as the decoder draws it
    rack_depth: float | None = field(
        default=None, metadata=option("--rack-depth", RACK_DEPTH_HELP, type=float, metavar="M", range=(0.0, None))
    )
    #: without a known depth, read the rack depth and box depths with the model's heads
    read_depth: bool = field(default=True, metadata=option("--no-depth-read", NO_DEPTH_READ_HELP, invert=True))
    #: the depths from every frame, not only the frames so far (offline)
    whole_sequence: bool = field(default=False, metadata=option("--whole-sequence", WHOLE_SEQUENCE_HELP, boolean=True))
    #: neighbouring frames' layouts fused, weights exp(-frames apart / tau); 0 = off
    fuse_tau: float = field(
        default=0.0,
        metadata=option(
            "--fuse-frames", FUSE_HELP, type=float, nargs="?", const=FUSE_TAU, metavar="TAU", range=(0.0, None)
        ),
    )
    #: the camera's roll, pitch (optical axis up > 0) and yaw (turned right > 0), levelled (`network.inference.roll`):
    #: degrees or "auto"; None = a generated sequence's recorded angle, else "auto"
    roll: float | str | None = _angle("roll", ROLL_HELP)
    pitch: float | str | None = _angle("pitch", PITCH_HELP)
    yaw: float | str | None = _angle("yaw", YAW_HELP)

    def validate(self) -> None:
        """One line naming the option when a setting is out of its range."""
        from layouts.rackdepth import check_rack_depth
        from network.inference.fusion import check_tau
        from network.inference.roll import check_angle

        if self.rack_depth is not None:
            check_rack_depth(self.rack_depth)
        check_tau(self.fuse_tau, "--fuse-frames")
        for name in ("roll", "pitch", "yaw"):
            check_angle(getattr(self, name), f"--{name}")
        check_range(InferenceSettings, self)

    def predictor_kwargs(self) -> dict[str, Any]:
        """The `Predictor`'s keywords (the angles as given: `network.inference.roll.resolve_angles` settles them)."""
        return asdict(self)


def dest(f: Any) -> str:
    """The argparse ``dest`` of a settings field (its option's name: ``--no-depth-read`` -> ``no_depth_read``)."""
    return f.metadata["option"][2:].replace("-", "_")


def add_options(
    p: argparse.ArgumentParser, cls: type, *, hidden: bool = False, prefix: str = "", only: tuple[str, ...] = ()
) -> None:
    """An option on ``p`` for every field of the settings dataclass ``cls`` (``only``: these fields), its name,
    help, default and argparse details from the field's metadata; ``hidden``: out of ``--help`` (config-file
    keys, `mvracklay.options.add`); ``prefix``: put before each help text."""
    for f in fields(cls):
        if only and f.name not in only:
            continue
        meta = dict(f.metadata["argparse"])
        default = None if f.default is MISSING else f.default
        if f.metadata["invert"]:
            meta.update(action="store_true")
            default = False
        elif meta.pop("boolean", False):
            meta.update(action=argparse.BooleanOptionalAction)
        add(p, f.metadata["option"], default=default, help=prefix + f.metadata["help"], hidden=hidden, **meta)


def from_args(cls: type, args: argparse.Namespace, **given: Any) -> Any:
    """The settings dataclass ``cls`` from parsed options (`add_options`); ``given``: fields set otherwise."""
    values = {}
    for f in fields(cls):
        if f.name in given or not hasattr(args, dest(f)):
            continue
        value = getattr(args, dest(f))
        values[f.name] = not value if f.metadata["invert"] else value
    return cls(**values, **given)


def check_range(cls: type, settings: Any) -> None:
    """One line naming the option when a numeric field lies outside its metadata's range."""
    for f in fields(cls):
        lo, hi = f.metadata.get("range") or (None, None)
        value = getattr(settings, f.name)
        if not isinstance(value, (int, float)) or isinstance(value, bool):
            continue
        if not math.isfinite(value) or (lo is not None and value < lo) or (hi is not None and value > hi):
            said = f"in [{lo if lo is not None else '-inf'}, {hi if hi is not None else 'inf'}]"
            raise InputError(f"{f.metadata['option']} must be {said}, got {value!r}")
