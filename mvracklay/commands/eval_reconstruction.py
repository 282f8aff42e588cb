"""``mvracklay eval-reconstruction``: stitch sequences and score the maps against ground-truth cuboids."""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from layouts.codecs import LayoutFolder
from layouts.errors import InputError
from mvracklay.models import CHECKPOINT_HELP, checkpoint_arg
from mvracklay.options import NO_DEPTH_READ_HELP, add_device_option, add_fuse_option, add_quiet_option, add_roll_option

if TYPE_CHECKING:
    from network.model.net import MVRackLay
    from stitching.map_eval import EvalResult
    from stitching.pipeline import StitchConfig
    from stitching.warehouse_map import WarehouseMap
    from waresynth.dataset import Sequence

NAME = "eval-reconstruction"
HELP = "reconstruct sequences and score them against the generator's ground-truth cuboids"
DESCRIPTION = (
    "For each WareSynth sequence: stitch its layouts (ground truth, a layout folder, or ground truth "
    "degraded like network output) and compare the map with scene.json: box precision/recall at 3D "
    "IoU >= --iou (unit: a ground-truth stack), mean 3D IoU, per-shelf box-count accuracy, free-length "
    "error and end-of-sequence drift of the estimated camera shifts. The map is placed in the world "
    "using only the first frame's record. PATH is a dataset folder (manifest.json) or one sequence. "
    "--checkpoint scores the network instead: each sequence's layouts are predicted (streaming by default), "
    "then stitched and scored the same way (add --noisy for the clean-up settings meant for network output)."
)
GROUP = "models"
ORDER = 33


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("path", metavar="PATH", help="WareSynth dataset or sequence folder")
    p.add_argument("--layouts", default="gt", help="'gt' or a layout folder (single sequence only)")
    p.add_argument(
        "--checkpoint",
        type=checkpoint_arg,
        help=f"predict each sequence's layouts with this model ({CHECKPOINT_HELP}) and score those",
    )
    p.add_argument("--mode", choices=["stream", "window"], default="stream", help="with --checkpoint: inference mode")
    p.add_argument("--threads", type=int, default=2, help="with --checkpoint: torch CPU threads")
    add_device_option(p, "with --checkpoint: auto = the GPU when CUDA is present")
    p.add_argument(
        "--rack-depth",
        metavar="M|scene",
        help="with --checkpoint: impose a known rack depth on the predicted top views (as 'mvracklay predict "
        "--rack-depth'): metres, or 'scene' for each sequence's own from its scene.json",
    )
    p.add_argument("--no-depth-read", action="store_true", help="with --checkpoint: " + NO_DEPTH_READ_HELP)
    add_fuse_option(p, "with --checkpoint: ")
    add_roll_option(p, "with --checkpoint: ")
    p.add_argument("--map", help="score this warehouse.json instead of reconstructing (single sequence only)")
    p.add_argument(
        "--scale-corrected",
        action="store_true",
        help="with --map: also score the map with its scale corrected (every length times the sequence's recorded "
        "distance over the distance the map was made at, from its meta): what a wrong distance costs beyond scale",
    )
    p.add_argument("--split", choices=("train", "val", "test"), help="only this split of a dataset")
    p.add_argument("--limit", type=int, default=0, help="at most this many sequences (0 = all)")
    p.add_argument("--iou", type=float, default=0.5, help="3D IoU threshold for a true positive")
    p.add_argument("--board-thickness", type=float, default=0.06, help="assumed board thickness (metres)")
    p.add_argument("--noisy", action="store_true", help="clean-up settings for network output")
    p.add_argument("--morph", type=int, default=0, help="degrade: grow (>0) / shrink (<0) boxes by N pixels")
    p.add_argument("--flip", type=float, default=0.0, help="degrade: fraction of pixels flipped to a random class")
    p.add_argument("--drop-frame", type=int, default=-1, help="degrade: leave this frame index out")
    p.add_argument("--seed", type=int, default=0, help="seed of the degradation")
    p.add_argument("--json", action="store_true", help="print JSON instead of a table")
    add_quiet_option(p, "no progress bar")


@dataclass(frozen=True)
class Degrade:
    morph: int = 0
    flip: float = 0.0
    drop_frame: int = -1
    seed: int = 0

    @property
    def active(self) -> bool:
        return bool(self.morph or self.flip > 0 or self.drop_frame >= 0)


