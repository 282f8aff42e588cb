"""``mvracklay eval-reconstruction``: stitch sequences and score the maps against ground-truth cuboids."""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

from layouts.errors import InputError
from mvracklay.command_settings import EvalReconstructionSettings
from mvracklay.settings import add_options

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


SETTINGS = EvalReconstructionSettings


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_options(p, EvalReconstructionSettings)


def run(args: EvalReconstructionSettings) -> int:
    from dataclasses import replace

    from tqdm import tqdm

    from mvracklay.reconstruction import resolve_layouts, stitch_settings
    from mvracklay.reconstruction_eval import (
        Degrade,
        evaluate_sequence,
        format_results,
        handheld_sequence,
        open_sequences,
        predicted_layouts,
        rack_depth_option,
        scale_factor,
        summarise,
    )
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
        model, record = load_for_inference(args.checkpoint, NAME, args.device, threads=resolve_threads(args.threads))
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
