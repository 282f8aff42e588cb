"""Command-line options shared by several commands: one name, one help text, one default each.

The library packages keep only the functions that do the work (`network.inference.fusion.check_tau`,
`network.inference.roll.resolve_angles`, `layouts.rackdepth.check_rack_depth`, ...); the argparse side
lives here. This module imports neither torch nor any other heavy package, so `mvracklay --help` and
each command's ``--help`` start fast: the few library constants a help text needs are repeated here,
and tests/test_cli_light.py checks that they equal the library's.
"""

from __future__ import annotations

import argparse
import difflib
import sys
from pathlib import Path

from layouts.errors import InputError

#: `network.precision.PRECISIONS`: the arithmetic a command's ``--precision`` takes
PRECISIONS = ("fp32", "bf16")
#: `network.inference.fusion.FUSE_TAU`: what a bare ``--fuse-frames`` gives (frames)
FUSE_TAU = 1.0
#: the devices ``--device`` takes (`network.device.device_for`)
DEVICES = ("auto", "cpu", "cuda")

FLIP_HELP = (
    "also run every frame mirrored left-right and average the logits (test-time flip; measured on the "
    "held-out set: +0.3 to +0.8 mIoU per view and class, at half the frame rate)"
)
WHOLE_SEQUENCE_HELP = (
    "read the rack depth and box depths from every frame of the sequence, not only the frames so far "
    "(offline: layouts come once the whole sequence is read, ~0.3 MB held per frame; measured +0.2-1.4 top "
    "rack, +0.3-1.5 top box mIoU)"
)
RACK_DEPTH_HELP = (
    "known rack depth in metres (racking spec sheet or one tape measure): each shelf's top-view footprint is "
    "redrawn that deep and its boxes move with the front edge; the model's own reading of the depth is its "
    "largest top-view error; unset, the layouts keep the depth the model reads"
)
NO_DEPTH_READ_HELP = (
    "keep the depths the top-view decoder draws; by default a model with a back-edge head reads the rack depth "
    "from the shelf boards' back edges over the frames so far and redraws the top views at it, and a model with "
    "a box-depth head moves each box's back to the depth the frames so far showed"
)
PRECISION_HELP = (
    "the trunk's arithmetic at inference on the CPU: fp32 or bf16, where the CPU computes bf16 natively "
    "(AVX512-BF16, AMX) the trunk in about half the time (a frame ~1.2x as fast), its features ~1.5 %% off fp32's; "
    "emulated and far slower elsewhere"
)
FUSE_HELP = (
    "average each frame's layouts with its neighbours' along the row, shifted by the camera motion read from the "
    f"images, weights exp(-frames apart / TAU) (TAU {FUSE_TAU:g} when none is given; off by default). Measured: "
    "+0.2-0.9 top box mIoU held out, but the stitched maps lose 0.01-0.03 box precision and recall at TAU 1"
)
ROLL_HELP = (
    "the camera's roll about its optical axis, levelled before the network: 'auto' reads it from the frames "
    "(the edges of boards, uprights and boxes), a number gives it in degrees (the image turned counter-clockwise), "
    "0 takes the camera as level. Default (as for --pitch and --yaw): a generated sequence's recorded angle (0 "
    "unless its config turned the camera), auto for other footage"
)
PITCH_HELP = (
    "the camera's pitch, levelled before the network: 'auto' reads it from the frames (the uprights' lean "
    "across the image), a number gives it in degrees (optical axis tilted up > 0; e.g. from the mount or an "
    "IMU), 0 takes it as level. Default as --roll"
)
YAW_HELP = (
    "the camera's yaw, levelled before the network: 'auto' reads it from the frames (the boards' convergence), "
    "a number gives it in degrees (turned right > 0, away from square to the racks; e.g. from the mount), 0 "
    "takes it as level. Default as --roll"
)
DISTANCE_HELP = (
    "camera to rack front in metres, if you know it; default: a generated sequence's recorded distances, "
    "else read from the first frames (the distance reader) and printed; a wrong distance scales every length "
    "of the map"
)
CAMERA_HEIGHT_HELP = (
    "the camera's height above the floor in metres (a robot's mount): the distance then follows from where "
    "the floor meets the racks in the first frames, when that line is in view (else it is read as without)"
)
CAMERA_JSON_HELP = (
    "JSON with the camera intrinsics: fx, fy, cx, cy in pixels and the width, height they refer to; "
    "with a lens's distortion beside them (OpenCV's k1, k2, p1, p2, k3, as a calibration gives), every "
    "frame is undistorted before the network (~13 ms a 640x360 frame; wider ones shrunk to 640 first)"
)


def add(p: argparse.ArgumentParser, *names: str, help: str, hidden: bool = False, **kwargs) -> argparse.Action:
    """``p.add_argument``; a ``hidden`` option stays out of ``--help`` (a config-file key, still parseable)
    and keeps its text for ``--help-all``."""
    action = p.add_argument(*names, help=argparse.SUPPRESS if hidden else help, **kwargs)
    action.full_help = help  # type: ignore[attr-defined]
    return action


class HelpAllAction(argparse._HelpAction):
    """``--help-all``: the help with the hidden options too."""

    def __call__(self, parser, namespace, values, option_string=None) -> None:
        for action in parser._actions:
            if action.help == argparse.SUPPRESS and getattr(action, "full_help", None):
                action.help = action.full_help
        parser.print_help()
        parser.exit()


