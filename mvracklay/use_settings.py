"""The options of the commands that use a model or a map (``run``, ``predict``, ``reconstruct``, ``map``, ``diff``,
``free-space``): one settings dataclass each, every field with its option's declaration (`mvracklay.settings`), the
options the commands share taken from their one declaration (`same_as`: `ComputeSettings`, `OutputSettings`,
`RunConfig`). ``predict``'s settings are also what `mvracklay.inference.predict_folder` takes. Like
`mvracklay.settings`, this module imports no torch (``--help`` stays fast).
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from pathlib import Path

from layouts.errors import InputError
from mvracklay.command_settings import EvalReconstructionSettings
from mvracklay.presets import PRESETS
from mvracklay.settings import (
    ComputeSettings,
    InferenceSettings,
    OutputSettings,
    RunConfig,
    check_range,
    nested,
    overwrite_help,
    same_as,
    setting,
    spawn_help,
)


@dataclass(frozen=True)
class RunCommandSettings:
    """``mvracklay run``'s options beside `RunConfig`'s and `LiveSettings`': the input, where it writes, the preset
    and the config file."""

    input: str | None = setting(
        "input",
        "sequence folder, image folder, video file, or live: a camera (/dev/video0 or 0) or a stream URL",
        metavar="INPUT",
    )  # fmt: skip
    out: Path | None = same_as(OutputSettings, "out", "output folder (required)")
    overwrite: bool = same_as(OutputSettings, "overwrite", overwrite_help("run's outputs", "run"))
    quality: str | None = setting(
        "--quality",
        "preset: default (online, as the network streams), offline (every frame's depths, test-time flip "
        "and fused neighbours: best layouts, about half the speed), fast (the decoder's own depths, a lighter "
        "recording); default: default",
        choices=tuple(PRESETS),
    )  # fmt: skip
    config: Path | None = setting(
        "--config",
        'JSON or TOML file of options by their long names, e.g. {"rack-depth": 1.1, "quality": "offline"}; '
        "options given here win over the file's, the file's over the --quality preset's",
        type=Path, metavar="FILE",
    )  # fmt: skip
    spawn: bool = same_as(OutputSettings, "spawn", spawn_help(live=True))


@dataclass(frozen=True)
class PredictSettings:
    """``mvracklay predict``, and what `mvracklay.inference.predict_folder` writes: the layouts of INPUT's frames."""

    seq_dir: Path | None = setting(
        "seq_dir", "sequence folder, image folder, image or video file", type=Path, metavar="INPUT"
    )
    checkpoint: Path | None = same_as(RunConfig, "checkpoint")
    out: Path | None = same_as(OutputSettings, "out", "layout folder to write", required=True)
    mode: str = same_as(RunConfig, "mode", "streaming (memory carried frame to frame) or windowed (the paper)")
    layout_size: int = same_as(RunConfig, "layout_size", "D of the written layouts (0 = the model's)")
    camera: Path | None = same_as(
        RunConfig,
        "camera",
        "the camera intrinsics: a JSON file (as `run --camera`: fx, fy, cx, cy, width, height and a lens's "
        "distortion beside them, OpenCV's k1, k2, p1, p2, k3: every frame is then undistorted first), or fx,fy,cx,cy "
        "in pixels of the input images",
        metavar="FILE|fx,fy,cx,cy", aliases=("--intrinsics",),
    )  # fmt: skip
    distance: float | None = same_as(
        RunConfig, "distance", "camera to rack front in metres (default: meta.json, else read from the frames)",
        metavar="DISTANCE",
    )  # fmt: skip
    #: --flip-average, --rack-depth, --no-depth-read, --whole-sequence, --fuse-frames, --roll, --pitch, --yaw
    inference: InferenceSettings = nested(InferenceSettings)
    threads: int | str = same_as(ComputeSettings, "threads")
    every: int | str = same_as(
        RunConfig, "every", "predict every N-th input frame (written as 0, 1, 2, ...)", metavar="N"
    )
    precision: str = same_as(ComputeSettings, "precision")
    device: str = same_as(ComputeSettings, "device")
    quiet: bool = same_as(OutputSettings, "quiet", "hide the progress bar")

    def validate(self) -> None:
        """One line naming the option when a setting is out of its range (checked before the model loads)."""
        from network.inference.distance import check_distance

        self.inference.validate()
        check_range(PredictSettings, self)
        check_distance(self.distance)
        if self.layout_size and not 8 <= self.layout_size <= 1024:
            raise InputError(f"--layout-size must be in [8, 1024], got {self.layout_size}")
        if not isinstance(self.every, int):
            raise InputError(f"--every must be an integer >= 1 (auto is for a live source), got {self.every!r}")


