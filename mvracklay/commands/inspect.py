"""``mvracklay inspect``: summarise a WareSynth dataset and draw one frame's preview sheet."""

from __future__ import annotations

import argparse
from pathlib import Path

from layouts.errors import InputError
from mvracklay.command_settings import InspectSettings
from mvracklay.settings import add_options

NAME = "inspect"
HELP = "summarise a WareSynth dataset and write a preview sheet (PNG) of one frame"
DESCRIPTION = (
    "Print a dataset summary (sequences per split, frames, image size, layout spec, semantic and layout "
    "class pixel fractions, boxes per shelf) and write a PNG sheet of one frame: RGB, depth, semantic "
    "classes, box instances and the top/front layouts of every shelf slot."
)
GROUP = "data"
ORDER = 21


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_options(p, InspectSettings)


def run(args: argparse.Namespace) -> int:
    from waresynth.preview import format_summary, summarise, write_sheet

    root = Path(args.dataset)
    out = Path(args.out)
    if not args.no_sheet and (out.suffix.lower() != ".png" or out.is_dir()):
        raise InputError(f"--out {out}: the preview sheet is written as PNG; give a file path ending in .png")
    if args.max_frames < 1:
        raise InputError(f"--max-frames must be a positive integer, got {args.max_frames}")
    if not root.is_dir():
        raise InputError(f"{root}: dataset folder not found")
    if not (root / "manifest.json").is_file():
        raise InputError(f"{root}: not a WareSynth dataset (no manifest.json)")
    if not args.no_sheet:
        from layouts.publish import refuse_overlap

        refuse_overlap([out], {"DIR": root})  # the sheet never replaces a file of the dataset
    from waresynth.dataset import open_dataset

    ds = open_dataset(root)
    seqs = ds.sequences()
    if not seqs:
        raise InputError(f"{root}: dataset has no sequences")
    if args.sequence is None:
        seq = seqs[0]
    else:
        names = [s.name for s in seqs]
        if args.sequence not in names:
            raise InputError(
                f"--sequence {args.sequence!r} not in {root} (have {', '.join(names[:5])}{' ...' if len(names) > 5 else ''})"
            )
        seq = ds.sequence(args.sequence)
    if not 0 <= args.frame < seq.num_frames:
        raise InputError(f"--frame must be in [0, {seq.num_frames}) for sequence {seq.name}, got {args.frame}")
    print(format_summary(summarise(ds, max_frames=args.max_frames, progress=not args.quiet)))
    if not args.no_sheet:
        w, h = write_sheet(seq, args.frame, args.out, dataset_name=root.resolve().name)
        print(f"preview sheet  {args.out} ({w}x{h} px): {seq.name} frame {args.frame}")
    return 0