def add_help_all_option(p: argparse.ArgumentParser) -> None:
    """``--help-all`` on a command that hides options from ``--help``."""
    p.add_argument("--help-all", action=HelpAllAction, help="show the help with every option, the hidden ones too")


THREADS_HELP = (
    "CPU threads for the network: a count, or auto (default): the cores free of other work when the command "
    "starts, all of them when none is (beside 1 busy process on 2 cores, 1 thread kept its idle speed where 2 "
    "fell below half of theirs); idle OpenMP threads sleep rather than spin (OMP_WAIT_POLICY=PASSIVE unless set)"
)


def threads_value(text: str) -> int | str:
    """``--threads``'s argparse type: a count >= 1 or ``auto`` (`mvracklay.threads.parse_threads`)."""
    from mvracklay.threads import parse_threads

    try:
        return parse_threads(text)
    except InputError as e:
        raise argparse.ArgumentTypeError(str(e).removeprefix("--threads ")) from None


def check_counts(settings: object, *names: str) -> None:
    """Refuse, in one line naming the option, the first of the fields ``names`` of ``settings`` (a command's or
    stage's parsed options: thread counts, sequence counts, every N-th frame) that is below 1."""
    for name in names:
        value = getattr(settings, name)
        if value < 1:
            raise InputError(f"--{name.replace('_', '-')} must be >= 1, got {value}")


class DeprecatedAlias(argparse.Action):
    """An old option name still taken (out of ``--help``), with one line on stderr naming the one to use."""

    def __init__(self, option_strings: list[str], dest: str, use: str, **kwargs) -> None:
        super().__init__(option_strings, dest, **kwargs)
        self.deprecated_for = use  #: the option to use instead (recipes still take the old name)

    def __call__(self, parser, namespace, values, option_string=None) -> None:
        print(f"warning: {option_string} is deprecated here: use {self.deprecated_for} (same value)", file=sys.stderr)
        setattr(namespace, self.dest, values)


def config_value(action: argparse.Action, key: str, value: object, where: str) -> object:
    """A config file's ``value`` for ``action`` as the command line would give it (one line when it cannot be)."""
    where = f"{where}: " if where else ""  # none: ``key`` says it all
    if value is None:
        return action.default
    if action.nargs == 0 or (action.nargs == "?" and isinstance(value, bool)):
        if not isinstance(value, bool):
            raise InputError(f"{where}{key} is a switch: want true or false, got {value!r}")
        if isinstance(action.const, bool):  # store_true / store_false
            return value if action.const else not value
        if action.nargs == "?":  # e.g. fuse-frames: true = given bare, false = off
            return action.const if value else action.default
        return value  # BooleanOptionalAction
    items = value if isinstance(value, list) and action.nargs not in (None, "?") else [value]
    out = []
    for item in items:
        if isinstance(item, (bool, list, dict)):
            raise InputError(f"{where}{key} wants a value like its option's, got {item!r}")
        try:
            got = action.type(str(item)) if callable(action.type) else str(item)
        except (TypeError, ValueError, argparse.ArgumentTypeError):
            raise InputError(f"{where}{key}: not a valid value: {item!r}") from None
        if action.choices is not None and got not in action.choices:
            raise InputError(f"{where}{key} must be one of {', '.join(map(str, action.choices))}, got {item!r}")
        out.append(got)
    return out if items is value else out[0]


def read_config(
    path: str | Path,
    parser: argparse.ArgumentParser,
    exclude: tuple[str, ...] = ("config",),
    settings: tuple[type, ...] = (),
) -> dict:
    """A ``--config`` FILE (JSON, or TOML by its ``.toml`` suffix) of options by their long names
    (``"flip-average": true``, ``rack-depth = 1.1``), as ``{dest: value}`` for ``parser.set_defaults``.

    Unknown keys, values the option would refuse, and values outside the declared schema
    (`mvracklay.config_schema`, typed from the settings dataclasses ``settings``: not finite, out of a
    field's range) fail with one line naming the file and the key.
    """
    path = Path(path)
    where = f"--config {path}"
    if not path.is_file():
        raise InputError(f"{where}: file not found")
    try:
        text = path.read_text(encoding="utf-8")
        if path.suffix.lower() == ".toml":
            from layouts.fileio import loads_toml

            data = loads_toml(text, where)
        else:
            from layouts.fileio import loads_json

            data = loads_json(text, where)
    except InputError:
        raise
    except (OSError, UnicodeDecodeError, ValueError, RecursionError) as e:
        raise InputError(
            f"{where}: not a readable {'TOML' if path.suffix.lower() == '.toml' else 'JSON'} file ({e})"
        ) from None
    if not isinstance(data, dict):
        raise InputError(f"{where}: want a table of option names and values, got {type(data).__name__}")
    by_name = {
        s[2:]: a
        for a in parser._actions
        for s in a.option_strings
        if s.startswith("--")
        and s[2:] not in exclude
        and not isinstance(a, (argparse._HelpAction, argparse._VersionAction))
    }
    out = {}
    for key, value in data.items():
        action = by_name.get(key)
        if action is None:
            close = difflib.get_close_matches(str(key).replace("_", "-"), by_name, n=1)
            hint = f" (did you mean {close[0]!r}?)" if close else f"; known: {', '.join(sorted(by_name))}"
            raise InputError(f"{where}: unknown option {key!r}{hint}")
        out[action.dest] = config_value(action, key, value, where)
    from mvracklay.config_schema import check_config

    check_config(data, by_name, settings, where)
    return out