@dataclass(frozen=True)
class ReconstructSettings:
    """``mvracklay reconstruct``: a sequence's or layout folder's layouts stitched into a map."""

    seq_dir: str | None = setting("seq_dir", "WareSynth sequence folder or a layout folder", metavar="SEQ_DIR")
    layouts: str = same_as(
        EvalReconstructionSettings,
        "layouts",
        "'gt' for SEQ_DIR/layouts (or SEQ_DIR itself when it is a layout folder), or a layout folder",
    )  # fmt: skip
    out: Path | None = same_as(OutputSettings, "out", required=True)
    overwrite: bool = same_as(OutputSettings, "overwrite", overwrite_help("the map files", "run"))
    board_thickness: float = same_as(
        RunConfig, "board_thickness", "metres between a clear height and the next board top"
    )
    noisy: bool = same_as(
        EvalReconstructionSettings,
        "noisy",
        "clean-up for network output (StitchConfig.noisy: box-mask openings, small boxes and rarely seen boxes dropped)",
    )  # fmt: skip
    rrd: bool = same_as(RunConfig, "rrd")
    spawn: bool = same_as(OutputSettings, "spawn")
    rgb: bool = same_as(RunConfig, "rgb", "do not log RGB frames to Rerun")
    map_every: int = same_as(RunConfig, "map_every")
    keep_steps: int = setting(
        "--keep-steps",
        "keep the per-frame camera steps of only the last N frames in the map (0 = all); bounds memory on endless "
        "streams",
        0, type=int,
    )  # fmt: skip
    quiet: bool = same_as(OutputSettings, "quiet", "no progress bar")


@dataclass(frozen=True)
class MapSettings:
    """``mvracklay map``: the passes of a building mapped into one building map."""

    dataset: str | None = setting(
        "dataset", "a building dataset folder (route.json inside) or a route file", metavar="DATASET"
    )
    out: Path | None = same_as(OutputSettings, "out", "output folder of the building map", metavar="MAP", required=True)
    overwrite: bool = same_as(
        OutputSettings, "overwrite", overwrite_help("the building map's files and MAP/passes", "map")
    )
    layouts: str = setting(
        "--layouts",
        "net: predict every pass's layouts with the network (as `run`); gt: a generated building's ground-truth "
        "layouts",
        "net", choices=("net", "gt"),
    )  # fmt: skip
    pose_noise: str | None = setting(
        "--pose-noise",
        "move every pass's route start M metres in a random direction and turn it DEG degrees (seeded by "
        "--seed) before placing it: how the map holds up against poor odometry",
        metavar="M,DEG",
    )  # fmt: skip
    seed: int = setting("--seed", "seed of --pose-noise", 0, type=int)
    code: str | None = setting(
        "--code",
        "location code format, fields {aisle} {side} {bay} {level} {position}; default: the building's, "
        "else {aisle:02d}-{side}-{bay:02d}-{level:02d}",
        metavar="FORMAT",
    )  # fmt: skip
    positions: int | None = setting(
        "--positions", "positions per level (default: the building's, else 1)", type=int, metavar="N"
    )
    locations: str | None = setting(
        "--locations",
        "the WMS's location list (CSV: code,aisle,side,bay,level,start_m,end_m[,position]) or an earlier map "
        "(its folder or building.json): codes and spans from it, a row for every listed location, boxes outside "
        "them reported apart",
        metavar="FILE",
    )  # fmt: skip
    workers: int = same_as(ComputeSettings, "workers", "passes mapped at once (local processes)")
    ray: str | None = same_as(ComputeSettings, "ray")
    rrd: bool = same_as(OutputSettings, "rrd", "do not write building.rrd")
    evaluate: bool = setting(
        "--evaluate",
        "a generated building: score the map against its ground_truth/ (locations with the right code and "
        "box count, box recall and precision at 3D IoU 0.5; docs/buildings.md) and add the figures to --json-out",
        False, action="store_true",
    )  # fmt: skip
    #: --checkpoint, --distance, --camera-height: how the network maps a pass (`mvracklay.building_job.MapSettings`)
    run: RunConfig = nested(RunConfig, only=("checkpoint", "distance", "camera_height"))
    device: str = same_as(ComputeSettings, "device")
    threads: int | str = same_as(ComputeSettings, "threads")
    spawn: bool = same_as(OutputSettings, "spawn", spawn_help("MAP/building.rrd"))
    json_out: Path | None = same_as(
        OutputSettings, "json_out", "write the summary and the inventory's counts as JSON to FILE"
    )
    quiet: bool = same_as(OutputSettings, "quiet")


