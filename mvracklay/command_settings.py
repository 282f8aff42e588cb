"""The settings of the commands a training recipe also runs as stages (``generate``, ``evaluate``,
``evaluate-baseline``, ``eval-reconstruction``): one dataclass each, every field with its option's name,
default, range and help in its metadata (`mvracklay.settings.option`), from which the command's options are
made (`mvracklay.settings.add_options`) and a recipe's stage is built (`mvracklay.training.stages`).
Like `mvracklay.settings`, this module imports no torch (``--help`` stays fast).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from layouts.errors import InputError
from mvracklay.models import CHECKPOINT_HELP
from mvracklay.options import THREADS_HELP
from mvracklay.parallel import RAY_HELP
from mvracklay.settings import (
    ComputeSettings,
    InferenceSettings,
    OutputSettings,
    RunConfig,
    check_range,
    json_out_setting,
    nested,
    precision_setting,
    quiet_setting,
    same_as,
    setting,
)
from waresynth.exporters import EXPORT_FORMATS


@dataclass(frozen=True)
class GenerateSettings:
    """``mvracklay generate``: a synthetic dataset."""

    out: Path | None = setting("out", "output dataset folder", metavar="OUT", type=Path)
    sequences: int = setting(
        "--sequences", "sequences (one scene + camera path each)", 10, metavar="N", type=int, range=(1, 100000)
    )
    frames: int = setting("--frames", "frames per sequence", 50, metavar="F", type=int, range=(1, 100000))
    #: None: not given (256, 128 and 3; a rescan takes SCAN's)
    size: int | None = setting(
        "--size", "image width and height in pixels (default 256; --rescan: SCAN's)", metavar="S", type=int,
        range=(16, 8192),
    )  # fmt: skip
    layout_size: int | None = setting(
        "--layout-size", "layout resolution, pixels per side, at least 8 (default 128; --rescan: SCAN's)",
        metavar="D", type=int, range=(8, 4096),
    )  # fmt: skip
    slots: int | None = setting(
        "--slots", "shelf slots per layout (default 3; --rescan: SCAN's)", metavar="R", type=int, range=(1, 16)
    )
    seed: int = setting("--seed", "dataset seed (same seed + config -> same bytes)", 0, type=int, range=(0, 2**63 - 1))
    config: Path | None = setting(
        "--config",
        "JSON config overriding waresynth/default_config.json, or a shipped one by name (wide_look: the wider camera "
        "and building look meant for training; wide_camera: a wider camera geometry, 45-80 degree lenses, 1.8-3.5 m, "
        "turned mounts, steps to 30 cm; shifted_look: a look outside wide_look, for held-out tests); several joined "
        "by '+' apply in order (wide_look+wide_camera)",
        metavar="FILE", type=Path,
    )  # fmt: skip
    supersample: int | None = setting(
        "--supersample",
        "each pixel's colour the mean of S x S rays over its area, as a camera's sensor integrates light "
        "(S^2 the rendering cost; depth and labels stay sampled at pixel centres); sets the config's "
        "sensor.supersample (default: the config's, 1)",
        metavar="S", type=int, choices=(1, 2, 3, 4),
    )  # fmt: skip
    workers: int = same_as(ComputeSettings, "workers")
    ray: str | None = same_as(ComputeSettings, "ray", RAY_HELP + "; one task per sequence or pass")
    format: str = setting(
        "--format", "also export the dataset in this format (as `mvracklay export` does) to --export-out",
        "native", choices=("native", *EXPORT_FORMATS),
    )  # fmt: skip
    export_out: Path | None = setting(
        "--export-out", "export folder (default: OUT_<format> beside OUT)", metavar="DIR", type=Path
    )
    overwrite: bool = same_as(
        OutputSettings, "overwrite", "delete a non-empty OUT (or export folder) that is not this dataset"
    )
    shard: str | None = setting(
        "--shard",
        "write only shard I of N (sequences k with k %% N == I), e.g. one job of an array; "
        "join the shards with `mvracklay merge-shards`",
        metavar="I/N",
    )  # fmt: skip
    building: str | None = setting(
        "--building",
        "a whole building instead of --sequences rows: its aisles' rack faces scanned in passes (one sequence each, "
        "long faces in overlapping passes, some twice), with OUT/route.json and OUT/ground_truth/ (building.json, "
        "inventory.csv); FILE: a JSON building config overriding the defaults (docs/waresynth.md, Buildings)",
        metavar="FILE", nargs="?", const="",
    )  # fmt: skip
    rescan: Path | None = setting(
        "--rescan",
        "with --building: the building of the dataset SCAN again after a seeded set of changes (stacks removed, "
        "added, moved, shifted, replaced at the building config's `changes` rates), scanned by passes and cameras "
        "of its own drawn from --seed; its racks, configs, --size and layout spec are SCAN's (options given must "
        "agree); OUT/ground_truth/changes.csv lists the changes (docs/waresynth.md, Rescans)",
        metavar="SCAN", type=Path,
    )  # fmt: skip
    quiet: bool = quiet_setting("hide the progress bar", alias=True)

    def validate(self) -> None:
        """One line naming the options when a value is out of its range or options do not go together."""
        check_range(GenerateSettings, self)  # --sequences, --frames, --size, ... within their ranges
        if self.shard is not None and self.format != "native":
            raise InputError("--format exports a whole dataset: export after `mvracklay merge-shards`, not per shard")
        if self.rescan is not None and self.building is None:
            raise InputError(
                "--rescan SCAN: a rescan is of a building; add --building (generate OUT --building --rescan SCAN)"
            )
        if self.building is None:
            return
        if self.shard is not None or self.format != "native":
            raise InputError("--building writes a whole building in one folder: without --shard and --format")
        defaults = GenerateSettings()
        if (self.sequences, self.frames) != (defaults.sequences, defaults.frames):
            raise InputError(
                "--building: the passes and their frames come from the building config, not --sequences / --frames"
            )


#: the inference settings `evaluate` takes (a rack depth is each sequence's own to read)
EVALUATE_INFERENCE = ("flip", "read_depth", "whole_sequence", "fuse_tau", "roll", "pitch", "yaw")


@dataclass(frozen=True)
class EvaluateSettings:
    """``mvracklay evaluate``: Table I of a checkpoint on a dataset split."""

    checkpoint: Path | None = same_as(RunConfig, "checkpoint", CHECKPOINT_HELP, required=True)
    data: Path | None = setting(
        "--data",
        "dataset folder ('mvracklay generate'), or a RackLay/MVRackLay export ('mvracklay export --format racklay')",
        type=Path, required=True,
    )  # fmt: skip
    split: str = setting("--split", "which split to score (train, val, test, or all)", "test")
    mode: str = setting("--mode", "windowed (paper) or streaming", "window", choices=["window", "stream"])
    #: --flip-average, --no-depth-read, --whole-sequence, --fuse-frames, --roll, --pitch, --yaw
    inference: InferenceSettings = nested(InferenceSettings, only=EVALUATE_INFERENCE)
    max_frames: int = same_as(RunConfig, "max_frames", "frames per sequence (0 = all)")
    threads: int | str = same_as(ComputeSettings, "threads")
    precision: str = precision_setting()
    device: str = same_as(ComputeSettings, "device")
    true_anchors: bool = setting(
        "--true-anchors",
        "analysis: place the shelf slots at the ground-truth boards instead of the row head's (decoders alone)",
        False, action="store_true",
    )  # fmt: skip
    metric: str = setting(
        "--metric",
        "ours (default: empty pairs skipped, in view and all cells, pooled), reference (the authors' "
        "eval_vracklay.py: all cells, an empty (frame, slot) pair scores 1, precision over the classes in the "
        "ground truth, / frames x slots, targets f0, f0, f1 .. f[N-2] of each sequence), or both",
        "ours", choices=["ours", "reference", "both"],
    )  # fmt: skip
    json_out: Path | None = json_out_setting("also write the full result as JSON here")
    quiet: bool = quiet_setting("hide the progress bar", alias=True)


@dataclass(frozen=True)
class EvaluateBaselineSettings:
    """``mvracklay evaluate-baseline``: Table I of the depth-projection baseline."""

    data: Path | None = same_as(EvaluateSettings, "data", "dataset folder written by 'mvracklay generate'")
    split: str = same_as(EvaluateSettings, "split")
    max_frames: int = same_as(RunConfig, "max_frames", "frames per sequence (0 = all)")
    json_out: Path | None = json_out_setting("also write the result as JSON here")
    quiet: bool = quiet_setting("no progress bar", alias=True)


def _with_checkpoint(name: str, help: str, default: object = None, **kwargs: object) -> object:
    return setting(name, f"with --checkpoint: {help}", default, **kwargs)


@dataclass(frozen=True)
class EvalReconstructionSettings:
    """``mvracklay eval-reconstruction``: stitch sequences and score the maps against ground-truth cuboids."""

    path: str | None = setting("path", "WareSynth dataset or sequence folder", metavar="PATH")
    layouts: str = setting("--layouts", "'gt' or a layout folder (single sequence only)", "gt")
    checkpoint: Path | None = same_as(
        RunConfig, "checkpoint", f"predict each sequence's layouts with this model ({CHECKPOINT_HELP}) and score those"
    )
    mode: str = same_as(RunConfig, "mode", "with --checkpoint: inference mode")
    threads: int | str = same_as(ComputeSettings, "threads", f"with --checkpoint: {THREADS_HELP}")
    device: str = same_as(ComputeSettings, "device", "with --checkpoint: auto = the GPU when CUDA is present")
    #: metres, 'scene' (each sequence's own, from its scene.json) or None (`mvracklay.reconstruction_eval`)
    rack_depth: str | None = _with_checkpoint(
        "--rack-depth",
        "impose a known rack depth on the predicted top views (as 'mvracklay predict "
        "--rack-depth'): metres, or 'scene' for each sequence's own from its scene.json",
        metavar="M|scene",
    )  # fmt: skip
    #: --no-depth-read, --fuse-frames, --roll, --pitch, --yaw (the rack depth is the option above)
    inference: InferenceSettings = nested(
        InferenceSettings, only=("read_depth", "fuse_tau", "roll", "pitch", "yaw"), prefix="with --checkpoint: "
    )
    map: str | None = setting("--map", "score this warehouse.json instead of reconstructing (single sequence only)")
    scale_corrected: bool = setting(
        "--scale-corrected",
        "with --map: also score the map with its scale corrected (every length times the sequence's recorded "
        "distance over the distance the map was made at, from its meta): what a wrong distance costs beyond scale",
        False, action="store_true",
    )  # fmt: skip
    split: str | None = setting("--split", "only this split of a dataset", choices=("train", "val", "test"))
    limit: int = setting("--limit", "at most this many sequences (0 = all)", 0, type=int)
    iou: float = setting("--iou", "3D IoU threshold for a true positive", 0.5, type=float)
    board_thickness: float = same_as(RunConfig, "board_thickness", "assumed board thickness (metres)")
    noisy: bool = setting("--noisy", "clean-up settings for network output", False, action="store_true")
    morph: int = setting("--morph", "degrade: grow (>0) / shrink (<0) boxes by N pixels", 0, type=int)
    flip: float = setting("--flip", "degrade: fraction of pixels flipped to a random class", 0.0, type=float)
    drop_frame: int = setting("--drop-frame", "degrade: leave this frame index out", -1, type=int)
    handheld: bool = setting(
        "--handheld",
        "walk each sequence as a hand-held camera would (stops of 3-6 frames, uneven steps up to twice the "
        "usual, a step back: waresynth.handheld) before stitching, seeded by --seed; meant for fine-step sequences "
        "(the walk's usual step is 2 of their frames), e.g. generated with a config whose camera.step is halved",
        False, action="store_true",
    )  # fmt: skip
    seed: int = setting("--seed", "seed of the degradation and of --handheld's walks", 0, type=int)
    json: bool = same_as(OutputSettings, "json")
    quiet: bool = quiet_setting("no progress bar", alias=True)


@dataclass(frozen=True)
class ExportSettings:
    """``mvracklay export``: a generated dataset in another format."""

    dataset: str | None = setting("dataset", "WareSynth dataset folder (holds manifest.json)", metavar="DIR")
    format: str | None = setting("--format", "output format", required=True, choices=EXPORT_FORMATS)
    out: Path | None = same_as(
        OutputSettings, "out", "output folder (must be outside DIR)", metavar="OUT", required=True
    )
    yolo_task: str = setting(
        "--yolo-task", "yolo labels: boxes (detect) or polygons (segment)", "detect", choices=("detect", "segment")
    )
    slots: int | None = same_as(
        GenerateSettings,
        "slots",
        "racklay: shelf slots per layout stack, the empty ones all 0 (default 4, the reference code's --num_racks; "
        "at least the dataset's slots)",
        metavar="N",
    )  # fmt: skip
    overwrite: bool = same_as(OutputSettings, "overwrite", "replace OUT if it exists and is not empty")
    quiet: bool = same_as(OutputSettings, "quiet", "no progress bar")


@dataclass(frozen=True)
class InspectSettings:
    """``mvracklay inspect``: a generated dataset's summary and a preview sheet."""

    dataset: str | None = setting("dataset", "WareSynth dataset folder (holds manifest.json)", metavar="DIR")
    sequence: str | None = setting("--sequence", "sequence to preview (default: the first one)", metavar="NAME")
    frame: int = setting("--frame", "frame index within the sequence", 0, metavar="I", type=int)
    out: Path | None = same_as(
        OutputSettings, "out", "where to write the preview sheet", default="sheet.png", metavar="PNG"
    )
    max_frames: int = same_as(
        RunConfig, "max_frames", "measure pixel fractions on at most N frames spread evenly over the dataset",
        default=200, metavar="N",
    )  # fmt: skip
    no_sheet: bool = setting("--no-sheet", "print the summary only", False, action="store_true")
    quiet: bool = same_as(OutputSettings, "quiet", "no progress bar")