def evaluate_sequence(
    seq,
    folder: LayoutFolder | None = None,
    config: StitchConfig | None = None,
    deg: Degrade | None = None,
    iou: float = 0.5,
    wmap: WarehouseMap | None = None,
    motion: tuple[list[float], list[float]] | None = None,
) -> tuple[EvalResult, WarehouseMap]:
    """Stitch ``seq`` (a waresynth Sequence) from ``folder`` (default: its ground truth) and score it; ``motion``:
    each frame's camera step as the images read it and its confidence (`mvracklay.commands.predict.read_camera_steps`),
    handed to the stitcher while no frame is dropped."""
    from stitching.detect import visible_range
    from stitching.map_eval import covered_range, evaluate_map
    from stitching.pipeline import Stitcher
    from stitching.synthetic import degrade
    from stitching.warehouse_map import origin_from_record

    folder = folder or seq.layout_folder
    deg = deg or Degrade()
    indices = [i for i in folder.indices() if i != deg.drop_frame]
    if not indices:
        raise InputError(f"{folder.root}: no frames to reconstruct")
    if indices[-1] >= seq.num_frames:
        raise InputError(f"{folder.root}: frame {indices[-1]} has no record in {seq.root / 'meta.json'}")
    rng = np.random.default_rng(deg.seed)
    spec = folder.spec
    stitcher = Stitcher(spec, config)
    vis_x = []
    for i in indices:
        fl = folder.read(i)
        lo, hi = visible_range(fl.visible, spec.size)
        vis_x.append((float(spec.col_to_x(lo)), float(spec.col_to_x(hi))))
        if wmap is None:
            if deg.morph or deg.flip > 0:
                fl = degrade(fl, rng, deg.morph, deg.flip)
            step = motion is not None and deg.drop_frame < 0 and 0 < i < len(motion[0])
            stitcher.push(fl, i, *((motion[0][i], motion[1][i]) if step else ()))
    records = [seq.frame(i) for i in indices]
    if wmap is None:
        wmap = stitcher.map(origin_from_record(records[0]))
    elif len(wmap.steps) != len(indices):
        raise InputError(f"--map holds {len(wmap.steps)} frames but the sequence has {len(indices)}")
    result = evaluate_map(wmap, seq.scene(), records, covered_range(records, vis_x), iou)
    return result, wmap


def scale_factor(seq, wmap: WarehouseMap, source: str) -> float:
    """The sequence's recorded distance (median over its frames) over the distance ``wmap`` was made at."""
    used = wmap.meta.get("distance")
    if not isinstance(used, (int, float)) or not used > 0:
        raise InputError(f"--map {source}: its meta records no distance (a map written before distances were kept)")
    recorded = [seq.frame(i).get("distance") for i in range(seq.num_frames)]
    return float(np.median([d for d in recorded if d])) / float(used)


def summarise(results: list[tuple[str, EvalResult]]) -> dict:
    """Pooled figures over sequences (TP/FP/FN and shelves summed; drift as mean and max)."""
    tp = sum(r.tp for _, r in results)
    fp = sum(r.fp for _, r in results)
    fn = sum(r.fn for _, r in results)
    shelves = sum(r.shelves for _, r in results)
    exact = sum(r.count_exact for _, r in results)
    ious = [r.mean_iou for _, r in results if r.tp]
    return {
        "sequences": len(results),
        "precision": tp / (tp + fp) if tp + fp else 1.0,
        "recall": tp / (tp + fn) if tp + fn else 1.0,
        "mean_iou": float(np.mean(ious)) if ious else 0.0,
        "tp": tp,
        "fp": fp,
        "fn": fn,
        "count_accuracy": exact / shelves if shelves else 1.0,
        "shelves": shelves,
        "free_length_mae": float(np.mean([r.free_length_mae for _, r in results])) if results else 0.0,
        "drift_end_mean": float(np.mean([r.drift_end for _, r in results])) if results else 0.0,
        "drift_end_max": max((r.drift_end for _, r in results), default=0.0),
    }


def _sequences(path: Path, split: str | None, limit: int):
    from mvracklay.commands.reconstruct import open_sequence
    from waresynth.dataset import open_dataset

    if (path / "manifest.json").is_file():
        seqs = open_dataset(path).sequences(split)
    else:
        seq = open_sequence(path)
        if seq is None:
            raise InputError(f"{path}: neither a WareSynth dataset (manifest.json) nor a sequence (meta.json)")
        seqs = [seq]
    if limit < 0:
        raise InputError(f"--limit must be >= 0, got {limit}")
    return seqs[:limit] if limit else seqs


def _rack_depth_option(text: str | None) -> float | str | None:
    """``--rack-depth``: None, ``'scene'``, or a positive number of metres (one-line error otherwise)."""
    from layouts.rackdepth import check_rack_depth

    if text is None or text == "scene":
        return text
    try:
        value = float(text)
    except ValueError:
        raise InputError(f"--rack-depth must be metres or 'scene', got {text!r}") from None
    return check_rack_depth(value)


