"""Settings as data: each field of a settings dataclass carries its option's name, help, range and argparse
details in its metadata, and the command-line options are made from them (`add_options`, `from_args`).

`InferenceSettings` holds what a model's prediction is asked to do (test-time flip, rack depth, whole
sequence, fusion, the camera's roll / pitch / yaw), the one list `mvracklay run`, `predict`, `evaluate` and
the Python API share; `RunConfig` is one run of `mvracklay run` (the input, the model, the stitching, the
outputs), composing it. Like `mvracklay.options`, this module imports no torch (``--help`` stays fast); the
checks that need the libraries import them when they run.
"""

from __future__ import annotations

import argparse
import math
from dataclasses import MISSING, asdict, dataclass, field, fields
from pathlib import Path
from typing import Any

from layouts.errors import InputError
from mvracklay.models import CHECKPOINT_HELP, DEFAULT_MODEL, checkpoint_arg
from mvracklay.options import (
    CAMERA_HEIGHT_HELP,
    CAMERA_JSON_HELP,
    DEVICES,
    DISTANCE_HELP,
    FLIP_HELP,
    FUSE_HELP,
    FUSE_TAU,
    NO_DEPTH_READ_HELP,
    PITCH_HELP,
    PRECISION_HELP,
    PRECISIONS,
    RACK_DEPTH_HELP,
    ROLL_HELP,
    THREADS_HELP,
    WHOLE_SEQUENCE_HELP,
    YAW_HELP,
    add,
    threads_value,
)
from mvracklay.parallel import RAY_HELP
from mvracklay.threads import AUTO


def option(name: str, help: str, *, invert: bool = False, range: tuple[float | None, float | None] | None = None,
           group: str | None = None, old: tuple[str, ...] = (), aliases: tuple[str, ...] = (),
           **argparse_kwargs: Any) -> dict[str, Any]:  # fmt: skip
    """A field's metadata: its option ``name`` (``--flip-average``; a name without dashes is a positional
    argument), ``help``, ``invert`` (a switch that turns the field off, as ``--no-depth-read`` turns
    ``read_depth`` off), the numeric ``range`` it takes (None = open), the help ``group`` it is listed under,
    ``old`` names still taken with a warning naming ``name`` (``--json`` for ``--json-out``), ``aliases`` taken
    silently and kept out of ``--help`` (``--no-progress`` for ``--quiet``) and any other
    `argparse.ArgumentParser.add_argument` keyword (``type``, ``choices``, ``nargs``, ``required``,
    ``action="store_true"``, ``dest``, ...; ``boolean=True``: ``--x`` / ``--no-x``)."""
    return {"option": name, "help": help, "invert": invert, "range": range, "group": group, "old": old,
            "aliases": aliases, "argparse": argparse_kwargs}  # fmt: skip


def nested(cls: type, *, only: tuple[str, ...] = (), prefix: str = "") -> Any:
    """A field holding settings of their own (``cls``, e.g. `InferenceSettings`), their options listed where the
    field stands (``only``: these fields' options; ``prefix`` put before each help text)."""
    return field(default_factory=cls, metadata={"settings": cls, "only": only, "prefix": prefix})


def setting(name: str, help: str, default: Any = None, **kwargs: Any) -> Any:
    """A settings field with its option (`option`); a list ``default`` is copied for each instance."""
    if isinstance(default, list):
        return field(default_factory=lambda: list(default), metadata=option(name, help, **kwargs))
    return field(default=default, metadata=option(name, help, **kwargs))


def _angle(name: str, text: str) -> Any:
    return field(default=None, metadata=option(f"--{name}", text, metavar="auto|DEG", range=(-45.0, 45.0)))


def json_out_setting(help: str) -> Any:
    """``--json-out PATH``: also write the result as JSON to PATH (the older ``--json PATH`` still taken, with a
    warning: elsewhere ``--json`` prints JSON instead of a table)."""
    return setting("--json-out", help, type=Path, metavar="PATH", old=("--json",))


def quiet_setting(help: str = "hide the progress bar", alias: bool = False) -> Any:
    """``--quiet``: no progress bars (``alias``: ``--no-progress`` also taken, out of ``--help``)."""
    return setting("--quiet", help, False, action="store_true", aliases=("--no-progress",) if alias else ())


