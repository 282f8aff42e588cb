"""``mvracklay diff``: what changed between two scans of a building, per location."""

from __future__ import annotations

import argparse
from pathlib import Path

from layouts.errors import InputError
from mvracklay.settings import add_options
from mvracklay.use_settings import DiffSettings, tolerance_helps

NAME = "diff"
HELP = "what changed between two building maps per location (emptied, filled, count changed), or a map against the WMS"
DESCRIPTION = (
    "Compares two building maps of the same building (`mvracklay map`'s output folders or building.json; any "
    "route poses, camera distances or passes): per location first its count before and after (emptied, filled, "
    "count changed, with a confidence and recount where either row is flagged; DIR/location_changes.csv), then the boxes added, removed, moved (from -> to) and "
    "shifted along their level, and the change of free length, each change with a confidence from both maps. "
    "A location the new scan did not see is `not scanned`, never `removed`. Prints the changes and writes "
    "DIR/changes.csv and changes.json (the columns of a generated rescan's ground_truth/changes.csv, plus "
    "confidence; the JSON also per location), DIR/changes.glb and changes.rrd (added green, removed a red "
    "outline, moved blue with an arrow from where it stood, shifted orange). DIR may be missing, empty or an earlier "
    "diff's folder (--overwrite: any other), never a map compared or inside one; a failed diff leaves it as it was. "
    "With --expected WMS_CSV and one map: the exceptions against the counts the WMS expects (DIR/exceptions.csv)."
)
GROUP = "use"
ORDER = 15
INTERRUPTED = "DIR left as it was"


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_options(p, DiffSettings, helps=tolerance_helps())


def building_path(arg: str | Path, name: str) -> Path:
    path = Path(arg)
    if path.is_dir():
        path = path / "building.json"
    if not path.is_file():
        raise InputError(f"{name} {arg}: no building map there (want `mvracklay map`'s folder or its building.json)")
    return path


def run(args: argparse.Namespace) -> int:
    from dataclasses import replace

    from layouts.locations import read_rows
    from layouts.publish import output_folder
    from stitching.building.diff import DiffConfig, diff_buildings, format_diff
    from stitching.building.diff_export import CHANGE_FILES, is_changes_folder, write_changes
    from stitching.building.eval import evaluate_changes
    from stitching.building.location_counts import score_locations
    from stitching.building.map import BuildingMap
    from stitching.building.schema import check_change_rows

    given = {
        k: v
        for k, v in (("same", args.same), ("size_tol", args.size_tol), ("move_tol", args.move_tol))
        if v is not None
    }
    for name, v in given.items():
        if not 0 <= v <= 5:
            raise InputError(f"--{name.replace('_', '-')} must be in [0, 5] metres, got {v}")
    if args.expected is not None:
        return _expected(args)
    if args.new is None:
        raise InputError("diff: NEW_MAP is missing (or give --expected WMS_CSV to compare one map with the WMS)")
    old_path, new_path = building_path(args.old, "OLD_MAP"), building_path(args.new, "NEW_MAP")
    inputs = {"OLD_MAP": args.old, "NEW_MAP": args.new, "--truth": args.truth}
    with output_folder(
        args.out, CHANGE_FILES, command="diff", earlier=is_changes_folder, inputs=inputs, overwrite=args.overwrite
    ) as stage:  # DIR checked and held first, the changes swapped in whole
        old, new = BuildingMap.load(old_path), BuildingMap.load(new_path)
        truth = None
        if args.truth is not None:
            if not args.truth.is_file():
                raise InputError(f"--truth {args.truth}: file not found")
            truth = read_rows(args.truth.read_text(), ("location", "change"), f"--truth {args.truth}")
            check_change_rows(truth, f"--truth {args.truth}")
        d = diff_buildings(old, new, replace(DiffConfig.for_maps(old, new), **given))
        print(format_diff(d, args.limit))
        scores = evaluate_changes(d.rows(), truth) if truth is not None else None
        beside = args.truth.parent / "location_changes.csv" if truth is not None else None
        per_location = score_locations(d.location_rows(), beside) if beside is not None and beside.is_file() else None
        for cat, s in (scores or {}).items():
            print(f"{cat:<8} precision {s['precision']:.3f} recall {s['recall']:.3f} ({s['tp']} of {s['found']} "
                  f"found, {s['truth']} true)")  # fmt: skip
        if per_location is not None:
            scores["locations"] = per_location
        written = write_changes(old, new, d, stage, rrd=not args.no_rrd, evaluation=scores)
    print("wrote " + ", ".join(str(args.out / n) for n in written))
    return 0


def _expected(args: argparse.Namespace) -> int:
    """``diff MAP --expected WMS_CSV``: the map's exceptions against the WMS's expected counts."""
    from layouts.publish import output_folder
    from stitching.building import location_counts as lc
    from stitching.building.map import BuildingMap

    if args.new is not None:
        raise InputError("diff --expected compares one map with the WMS: give OLD_MAP alone, not NEW_MAP too")
    path = building_path(args.old, "MAP")
    inputs = {"MAP": args.old, "--expected": args.expected}
    with output_folder(args.out, lc.EXCEPTION_FILES, command="diff", earlier=lambda d: (d / "exceptions.csv").is_file(),
                       inputs=inputs, overwrite=args.overwrite) as stage:  # fmt: skip
        expected = lc.read_expected(args.expected)
        rows = lc.expected_exceptions(BuildingMap.load(path), expected)
        print(lc.format_exceptions(rows, len(expected), args.limit))
        lc.write_exceptions(rows, stage)
    print(f"wrote {args.out / 'exceptions.csv'}")
    return 0
