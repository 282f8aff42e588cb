"""How well a map is reconstructed, as `mvracklay eval-reconstruction` scores it: a sequence's layouts (ground truth,
degraded like network output, or predicted) stitched and its map held against the generator's cuboids
(`evaluate_sequence`, `stitching.map_eval`), pooled over sequences (`summarise`) and tabled (`format_results`);
`eval_reconstruction` is the whole job, for the command and a recipe's stage.
"""

from __future__ import annotations

import json
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from layouts.codecs import LayoutFolder
from layouts.errors import InputError
from mvracklay.settings import InferenceSettings

if TYPE_CHECKING:
    from mvracklay.command_settings import EvalReconstructionSettings
    from network.model.net import MVRackLay
    from stitching.map_eval import EvalResult
    from stitching.pipeline import StitchConfig
    from stitching.warehouse_map import WarehouseMap
    from waresynth.dataset import Sequence


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
    each frame's camera step as the images read it and its confidence (`mvracklay.inference.read_camera_steps`),
    handed to the stitcher while no frame is dropped."""
    from stitching.detect import visible_range
    from stitching.map_eval import covered_range, evaluate_map
    from stitching.pipeline import Stitcher
    from stitching.synthetic import degrade
    from stitching.warehouse_map import origin_from_record

    folder = folder or seq.layout_folder
    deg = deg or Degrade()
    indices = [i for i in folder.indices() if i != deg.drop_frame] if wmap is None else mapped_frames(wmap, seq)
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
    result = evaluate_map(wmap, seq.scene(), records, covered_range(records, vis_x), iou)
    return result, wmap


def mapped_frames(wmap: WarehouseMap, seq) -> list[int]:
    """The frames of ``seq`` a given map's camera steps stand for: a live run's stream numbers (``input_frames`` in
    its meta: the frames it mapped, the others skipped or dropped), every N-th of a run with ``every`` N, else each
    frame; one line when they do not fit the sequence."""
    meta, n = wmap.meta, seq.num_frames
    numbers = meta.get("input_frames")
    every = meta.get("every", 1)
    if numbers is not None:
        ok = isinstance(numbers, list) and all(isinstance(i, int) and 0 <= i < n for i in numbers)
        if not ok or len(numbers) != len(wmap.steps):
            raise InputError(f"--map: its input_frames are not {len(wmap.steps)} frame numbers of a {n}-frame sequence")
        return numbers
    step = every if isinstance(every, int) and every >= 1 else 1
    indices = list(range(0, n, step))
    if len(wmap.steps) != len(indices):
        said = f"every {step}th frame: {len(indices)}" if step > 1 else f"{len(indices)}"
        raise InputError(f"--map holds {len(wmap.steps)} frames but the sequence has {said}")
    return indices


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


def open_sequences(path: Path, split: str | None = None, limit: int = 0) -> list:
    """The sequences of a dataset folder (``split``: only these) or the one sequence folder ``path``; ``limit``: the first N."""
    from mvracklay.reconstruction import open_sequence
    from waresynth.dataset import open_dataset

    if (path / "manifest.json").is_file():
        seqs = open_dataset(path).sequences(split)
        if not seqs:  # nothing scored is no score: never the pooled 1.000 of an empty sum
            where = "" if split is None else f" in split {split!r}"
            raise InputError(f"{path}: no sequence{where} to evaluate")
    else:
        seq = open_sequence(path)
        if seq is None:
            raise InputError(f"{path}: neither a WareSynth dataset (manifest.json) nor a sequence (meta.json)")
        seqs = [seq]
    if limit < 0:
        raise InputError(f"--limit must be >= 0, got {limit}")
    return seqs[:limit] if limit else seqs


def predicted_layouts(
    model: MVRackLay,
    record: dict[str, Any],
    seq: Sequence,
    out: Path,
    settings: InferenceSettings,
    mode: str = "stream",
    source: str = "checkpoint",
) -> LayoutFolder:
    """The layouts ``model`` predicts for ``seq``, written to the layout folder ``out`` (`mvracklay.inference.predict_folder`)."""
    from mvracklay.inference import predict_folder
    from mvracklay.use_settings import PredictSettings

    job = PredictSettings(seq_dir=seq.root, out=out, inference=settings, mode=mode, quiet=True)
    predict_folder(model, record, job, source=source)
    return LayoutFolder(out)


def format_results(results: list[tuple[str, EvalResult]], summary: dict[str, Any], deg: Degrade) -> str:
    """A table: one row per sequence, the pooled row, and the degradation applied (if any)."""
    lines = []
    head = f"{'sequence':<14} {'prec':>6} {'recall':>6} {'mIoU':>6} {'TP':>4} {'FP':>4} {'FN':>4} {'count':>7} {'free_err':>8} {'drift':>7}"
    lines.append(head)
    lines.append("-" * len(head))
    for name, r in results:
        lines.append(
            f"{name:<14} {r.precision:>6.3f} {r.recall:>6.3f} {r.mean_iou:>6.3f} {r.tp:>4d} {r.fp:>4d} {r.fn:>4d} "
            f"{r.count_exact:>3d}/{r.shelves:<3d} {r.free_length_mae:>8.3f} {r.drift_end:>7.3f}"
        )
    s = summary
    lines.append("-" * len(head))
    lines.append(
        f"{'pooled':<14} {s['precision']:>6.3f} {s['recall']:>6.3f} {s['mean_iou']:>6.3f} {s['tp']:>4d} {s['fp']:>4d} "
        f"{s['fn']:>4d} {s['count_accuracy']:>7.1%} {s['free_length_mae']:>8.3f} {s['drift_end_max']:>7.3f} (max)"
    )
    if deg.active:
        lines.append(
            f"degraded: morph {deg.morph:+d} px, flip {deg.flip:.0%}, dropped frame {deg.drop_frame}, seed {deg.seed}"
        )
    return "\n".join(lines)


def handheld_sequence(seq: Sequence, out: Path, seed: int) -> Sequence:
    """``seq`` walked by a hand-held camera (`waresynth.handheld`, seeded), written (hard links) to ``out``."""
    from mvracklay.reconstruction import open_sequence
    from waresynth.handheld import HandheldWalk, handheld_indices, resample_sequence, walk_note

    walk = HandheldWalk()
    resample_sequence(seq.root, out, handheld_indices(seq.num_frames, seed, walk), walk_note(walk, seed))
    return open_sequence(out)


def rack_depth_option(text: str | None) -> float | str | None:
    """``--rack-depth``: None, ``'scene'``, or a positive number of metres (one-line error otherwise)."""
    from layouts.rackdepth import check_rack_depth

    if text is None or text == "scene":
        return text
    try:
        value = float(text)
    except ValueError:
        raise InputError(f"--rack-depth must be metres or 'scene', got {text!r}") from None
    return check_rack_depth(value)


def eval_reconstruction(args: EvalReconstructionSettings) -> int:
    """Stitch and score the sequences ``args`` names (``mvracklay eval-reconstruction``), printing the table
    (or, ``--json``, the figures)."""
    from dataclasses import replace

    from tqdm import tqdm

    from mvracklay.reconstruction import resolve_layouts, stitch_settings
    from mvracklay.threads import resolve_threads
    from network.inference.loading import load_for_inference
    from stitching.warehouse_map import WarehouseMap

    path = Path(args.path)
    if not path.is_dir():
        raise InputError(f"{path}: folder not found")
    if not 0 < args.iou <= 1:
        raise InputError(f"--iou must be in (0, 1], got {args.iou}")
    if not 0 <= args.flip <= 1:
        raise InputError(f"--flip must be in [0, 1], got {args.flip}")
    seqs = open_sequences(path, args.split, args.limit)
    if (args.layouts != "gt" or args.map) and len(seqs) != 1:
        raise InputError("--layouts DIR and --map need a single sequence folder as PATH")
    if args.checkpoint and (args.layouts != "gt" or args.map):
        raise InputError("--checkpoint predicts the layouts itself: drop --layouts / --map")
    if args.scale_corrected and not args.map:
        raise InputError("--scale-corrected rescales a given map: it needs --map")
    if args.handheld and (args.layouts != "gt" or args.map):
        raise InputError("--handheld walks the sequence's own frames: drop --layouts / --map")
    if args.rack_depth is not None and not args.checkpoint:
        raise InputError("--rack-depth changes predicted layouts: it needs --checkpoint")
    rack_depth = rack_depth_option(args.rack_depth)
    config = stitch_settings(args.board_thickness, args.noisy)
    deg = Degrade(args.morph, args.flip, args.drop_frame, args.seed)
    settings = replace(args.inference, rack_depth=None)
    settings.validate()  # checked before anything runs
    model, record = None, None
    if args.checkpoint:
        model, record = load_for_inference(
            args.checkpoint, "eval-reconstruction", args.device, threads=resolve_threads(args.threads)
        )
    results, corrected = [], []
    with tempfile.TemporaryDirectory(prefix="mvracklay-eval-") as tmp:
        for k, seq in enumerate(
            tqdm(seqs, desc="eval-reconstruction", unit="seq", disable=args.quiet, file=sys.stderr)
        ):
            if args.handheld:
                seq = handheld_sequence(seq, Path(tmp) / "handheld" / seq.name, args.seed + k)
            if model is not None:
                depth = float(seq.scene()["row"]["depth"]) if rack_depth == "scene" else rack_depth
                seq_settings = replace(settings, rack_depth=depth)
                folder = predicted_layouts(
                    model, record, seq, Path(tmp) / seq.name, seq_settings, args.mode, str(args.checkpoint)
                )
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
    print(format_results(results + corrected, summary, deg))
    return 0