#: the tolerances of `DiffSettings` (`stitching.building.diff.DiffConfig`'s fields)
TOLERANCES = ("same", "size_tol", "move_tol")


def tolerance_helps() -> dict[str, str]:
    """The tolerances' help with their defaults, read from `DiffConfig` (any maps; network-made ones); made when
    ``diff``'s options are (the map modules stay unimported until then)."""
    from stitching.building.diff import DiffConfig

    out = {}
    for name in TOLERANCES:
        f = next(f for f in fields(DiffSettings) if f.name == name)
        mine, net = getattr(DiffConfig(), name), getattr(DiffConfig.network_made(), name)
        between = "between network-made maps" if name == "same" else "network-made"
        out[name] = f"{f.metadata['help']} (default {mine:g}; {net:g} {between})"
    return out


@dataclass(frozen=True)
class DiffSettings:
    """``mvracklay diff``: the changes between two building maps, or one map's exceptions against the WMS. The
    tolerances are None unless given (`DiffConfig.for_maps` picks them for the maps)."""

    old: str | None = setting("old", "the earlier scan's building map (folder or building.json)", metavar="OLD_MAP")
    new: str | None = setting(
        "new", "the later scan's building map (none with --expected)", metavar="NEW_MAP", nargs="?"
    )
    expected: Path | None = setting(
        "--expected", "the counts the WMS expects (CSV: location, expected): list the map's exceptions",
        type=Path, metavar="WMS_CSV",
    )  # fmt: skip
    out: Path | None = same_as(OutputSettings, "out", "output folder of the changes", metavar="DIR", required=True)
    overwrite: bool = same_as(OutputSettings, "overwrite", overwrite_help("the changes files", "diff"))
    truth: Path | None = setting(
        "--truth",
        "a generated rescan's ground_truth/changes.csv: print precision and recall per change category (per "
        "location too, from location_changes.csv beside it)",
        type=Path, metavar="CHANGES_CSV",
    )  # fmt: skip
    same: float | None = setting(
        "--same", "metres along a level within which a box has not moved", type=float,
    )  # fmt: skip
    size_tol: float | None = setting(
        "--size-tol", "metres each size may differ for a box in place to be the same",
        type=float,
    )  # fmt: skip
    move_tol: float | None = setting(
        "--move-tol", "metres each size may differ for a box found elsewhere, a move",
        type=float,
    )  # fmt: skip
    rrd: bool = same_as(OutputSettings, "rrd", "do not write changes.rrd")
    limit: int = setting("--limit", "changes printed (all are written)", 40, type=int)


@dataclass(frozen=True)
class FreeSpaceSettings:
    """``mvracklay free-space``: a map's free space per shelf or location, and where a box fits."""

    map: str | None = setting(
        "map", "warehouse.json written by `mvracklay run` / `reconstruct`, or their OUT folder", metavar="MAP"
    )
    box: str | None = setting("--box", "box size WxDxH in metres, e.g. 0.4x0.3x0.3")
    with_recount: bool = setting(
        "--with-recount",
        "building map: also offer locations flagged recount (marked, last); by default only where the count is sure",
        False, action="store_true",
    )  # fmt: skip
    margin: float = setting("--margin", "clearance in metres on each side and above the box", 0.02, type=float)
    shelf: str | None = setting("--shelf", "only this shelf id, e.g. rack_00/shelf_01 (a row map)")
    near: str | None = setting(
        "--near", "building map: rank the locations a --box fits by distance from it", metavar="CODE"
    )
    json: bool = same_as(OutputSettings, "json")
    csv: bool = setting(
        "--csv", "print CSV (one row per shelf) instead of a table; with --box also whether it fits and where",
        False, action="store_true",
    )  # fmt: skip