def run(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from mvracklay.commands.reconstruct import resolve_layouts, stitch_config
    from network.inference.roll import resolve_angles
    from stitching.warehouse_map import WarehouseMap

    path = Path(args.path)
    if not path.is_dir():
        raise InputError(f"{path}: folder not found")
    if not 0 < args.iou <= 1:
        raise InputError(f"--iou must be in (0, 1], got {args.iou}")
    if not 0 <= args.flip <= 1:
        raise InputError(f"--flip must be in [0, 1], got {args.flip}")
    seqs = _sequences(path, args.split, args.limit)
    if (args.layouts != "gt" or args.map) and len(seqs) != 1:
        raise InputError("--layouts DIR and --map need a single sequence folder as PATH")
    if args.checkpoint and (args.layouts != "gt" or args.map):
        raise InputError("--checkpoint predicts the layouts itself: drop --layouts / --map")
    if args.scale_corrected and not args.map:
        raise InputError("--scale-corrected rescales a given map: it needs --map")
    if args.rack_depth is not None and not args.checkpoint:
        raise InputError("--rack-depth changes predicted layouts: it needs --checkpoint")
    rack_depth = _rack_depth_option(args.rack_depth)
    config = stitch_config(args)
    deg = Degrade(args.morph, args.flip, args.drop_frame, args.seed)
    resolve_angles(args.roll, args.pitch, args.yaw, None)  # checked before anything runs
    model, record = _load_checkpoint(args) if args.checkpoint else (None, None)
    results, corrected = [], []
    with tempfile.TemporaryDirectory(prefix="mvracklay-eval-") as tmp:
        for seq in tqdm(seqs, desc="eval-reconstruction", unit="seq", disable=args.quiet, file=sys.stderr):
            if model is not None:
                folder = _predicted_layouts(model, record, seq, Path(tmp) / seq.name, args, rack_depth)
            elif args.layouts == "gt":
                folder = seq.layout_folder
            else:
                folder = resolve_layouts(seq.root, args.layouts)
            wmap = WarehouseMap.load(args.map) if args.map else None
            res, _ = evaluate_sequence(seq, folder, config, deg, args.iou, wmap)
            results.append((seq.name, res))
            if args.scale_corrected:
                factor = scale_factor(seq, wmap, args.map)
                res, _ = evaluate_sequence(seq, folder, config, deg, args.iou, wmap.scaled(factor))
                corrected.append((f"{seq.name} x{factor:.3f}", res))
    summary = summarise(results)
    if args.json:
        out = {"summary": summary, "sequences": {n: r.to_dict() for n, r in results}}
        if corrected:
            out["scale_corrected"] = {n: r.to_dict() for n, r in corrected}
        print(json.dumps(out, indent=2, sort_keys=True))
        return 0
    _print_table(results + corrected, summary, deg)
    return 0


def _load_checkpoint(args: argparse.Namespace) -> tuple[MVRackLay, dict[str, Any]]:
    """``--checkpoint``'s model (on ``--device``, ``--threads`` for torch) and its record."""
    import torch

    from network.checkpoint import load_model
    from network.inference.fusion import check_tau
    from network.training.distributed import single_process_device

    if args.threads < 1:
        raise InputError(f"--threads must be >= 1, got {args.threads}")
    check_tau(args.fuse_frames, "--fuse-frames")
    torch.set_num_threads(args.threads)
    model, record = load_model(args.checkpoint)
    model.to(single_process_device(NAME, args.device))
    return model, record


def _predicted_layouts(
    model: MVRackLay,
    record: dict[str, Any],
    seq: Sequence,
    out: Path,
    args: argparse.Namespace,
    rack_depth: float | str | None,
) -> LayoutFolder:
    """The layouts ``model`` predicts for ``seq``, written to the layout folder ``out`` (``rack_depth``
    "scene": the sequence's own from its scene.json)."""
    from mvracklay.commands.predict import predict_folder

    predict_folder(
        model,
        record,
        seq.root,
        out,
        mode=args.mode,
        rack_depth=float(seq.scene()["row"]["depth"]) if rack_depth == "scene" else rack_depth,
        read_depth=not args.no_depth_read,
        fuse_tau=args.fuse_frames,
        roll=args.roll,
        pitch=args.pitch,
        yaw=args.yaw,
        progress=False,
        source=str(args.checkpoint),
    )
    return LayoutFolder(out)


def _print_table(results: list[tuple[str, EvalResult]], summary: dict[str, Any], deg: Degrade) -> None:
    """One row per sequence, the pooled row, and the degradation applied (if any)."""
    head = f"{'sequence':<14} {'prec':>6} {'recall':>6} {'mIoU':>6} {'TP':>4} {'FP':>4} {'FN':>4} {'count':>7} {'free_err':>8} {'drift':>7}"
    print(head)
    print("-" * len(head))
    for name, r in results:
        print(
            f"{name:<14} {r.precision:>6.3f} {r.recall:>6.3f} {r.mean_iou:>6.3f} {r.tp:>4d} {r.fp:>4d} {r.fn:>4d} "
            f"{r.count_exact:>3d}/{r.shelves:<3d} {r.free_length_mae:>8.3f} {r.drift_end:>7.3f}"
        )
    s = summary
    print("-" * len(head))
    print(
        f"{'pooled':<14} {s['precision']:>6.3f} {s['recall']:>6.3f} {s['mean_iou']:>6.3f} {s['tp']:>4d} {s['fp']:>4d} "
        f"{s['fn']:>4d} {s['count_accuracy']:>7.1%} {s['free_length_mae']:>8.3f} {s['drift_end_max']:>7.3f} (max)"
    )
    if deg.active:
        print(
            f"degraded: morph {deg.morph:+d} px, flip {deg.flip:.0%}, dropped frame {deg.drop_frame}, seed {deg.seed}"
        )