def precision_setting(more: str = "") -> Any:
    """``--precision`` (`ComputeSettings`) of a stage that runs a trained network (``more``: added to its help)."""
    return same_as(ComputeSettings, "precision", PRECISION_HELP + more)


def same_as(
    cls: type, name: str, help: str | None = None, *, default: Any = MISSING, group: str | None = None, **shown: Any
) -> Any:
    """A field taking the option ``cls``'s field ``name`` declares (its type, default and range), in another
    settings dataclass; ``help``: as this command words it; ``group``: the help heading it is listed under
    here; ``shown``: its ``metavar`` / ``required`` / ``aliases`` here; ``default``: where a command must keep its
    own (`mvracklay.training.train_network`: a fixed ``--threads``, so that a seed's run repeats)."""
    f = next(f for f in fields(cls) if f.name == name)
    if set(shown) - {"metavar", "required", "aliases"}:
        raise ValueError(f"{name}: only metavar, required and aliases change where an option is shown")
    meta = {**f.metadata, "aliases": shown.pop("aliases", f.metadata["aliases"]), "group": group}
    meta["argparse"] = {**f.metadata["argparse"], **shown}
    if help is not None:
        meta["help"] = help
    if default is not MISSING:
        return field(default=default, metadata=meta)
    if f.default_factory is not MISSING:
        return field(default_factory=f.default_factory, metadata=meta)
    return field(default=f.default, metadata=meta)


@dataclass(frozen=True)
class ComputeSettings:
    """Where a command runs the network and how much of the machine it takes: each option's one declaration
    (`mvracklay.threads.resolve_threads` turns ``auto`` into a count; `network.device.device_for`)."""

    threads: int | str = setting("--threads", THREADS_HELP, AUTO, type=threads_value, metavar="N|auto")
    device: str = setting("--device", "auto = the GPU when CUDA is present", "auto", choices=DEVICES)
    #: the trunk graph's arithmetic (`network.model.frozen.set_precision`)
    precision: str = setting("--precision", PRECISION_HELP, "fp32", choices=PRECISIONS)
    workers: int = setting(
        "--workers", "worker processes (one sequence at a time each)", 1, metavar="W", type=int, range=(1, 256)
    )
    ray: str | None = setting("--ray", RAY_HELP, metavar="ADDRESS")


#: ``--overwrite``'s help where a command replaces ``outputs`` in its folder, an earlier ``command``'s
OVERWRITE_HELP = (
    "write into an output folder holding other files (only {outputs} there are replaced); without it the folder "
    "must be missing, empty or an earlier {command}'s output folder"
)


def overwrite_help(outputs: str, command: str) -> str:
    """``--overwrite``'s help of a command that replaces ``outputs`` in its folder (`mvracklay.outputs.check_out`)."""
    return OVERWRITE_HELP.format(outputs=outputs, command=command)


def spawn_help(rrd: str = "OUT/warehouse.rrd", live: bool = False) -> str:
    """``--spawn``'s help: the viewer opens on the written recording ``rrd`` when done; ``live``: a live source's run
    streams into it as it maps."""
    more = "; a live source: the viewer opens at the start and the recording streams into it as the map grows"
    return f"open the Rerun viewer on {rrd} when done" + (more if live else "")


@dataclass(frozen=True)
class OutputSettings:
    """Where a command writes and what it shows: each option's one declaration (a command words the help of
    its own outputs: `add_options`' ``helps``, `same_as`)."""

    out: Path | None = setting("--out", "output folder", type=Path)
    overwrite: bool = setting("--overwrite", overwrite_help("the outputs", "run"), False, action="store_true")
    rrd: bool = setting("--no-rrd", "do not write the Rerun recording", True, invert=True)
    spawn: bool = setting("--spawn", spawn_help(), False, action="store_true")
    quiet: bool = quiet_setting("no progress bars", alias=True)
    json_out: Path | None = json_out_setting("also write the result as JSON here")
    json: bool = setting("--json", "print JSON instead of a table", False, action="store_true")


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
        """One line naming the option when a setting is out of its range (its type first)."""
        from mvracklay.argtypes import check_dataclass

        check_dataclass(self)  # each field's type: one line, not a TypeError further on
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


