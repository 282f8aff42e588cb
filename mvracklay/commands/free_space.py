"""``mvracklay free-space``: free length/area/volume per shelf of a warehouse map, and where a box fits."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from layouts.errors import InputError
from mvracklay.settings import add_options
from mvracklay.use_settings import FreeSpaceSettings

NAME = "free-space"
HELP = "free space per shelf of a map (a row's warehouse.json or a building), and where a box fits"
DESCRIPTION = (
    "Reads a map written by `mvracklay run` or `reconstruct` (MAP: the warehouse.json or their output folder) "
    "and prints, per shelf, the number of boxes, the "
    "free length along the shelf inside its uprights (gaps between boxes and uprights; a rack's ends are its "
    "uprights' outer faces, a box stands 0.11 m inside them), free area, free volume (up to the clear height), "
    "occupancy (the share of that length under a box) and a confidence. A shelf of a rack cut by the first or last view is marked partial (start: its "
    "low-X end, end: its high-X end): its length is the seen part and the gap running to the cut end counts as "
    "unknown, not free (nor as a place for a box). With --box WxDxH (metres) it also lists the shelves and the X ranges "
    "(map frame, metres from the first camera position) where the box's centre can go: the box and its --margin "
    "clear of the uprights and of every box (on a map the network made, 5 cm more clear of its boxes). "
    "MAP may also be a building map (`mvracklay map`: its folder or building.json): then the table has one row "
    "per location (its code; `not scanned` where no pass saw it) and --box lists the scanned locations across the "
    "building where the box fits, nearest to --near CODE first, with the box centre's building X ranges."
)
GROUP = "use"
ORDER = 12


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_options(p, FreeSpaceSettings)


def map_path(arg: str) -> Path:
    """The map MAP names: the file, or OUT/warehouse.json (a run's) or OUT/building.json (`map`'s) in a folder."""
    path = Path(arg)
    if path.is_dir() and (path / "building.json").is_file() and not (path / "warehouse.json").is_file():
        return path / "building.json"
    if path.is_dir():
        if not (path / "warehouse.json").is_file():
            raise InputError(f"{path}: no warehouse.json in this folder (want a run's --out folder or a map file)")
        return path / "warehouse.json"
    if not path.is_file():
        raise InputError(f"{path}: map file not found")
    return path


def run(args: argparse.Namespace) -> int:
    from stitching.free_space import fits, format_table, free_space, free_space_csv, parse_box
    from stitching.warehouse_map import WarehouseMap

    path = map_path(args.map)
    if not (0 <= args.margin <= 10):
        raise InputError(f"--margin must be in [0, 10] metres, got {args.margin}")
    if args.json and args.csv:
        raise InputError("choose one of --json and --csv")
    if _is_building(path):
        return _building(path, args)
    if args.near or args.with_recount:
        raise InputError(
            f"{'--near' if args.near else '--with-recount'} is for a building map (`mvracklay map`'s output)"
        )
    wmap = WarehouseMap.load(path)
    rows = free_space(wmap)
    if args.shelf:
        wmap.shelf(args.shelf)  # one-line error when unknown
        rows = [r for r in rows if r.shelf == args.shelf]
    placements = None
    if args.box:
        w, d, h = parse_box(args.box)
        placements = [f for f in fits(wmap, w, d, h, args.margin) if not args.shelf or f.shelf == args.shelf]
    if args.csv:
        print(free_space_csv(rows, placements), end="")
        return 0
    if args.json:
        out = {"map": str(path), "racks": len(wmap.racks), "shelves": [r.to_dict() for r in rows]}
        if placements is not None:
            out["box"] = {
                "size": list(parse_box(args.box)),
                "margin": args.margin,
                "fits": [f.to_dict() for f in placements],
            }
        print(json.dumps(out, indent=2, sort_keys=True))
        return 0
    print(format_table(rows, racks=len(wmap.racks)))
    if placements is not None:
        print()
        if not placements:
            print(f"a {args.box} box (margin {args.margin} m) fits on no shelf")
        for f in placements:
            ranges = ", ".join(f"[{a:.2f}, {b:.2f}]" for a, b in f.centres)
            turn = " turned 90 deg" if f.rotated else ""
            print(f"fits on {f.shelf}{turn}: centre X in {ranges}")
    return 0


def _is_building(path: Path) -> bool:
    if path.name == "building.json":
        return True
    with open(path, "rb") as f:
        return b'"mvracklay-building-map"' in f.read(4096)


def _building(path: Path, args: argparse.Namespace) -> int:
    """A building map: its inventory, and with --box the locations the box fits, nearest to --near first."""
    from stitching.building.free import building_fits, check_near, format_fits, format_inventory
    from stitching.building.map import BuildingMap
    from stitching.free_space import parse_box

    if args.shelf:
        raise InputError("--shelf is for a row map; a building map's rows are locations (use --near CODE)")
    bmap = BuildingMap.load(path)
    near = check_near(bmap, args.near)
    rows = bmap.inventory()
    found = None
    if args.box:
        w, d, h = parse_box(args.box)
        found = building_fits(bmap, w, d, h, args.margin, near, with_recount=args.with_recount, inventory=rows)
    if args.json:
        out: dict = {"map": str(path), "locations": rows}
        if found is not None:
            out["box"] = {"size": list(parse_box(args.box)), "margin": args.margin, "near": near,
                          "fits": [f.to_dict() for f in found]}  # fmt: skip
        print(json.dumps(out, indent=2, sort_keys=True))
        return 0
    if args.csv:
        from layouts.locations import rows_csv
        from stitching.building.recount import MAP_INVENTORY_COLUMNS

        print(rows_csv(rows, MAP_INVENTORY_COLUMNS), end="")
        return 0
    print(format_fits(found, args.box) if found is not None else format_inventory(rows))
    return 0
