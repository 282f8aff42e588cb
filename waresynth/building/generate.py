"""``mvracklay generate OUT --building [FILE]``: every pass of a planned building (`waresynth.building.plan`) as a
sequence of a WareSynth dataset, with the route record and the building's ground truth.

``OUT`` is a WareSynth dataset (manifest.json, one folder per pass, all in the test split; every reader of a
dataset reads it) plus ``OUT/route.json`` (`waresynth.building.route`) and ``OUT/ground_truth/building.json``
and ``inventory.csv`` (`waresynth.building.truth`), and ``OUT/locations.csv``: the location list a warehouse
management system would export (`layouts.location_list`: codes and spans, no contents). As for any dataset, the same seed and configs give the same
bytes whatever the worker count, and a re-run skips the complete passes.

``rescan=OUT`` writes the same building after a seeded change set (`waresynth.building.changes`), scanned by
passes and cameras of its own (`waresynth.building.rescan`), with ``ground_truth/changes.csv`` and
``location_changes.csv`` beside the rest and ``rescan_of`` in the manifest; the same seed and OUT give the same bytes.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from layouts.errors import InputError
from layouts.fileio import atomic_write_json, atomic_write_text
from layouts.location_list import ListedLocation, write_location_list
from layouts.locations import inventory_csv
from layouts.publish import refuse_overlap
from layouts.spec import LayoutSpec
from layouts.tasks import TaskMap
from waresynth.building.changes import (
    apply_changes,
    changes_csv,
    changes_rows,
    location_change_rows,
    location_changes_csv,
)
from waresynth.building.plan import Building, pass_row, plan_building, replan_passes, route
from waresynth.building.rescan import open_rescan, pass_seed
from waresynth.building.schema import load_building
from waresynth.building.truth import ground_truth
from waresynth.config import load_config
from waresynth.dataset import DATASET_FORMAT, DATASET_VERSION
from waresynth.generate import check_writer_args, write_dataset

ROUTE = "route.json"
GROUND_TRUTH = "ground_truth"
CHANGES = "changes.csv"  #: a rescan's changes, in GROUND_TRUTH
LOCATION_CHANGES = "location_changes.csv"  #: a rescan's changed counts per location, in GROUND_TRUTH
LOCATIONS = "locations.csv"  #: the location list (codes and spans, no contents)


def listed_locations(doc: dict[str, Any]) -> list[ListedLocation]:
    """The location list of a ground truth (``building.json``'s content): a level's span is its bay's (its
    positions' where a level has several), along building X."""
    out = []
    for r in doc["racks"]:
        for lv in r["levels"]:
            many = len(lv["positions"]) > 1
            for pos in lv["positions"]:
                lo, hi = (pos["x_min"], pos["x_max"]) if many else (r["x_min"], r["x_max"])
                out.append(ListedLocation(pos["location"], r["aisle"], r["side"], r["bay"], lv["level"], lo, hi,
                                          pos["position"]))  # fmt: skip
    return out


def generate_building(
    out_dir: str | os.PathLike,
    *,
    building: dict[str, Any] | str | os.PathLike | None = None,
    image_size: tuple[int, int] | None = None,
    spec: LayoutSpec | dict[str, int] | None = None,
    seed: int = 0,
    config: dict[str, Any] | str | os.PathLike | None = None,
    workers: int = 1,
    overwrite: bool = False,
    progress: bool = True,
    stats: list[dict[str, Any]] | None = None,
    rescan: str | os.PathLike | None = None,
    tasks: TaskMap | None = None,
) -> Path:
    """Generate (or resume) a building's passes in ``out_dir``; returns its path. ``building``: the building
    config (a dict, a JSON file or None for `waresynth.building.schema.BUILDING_DEFAULTS`); ``config``: the
    generator config, as for `waresynth.generate.generate_dataset`; ``image_size`` None: 256 x 256.
    ``rescan``: a building dataset to scan again after changes (its racks, configs, spec and image size; the
    options given must agree with them, `waresynth.building.rescan.open_rescan`; ``spec`` may then be a dict of
    the spec's fields given, e.g. ``{"size": 64}``); ``tasks``: where the passes
    are written (`waresynth.generate.write_dataset`)."""
    if rescan is not None:
        return _rescan(out_dir, rescan, building, image_size, spec, seed, config, workers, overwrite, progress, stats,
                       tasks)  # fmt: skip
    seed, workers, spec, size = check_writer_args(seed, workers, spec, (256, 256) if image_size is None else image_size)
    bcfg = load_building(building)
    if "changes" in bcfg:
        src = building if isinstance(building, (str, os.PathLike)) else "building"
        raise InputError(f"{src}: changes (a rescan's change rates) apply only with --rescan OUT")
    cfg = load_config(config)
    plan = plan_building(bcfg, cfg, seed, size, spec.num_slots)
    return _write(Path(out_dir), plan, _manifest(seed, cfg, bcfg, spec, size, plan), overwrite, spec, cfg, size,
                  workers, progress, stats, tasks=tasks)  # fmt: skip


def _rescan(out_dir: str | os.PathLike, rescan: str | os.PathLike, building: dict[str, Any] | str | os.PathLike | None,
            image_size: tuple[int, int] | None, spec: LayoutSpec | dict[str, int] | None, seed: int,
            config: dict[str, Any] | str | os.PathLike | None, workers: int, overwrite: bool, progress: bool,
            stats: list[dict[str, Any]] | None, tasks: TaskMap | None = None) -> Path:  # fmt: skip
    """``generate_building(..., rescan=OUT)``: OUT's stock changed by ``seed``, scanned by passes of its own."""
    layout = spec if isinstance(spec, LayoutSpec) else None  # a dict: only the spec's fields given
    seed, workers, _, _ = check_writer_args(seed, workers, layout, (256, 256) if image_size is None else image_size)
    refuse_overlap([out_dir], {"--rescan": rescan}, "OUT")
    r = open_rescan(rescan, building=building, config=config, spec=spec, image_size=image_size)
    changed, changes = apply_changes(r.stock, r.building["changes"], seed, r.config)
    plan = replan_passes(changed, r.building, r.config, pass_seed(seed, r.depth), r.image_size, r.spec.num_slots)
    manifest = {**_manifest(seed, r.config, r.building, r.spec, r.image_size, plan), "rescan_of": r.record}
    rows = changes_rows(r.stock, changed, changes)
    return _write(Path(out_dir), plan, manifest, overwrite, r.spec, r.config, r.image_size, workers, progress, stats,
                  {CHANGES: changes_csv(rows),
                   LOCATION_CHANGES: location_changes_csv(location_change_rows(r.stock, changed))}, tasks)  # fmt: skip


def _manifest(seed: int, cfg: dict[str, Any], bcfg: dict[str, Any], spec: LayoutSpec, size: tuple[int, int],
              plan: Building) -> dict[str, Any]:  # fmt: skip
    return {
        "format": DATASET_FORMAT,
        "version": DATASET_VERSION,
        "seed": seed,
        "config": cfg,
        "building": bcfg,
        "spec": spec.to_dict(),
        "image_size": list(size),
        "splits": [0.0, 0.0, 1.0],
        "sequences": [{"name": p.name, "split": "test", "seed": p.seed, "frames": p.frames} for p in plan.passes],
    }


def _write(root: Path, plan: Building, manifest: dict[str, Any], overwrite: bool, spec: LayoutSpec,
           cfg: dict[str, Any], size: tuple[int, int], workers: int, progress: bool,
           stats: list[dict[str, Any]] | None, changes: dict[str, str] | None = None,
           tasks: TaskMap | None = None) -> Path:  # fmt: skip
    """The dataset of ``plan``'s passes with the route and the ground truth (and a rescan's ``changes``: file name
    -> text) beside it."""

    def beside(root: Path) -> None:  # the route and the ground truth next to the manifest
        atomic_write_json(root / ROUTE, route(plan))
        doc, rows = ground_truth(plan)
        atomic_write_json(root / GROUND_TRUTH / "building.json", doc)
        atomic_write_text(root / GROUND_TRUTH / "inventory.csv", inventory_csv(rows))
        write_location_list(listed_locations(doc), root / LOCATIONS)
        for name, text in (changes or {}).items():
            atomic_write_text(root / GROUND_TRUTH / name, text)

    plans = {p.name: (pass_row(plan, p), p.camera) for p in plan.passes}
    return write_dataset(root, manifest, overwrite, spec, cfg, size, workers, progress, stats, plans, beside, tasks)