def dest(f: Any) -> str | None:
    """The argparse ``dest`` of a settings field (its option's name: ``--no-depth-read`` -> ``no_depth_read``,
    or the ``dest`` its metadata names); None for a field without an option of its own."""
    if "option" not in f.metadata:
        return None
    return f.metadata["argparse"].get("dest") or f.metadata["option"].lstrip("-").replace("-", "_")


def field_default(f: Any) -> Any:
    """A field's default (a fresh one from its factory); None when it has none."""
    if f.default is not MISSING:
        return f.default
    return f.default_factory() if f.default_factory is not MISSING else None


def add_options(
    p: argparse.ArgumentParser,
    cls: type,
    *,
    hidden: bool = False,
    prefix: str = "",
    only: tuple[str, ...] = (),
    helps: dict[str, str] | None = None,
    **shown: dict[str, Any],
) -> None:
    """An option on ``p`` for every field of the settings dataclass ``cls`` (``only``: these fields), its name,
    help, default and argparse details from the field's metadata; ``hidden``: out of ``--help`` (config-file
    keys, `mvracklay.options.add`); ``prefix``: put before each help text; ``helps``: a field's help as this
    command words it; ``shown``: a field's ``metavar`` / ``required`` here (``out={"metavar": "MAP"}``), its
    type, default and range staying the declaration's. Fields with a ``group`` go under that heading (made on
    first use, in field order)."""
    from mvracklay.options import DeprecatedAlias

    groups: dict[str, Any] = {}
    for f in fields(cls):
        if only and f.name not in only:
            continue
        if "settings" in f.metadata:  # settings of their own: their options here
            inner = f.metadata
            add_options(p, inner["settings"], hidden=hidden, prefix=prefix + inner["prefix"], only=inner["only"])
            continue
        if dest(f) is None:
            continue
        meta = dict(f.metadata["argparse"])
        if set(shown.get(f.name, ())) - {"metavar", "required"}:
            raise ValueError(f"{f.name}: only metavar and required change where an option is shown")
        meta.update(shown.get(f.name, {}))
        default = field_default(f)
        if f.metadata["invert"]:
            meta.update(action="store_true")
            default = False
        elif meta.pop("boolean", False):
            meta.update(action=argparse.BooleanOptionalAction)
        group = f.metadata.get("group")
        where = p if group is None else groups.get(group) or groups.setdefault(group, p.add_argument_group(group))
        name = f.metadata["option"]
        if not name.startswith("-"):  # a positional argument: argparse names its dest after it
            meta.pop("dest", None)
        text = (helps or {}).get(f.name, f.metadata["help"])
        add(where, name, default=default, help=prefix + text, hidden=hidden, **meta)
        for old in f.metadata.get("old", ()):
            kept = {k: v for k, v in meta.items() if k in ("type", "metavar", "nargs")}
            where.add_argument(old, dest=dest(f), action=DeprecatedAlias, use=name, default=argparse.SUPPRESS,
                               help=argparse.SUPPRESS, **kept)  # fmt: skip
        for alias in f.metadata.get("aliases", ()):
            where.add_argument(alias, dest=dest(f), default=argparse.SUPPRESS, help=argparse.SUPPRESS, **meta)


def from_args(cls: type, args: argparse.Namespace, only: tuple[str, ...] = (), **given: Any) -> Any:
    """The settings dataclass ``cls`` from parsed options (`add_options`; ``only``: these fields, the others left at
    their defaults, as `nested` lists them); ``given``: fields set otherwise."""
    values = {}
    for f in fields(cls):
        if only and f.name not in only:
            continue
        if f.name not in given and "settings" in f.metadata:
            values[f.name] = from_args(f.metadata["settings"], args, f.metadata["only"])
            continue
        if f.name in given or dest(f) is None or not hasattr(args, dest(f)):
            continue
        value = getattr(args, dest(f))
        values[f.name] = not value if f.metadata["invert"] else value
    return cls(**values, **given)


