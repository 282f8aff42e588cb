"""``mvracklay free-space``: free length/area/volume per shelf of a warehouse map, and where a box fits."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from layouts.errors import InputError

NAME = "free-space"
HELP = "free space per shelf of a warehouse.json, and where a box of a given size fits"
DESCRIPTION = (
    "Reads a map written by `mvracklay reconstruct` and prints, per shelf, the number of boxes, the "
    "free length along the shelf (gaps between boxes), free area, free volume (up to the clear height), "
    "occupancy and a confidence. With --box WxDxH (metres) it also lists the shelves and the X ranges "
    "(map frame, metres from the first camera position) where the box's centre can go."
)
GROUP = "use"
ORDER = 12


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("map", metavar="MAP", help="warehouse.json written by `mvracklay reconstruct`")
    p.add_argument("--box", help="box size WxDxH in metres, e.g. 0.4x0.3x0.3")
    p.add_argument("--margin", type=float, default=0.02, help="clearance in metres on each side and above the box")
    p.add_argument("--shelf", help="only this shelf id, e.g. rack_00/shelf_01")
    p.add_argument("--json", action="store_true", help="print JSON instead of a table")
    p.add_argument("--csv", action="store_true", help="print CSV (one row per shelf) instead of a table")


def run(args: argparse.Namespace) -> int:
    from stitching.free_space import fits, format_table, free_space, parse_box
    from stitching.warehouse_map import WarehouseMap

    path = Path(args.map)
    if not path.is_file():
        raise InputError(f"{path}: map file not found")
    if not (args.margin >= 0):
        raise InputError(f"--margin must be >= 0 metres, got {args.margin}")
    wmap = WarehouseMap.load(path)
    rows = free_space(wmap)
    if args.shelf:
        wmap.shelf(args.shelf)  # one-line error when unknown
        rows = [r for r in rows if r.shelf == args.shelf]
    placements = []
    if args.box:
        w, d, h = parse_box(args.box)
        placements = [f for f in fits(wmap, w, d, h, args.margin) if not args.shelf or f.shelf == args.shelf]
    if args.json and args.csv:
        raise InputError("choose one of --json and --csv")
    if args.csv:
        cols = ["shelf", "boxes", "length", "depth", "clear_height", "free_length", "free_area", "free_volume"]
        cols += ["occupancy", "confidence"]
        print(",".join(cols))
        for r in rows:
            d = r.to_dict()
            print(",".join(str(d[c]) for c in cols))
        return 0
    if args.json:
        out = {"map": str(path), "shelves": [r.to_dict() for r in rows]}
        if args.box:
            out["box"] = {
                "size": list(parse_box(args.box)),
                "margin": args.margin,
                "fits": [f.to_dict() for f in placements],
            }
        print(json.dumps(out, indent=2, sort_keys=True))
        return 0
    print(format_table(rows))
    if args.box:
        print()
        if not placements:
            print(f"a {args.box} box (margin {args.margin} m) fits on no shelf")
        for f in placements:
            ranges = ", ".join(f"[{a:.2f}, {b:.2f}]" for a, b in f.centres)
            turn = " turned 90 deg" if f.rotated else ""
            print(f"fits on {f.shelf}{turn}: centre X in {ranges}")
    return 0
