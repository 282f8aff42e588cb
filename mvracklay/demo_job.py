"""The main job end to end on a fresh machine (``make demo`` / ``python -m mvracklay.demo_job``).

1. Generates one seeded WareSynth sequence with the embedded default config (resumable: a
   complete sequence on disk is reused, byte-identical).
2. Writes a preview sheet of its middle frame (RGB, depth, semantics, layouts) as a PNG.
3. Runs `mvracklay run` on it with the shipped model (`mvracklay.models`, mvracklay-disc-4) or
   ``--checkpoint``; without a trained model it reconstructs from the generator's ground-truth
   layouts instead (`mvracklay reconstruct`) and says so.
4. Prints the free space per shelf and the reconstruction accuracy against the generator's
   ground-truth cuboids, and where the .glb, .rrd and preview are, and how to open them.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Sequence as Seq
from pathlib import Path

from layouts.codecs import LayoutFolder
from layouts.errors import InputError
from layouts.spec import LayoutSpec
from mvracklay.models import CHECKPOINT_HELP, checkpoint_arg

DEFAULT_OUT = Path("out/demo")
DEFAULT_SEED = 2026


def parse_args(argv: Seq[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(
        prog="python -m mvracklay.demo_job",
        description=__doc__.split("\n\n")[0],
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    p.add_argument("--out", type=Path, default=DEFAULT_OUT, help="working folder (data/, run/, preview.png)")
    p.add_argument("--seed", type=int, default=DEFAULT_SEED, help="generator seed")
    p.add_argument("--frames", type=int, default=50, help="frames in the sequence")
    p.add_argument("--size", type=int, default=256, help="image width and height in pixels")
    p.add_argument("--layout-size", type=int, default=128, help="ground-truth layout resolution D")
    p.add_argument("--checkpoint", type=checkpoint_arg, help=f"{CHECKPOINT_HELP} (default: the shipped model, if any)")
    p.add_argument("--ground-truth", action="store_true", help="reconstruct from ground-truth layouts, no network")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    return p.parse_args(argv)


def format_accuracy(rows: list[tuple[str, object]]) -> str:
    """A small table of `stitching.map_eval.EvalResult` rows."""
    head = f"{'layouts':<48} {'stacks':>6} {'recall':>6} {'prec':>6} {'mIoU3D':>6} {'count':>7} {'free_err':>8} {'drift':>8}"
    lines = [head, "-" * len(head)]
    for name, r in rows:
        lines.append(
            f"{name[:48]:<48} {r.tp + r.fn:>6d} {r.recall:>6.3f} {r.precision:>6.3f} {r.mean_iou:>6.3f} "
            f"{r.count_exact:>3d}/{r.shelves:<3d} {r.free_length_mae:>6.3f} m {100 * r.drift_end:>5.2f} cm"
        )
    lines.append("recall/precision at 3D IoU >= 0.5; count = shelves with the exact box count; drift at the last frame")
    return "\n".join(lines)


def _banner(text: str) -> None:
    print(f"\n== {text}", flush=True)


def main(argv: Seq[str] | None = None) -> int:
    from mvracklay.cli import main as cli_main

    args = parse_args(argv)
    try:
        return _run(args, cli_main)
    except InputError as e:
        print(f"demo: error: {e}", file=sys.stderr)
        return 2


def _run(args: argparse.Namespace, cli_main) -> int:
    from mvracklay.pipeline import DEFAULT_CHECKPOINT
    from mvracklay.reconstruction_eval import evaluate_sequence
    from stitching.free_space import format_table, free_space
    from stitching.warehouse_map import WarehouseMap
    from waresynth.dataset import open_dataset
    from waresynth.generate import DatasetSettings, generate_dataset
    from waresynth.preview import write_sheet

    t_start = time.perf_counter()
    out: Path = args.out
    if args.checkpoint is not None and not args.checkpoint.is_file():
        raise InputError(f"--checkpoint {args.checkpoint}: file not found")
    quiet = ["--quiet"] if args.quiet else []

    _banner(f"1/4 generate a seeded sequence (seed {args.seed}, {args.frames} frames, {args.size}x{args.size})")
    data = out / "data"
    t0 = time.perf_counter()
    generate_dataset(
        data,
        DatasetSettings(
            num_sequences=1,
            frames=args.frames,
            image_size=(args.size, args.size),
            spec=LayoutSpec(size=args.layout_size),
            seed=args.seed,
            config=None,
            progress=not args.quiet,
        ),
    )
    seq = open_dataset(data).sequences()[0]
    print(f"sequence {seq.root} ready ({time.perf_counter() - t0:.1f} s)")

    _banner("2/4 preview sheet")
    preview = out / "preview.png"
    w, h = write_sheet(seq, seq.num_frames // 2, preview, "demo")
    print(
        f"wrote {preview} ({w}x{h}): RGB, depth, semantics and the ground-truth layouts of frame {seq.num_frames // 2}"
    )

    run_dir = out / "run"
    ckpt = args.checkpoint or (DEFAULT_CHECKPOINT if DEFAULT_CHECKPOINT.is_file() else None)
    if args.ground_truth or ckpt is None:
        why = "--ground-truth given" if args.ground_truth else "no trained model is shipped yet"
        _banner(f"3/4 reconstruct from the GROUND-TRUTH layouts ({why})")
        if ckpt is None and not args.ground_truth:
            print(
                f"{DEFAULT_CHECKPOINT.name} is absent from {DEFAULT_CHECKPOINT.parent}, so this shows the stitching "
                "on perfect layouts, not the network. Train one with 'mvracklay train' (docs/network.md) and pass "
                f"--checkpoint, or ship it as {DEFAULT_CHECKPOINT.name} in mvracklay/models/."
            )
        rc = cli_main(["reconstruct", str(seq.root), "--out", str(run_dir), *quiet])
        layouts = seq.layout_folder
        source = "ground truth"
    else:
        _banner(f"3/4 mvracklay run with {ckpt}")
        rc = cli_main(["run", str(seq.root), "--out", str(run_dir), "--checkpoint", str(ckpt), *quiet])
        layouts = LayoutFolder(run_dir / "layouts") if rc == 0 else None
        source = f"predicted by {ckpt.name}"
    if rc != 0:
        return rc

    _banner(f"4/4 results (layouts {source})")
    wmap = WarehouseMap.load(run_dir / "warehouse.json")
    if layouts is seq.layout_folder:  # `mvracklay run` has printed it already
        print("free space per shelf:")
        print(format_table(free_space(wmap)))
    print("\nreconstruction accuracy vs the generator's ground-truth cuboids (unit: a box stack fully seen):")
    rows = [(source, evaluate_sequence(seq, layouts, wmap=wmap)[0])]
    if layouts is not seq.layout_folder:
        rows.append(("ground-truth layouts (reference)", evaluate_sequence(seq)[0]))
    print(format_accuracy(rows))
    print(
        f"\noutputs:\n"
        f"  3D model   {run_dir / 'warehouse.glb'}   (any glTF viewer, e.g. https://gltf-viewer.donmccurdy.com, Blender)\n"
        f"  recording  {run_dir / 'warehouse.rrd'}   (open with: rerun {run_dir / 'warehouse.rrd'})\n"
        f"  map        {run_dir / 'warehouse.json'}  (mvracklay free-space {run_dir / 'warehouse.json'} --box 0.4x0.3x0.3)\n"
        f"  preview    {preview}   (any image viewer)\n"
        f"demo finished in {time.perf_counter() - t_start:.0f} s"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