def check_range(cls: type, settings: Any) -> None:
    """One line naming the option when a field lies outside its declared range or choices (the one statement
    of them: argparse, the ``--config`` schema and the Python API all check against it)."""
    for f in fields(cls):
        if "option" not in f.metadata:
            continue
        value, name = getattr(settings, f.name), f.metadata["option"]
        choices = f.metadata["argparse"].get("choices")
        if choices is not None and value is not None and value not in choices:
            raise InputError(f"{name} must be one of {', '.join(map(str, choices))}, got {value!r}")
        lo, hi = f.metadata.get("range") or (None, None)
        if (lo is None and hi is None) or not isinstance(value, (int, float)) or isinstance(value, bool):
            continue
        if not math.isfinite(value) or (lo is not None and value < lo) or (hi is not None and value > hi):
            said = f"in [{lo}, {hi}]" if lo is not None and hi is not None else f">= {lo}" if hi is None else f"<= {hi}"
            raise InputError(f"{name} must be {said}, got {value!r}")


def every_arg(text: str) -> int | str:
    """``--every``'s argparse type: a count, or ``auto`` (a live source's frames kept a few cm apart)."""
    if text == "auto":
        return text
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"want an integer >= 1 or auto, got {text!r}") from None


def _run(name: str, help: str, **kwargs: Any) -> Any:
    """A `RunConfig` field with its ``mvracklay run`` option (``default`` among ``kwargs``)."""
    default = kwargs.pop("default", None)
    invert, rng = kwargs.pop("invert", False), kwargs.pop("range", None)
    return field(default=default, metadata=option(name, help, invert=invert, range=rng, **kwargs))


@dataclass(frozen=True)
class RunConfig:
    """Settings of one run (see `mvracklay run --help`): the input and model, what the prediction does
    (``inference``, `InferenceSettings`), the stitching and the outputs. Each field with an option carries it
    (`add_options`); ``threads``, ``precision``, ``device`` and ``progress`` take the options all commands
    running a model share (`mvracklay.options`)."""

    checkpoint: Path | None = _run(
        "--checkpoint", f"{CHECKPOINT_HELP}; default: the shipped {DEFAULT_MODEL}", type=checkpoint_arg
    )
    camera: Path | None = _run("--camera", CAMERA_JSON_HELP, type=Path)
    mode: str = _run("--mode", "network inference mode", default="stream", choices=["stream", "window"])
    max_frames: int = _run("--max-frames", "process at most N frames (0 = all)", default=0, type=int, range=(0, None))
    #: process every N-th frame of the input (`mvracklay.frames.every_nth`)
    every: int | str = _run(
        "--every",
        "process every N-th input frame (video at 30 fps moves a few cm a frame); --max-frames counts the frames "
        "kept; a live source also takes auto: frames kept a few cm apart, at the camera speed the network reads",
        default=1, type=every_arg, metavar="N|auto", range=(1, None),
    )  # fmt: skip
    layout_size: int = _run(
        "--layout-size", "resolution D of the written layouts (0 = the model's)", default=0, type=int
    )
    #: camera to rack front, metres; None = recorded, or read (`mvracklay.camera.FrameDistances`)
    distance: float | None = _run("--distance", DISTANCE_HELP, type=float, metavar="M")
    #: the camera's height above the floor, metres: the distance from the floor line
    camera_height: float | None = _run("--camera-height", CAMERA_HEIGHT_HELP, type=float, metavar="M")
    distance_reader: Path | None = _run(
        "--distance-reader", "the distance reader to read footage's distance with (default: the shipped one)",
        type=Path, metavar="FILE",
    )  # fmt: skip
    #: what the prediction does: flip, rack depth, depth reading, whole sequence, fusion, the camera's angles
    inference: InferenceSettings = field(default_factory=InferenceSettings)
    rrd: bool = same_as(OutputSettings, "rrd", "do not write warehouse.rrd")
    rgb: bool = _run("--no-rgb", "do not log the RGB frames to Rerun", default=True, invert=True)
    map_every: int = _run(
        "--map-every", "log the growing map to Rerun every N frames", default=1, type=int, range=(1, None)
    )
    opening: bool = _run(
        "--no-opening",
        "stitch with the ground-truth settings instead of the clean-up for network output (StitchConfig.noisy)",
        default=True, invert=True,
    )  # fmt: skip
    board_thickness: float = _run(
        "--board-thickness", "assumed shelf board thickness (metres)", default=0.06, type=float, range=(0.0, 1.0)
    )
    threads: int = 2
    precision: str = "fp32"  #: the trunk graph's arithmetic, fp32 or bf16 (`network.model.frozen.set_precision`)
    device: str = "auto"  #: auto (the GPU when CUDA is present), cpu or cuda
    progress: bool = True

    @classmethod
    def build(cls, **values: Any) -> RunConfig:
        """A RunConfig from field names, `InferenceSettings`' among them (``rack_depth=1.0``); one line naming
        the unknown ones."""
        inner = {f.name for f in fields(InferenceSettings)}
        outer = {f.name for f in fields(cls)} - {"inference"}
        unknown = sorted(set(values) - inner - outer)
        if unknown:
            known = ", ".join(sorted(inner | outer))
            raise InputError(f"unknown option(s) {', '.join(unknown)}: RunConfig takes {known}")
        settings = InferenceSettings(**{k: v for k, v in values.items() if k in inner})
        return cls(**{k: v for k, v in values.items() if k in outer}, inference=settings)

    def validate(self) -> None:
        """One line naming the option when a setting is out of its range (its type first)."""
        from mvracklay.argtypes import check_dataclass

        check_dataclass(self)  # each field's type: one line, not a TypeError further on
        from network.inference.distance import check_camera_height, check_distance
        from network.precision import check_precision

        check_range(RunConfig, self)  # the ranges and choices its fields declare
        if self.every != "auto" and not isinstance(self.every, int):
            raise InputError(f"--every must be an integer >= 1 (or auto, for a live source), got {self.every!r}")
        if self.layout_size and not 8 <= self.layout_size <= 1024:  # 0: the model's
            raise InputError(f"--layout-size must be in [8, 1024], got {self.layout_size}")
        check_distance(self.distance)
        check_camera_height(self.camera_height)
        self.inference.validate()
        if self.threads < 1:
            raise InputError(f"--threads must be >= 1, got {self.threads}")
        check_precision(self.precision)
        if self.device not in DEVICES:
            raise InputError(f"--device must be one of {', '.join(DEVICES)}, got {self.device!r}")


