"""``mvracklay export``: convert a WareSynth dataset to COCO, YOLO or the RackLay/MVRackLay layout."""

from __future__ import annotations

import argparse
import json

from mvracklay.command_settings import ExportSettings
from mvracklay.settings import add_options

NAME = "export"
HELP = "export a WareSynth dataset as COCO instance segmentation, YOLO detection or RackLay layouts"
DESCRIPTION = (
    "Write a WareSynth dataset in another format. coco: images/<split>/ and "
    "annotations/instances_<split>.json (RLE masks; categories box, shelf, rack). yolo: images/, labels/, "
    "<split>.txt lists and data.yaml. racklay: the authors' RackLay/MVRackLay layout, img/ and topLayouts/ "
    "(top and front 0/115/255 .npy stacks of --slots slots) and splits/warehouse/ with RackLay and MVRackLay "
    "lists of absolute image paths (copy them under their code's splits/warehouse/). The export is built "
    "in a staging folder on OUT's filesystem and moved into place when complete, one export into OUT at a time; "
    "the same dataset always gives the same bytes (the racklay lists name OUT's absolute path)."
)
GROUP = "data"
ORDER = 22


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_options(p, ExportSettings)


def run(args: argparse.Namespace) -> int:
    from waresynth.exporters import export_dataset

    out = export_dataset(
        args.dataset,
        args.out,
        args.format,
        overwrite=args.overwrite,
        progress=not args.quiet,
        yolo_segments=args.yolo_task == "segment",
        slots=args.slots,
    )
    summary = out / ("racklay_export.json" if args.format == "racklay" else "export.json")
    info = json.loads(summary.read_text(encoding="utf-8"))
    if args.format == "racklay":
        lists = info["lists"]
        print(f"wrote {out}: {info['num_frames']} frames, splits {', '.join(info['splits'])}, {info['slots']} slots")
        print(f"reference lists in {out / lists['folder']}: val from {lists['val']['from']}")
    else:
        for split in info["splits"]:
            c = info["counts"][split]
            objs = ", ".join(f"{v} {k}" for k, v in c.items() if k != "images")
            print(f"wrote {out} [{split}]: {c['images']} images, {objs}")
    return 0