@dataclass(frozen=True)
class MergeShardsSettings:
    """``mvracklay merge-shards``: the shards of a generated dataset joined into one."""

    out: Path | None = same_as(GenerateSettings, "out", "merged dataset folder (new or empty)")
    shards: list[Path] | None = setting(
        "shards", "shard folders, all N of them", metavar="SHARD_DIR", type=Path, nargs="+"
    )
    link: bool = setting(
        "--link",
        "hard-link the files instead of moving the folders (the shards stay usable; copies across filesystems)",
        False, action="store_true",
    )  # fmt: skip
    quiet: bool = same_as(OutputSettings, "quiet", "hide the progress bar")


@dataclass(frozen=True)
class RecipeSettings:
    """``mvracklay train --recipe``: a training recipe's stages run into the run folder (`mvracklay.training.runner`)."""

    recipe: str | None = setting(
        "--recipe",
        "run a training recipe into --out (the run folder): a shipped one (smoke, default-128, budget-256, "
        "default-256) or a TOML file; the training options above then come from the recipe",
        metavar="NAME|FILE", group="recipe",
    )  # fmt: skip
    set: list[str] = setting(
        "--set",
        "with --recipe: change one value, e.g. vars.head_sequences=4, data.train.sequences=12, "
        "stage.stage2.minutes=0.3, stage.stage2.lr=1e-3, budget.total=100, precision=fp32 (repeatable)",
        [], action="append", metavar="PATH=VALUE", group="recipe",
    )  # fmt: skip
    dry_run: bool = setting(
        "--dry-run", "with --recipe: print the stages and their arguments only", False, action="store_true",
        group="recipe",
    )  # fmt: skip