#: the help heading of the live sources' options
LIVE_GROUP = "live source (a camera or a stream URL)"
#: the port a live run's Rerun server listens on (``--serve`` given bare), Rerun's own default
SERVE_PORT = 9876


@dataclass(frozen=True)
class LiveSettings:
    """What a live run (`mvracklay.live`: INPUT a camera or a stream URL) adds to `RunConfig`: when it ends, how it
    reconnects, the buffer between the stream and the network and the Rerun server a remote viewer connects to."""

    idle_timeout: float = _run(
        "--idle-timeout", "end the run (saving the map) when the stream has been quiet this long",
        default=5.0, type=float, metavar="S", range=(0.0, None), group=LIVE_GROUP,
    )  # fmt: skip
    serve: int | None = _run(
        "--serve",
        "serve the recording as it grows (Rerun's gRPC server on PORT, default 9876) for a viewer "
        "on another machine: rerun --connect rerun+http://HOST:PORT/proxy",
        type=int, nargs="?", const=SERVE_PORT, metavar="PORT", range=(1, 65535), group=LIVE_GROUP,
    )  # fmt: skip
    retries: int = _run(
        "--retries", "a live source: reopen a lost connection this many times before ending the run",
        default=3, type=int, metavar="N", range=(0, None),
    )  # fmt: skip
    live_buffer: int = _run(
        "--live-buffer",
        "a live source: frames waiting for the network at most; when it falls behind the oldest is dropped",
        default=2, type=int, metavar="N", range=(1, None),
    )  # fmt: skip

    def validate(self) -> None:
        """One line naming the option when a setting is out of its range (its type first)."""
        from mvracklay.argtypes import check_dataclass

        check_dataclass(self)
        if not self.idle_timeout > 0:
            raise InputError(f"--idle-timeout must be > 0 seconds, got {self.idle_timeout!r}")
        check_range(LiveSettings, self)
