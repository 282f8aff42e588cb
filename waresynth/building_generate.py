"""``mvracklay generate OUT --building [FILE]``: every pass of a planned building (`waresynth.building`) as a
sequence of a WareSynth dataset, with the route record and the building's ground truth.

``OUT`` is a WareSynth dataset (manifest.json, one folder per pass, all in the test split; every reader of a
dataset reads it) plus ``OUT/route.json`` (`waresynth.building.route`) and ``OUT/ground_truth/building.json``
and ``inventory.csv`` (`waresynth.building_truth`). As for any dataset, the same seed and configs give the same
bytes whatever the worker count, and a re-run skips the complete passes.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from layouts.fileio import atomic_write_json, atomic_write_text
from layouts.locations import inventory_csv
from layouts.spec import LayoutSpec
from layouts.tasks import TaskMap
from waresynth.building import pass_row, plan_building, route
from waresynth.building_schema import load_building
from waresynth.building_truth import ground_truth
from waresynth.config import load_config
from waresynth.dataset import DATASET_FORMAT, DATASET_VERSION
from waresynth.generate import check_writer_args, write_dataset

ROUTE = "route.json"
GROUND_TRUTH = "ground_truth"


def generate_building(
    out_dir: str | os.PathLike,
    *,
    building: dict[str, Any] | str | os.PathLike | None = None,
    image_size: tuple[int, int] = (256, 256),
    spec: LayoutSpec | None = None,
    seed: int = 0,
    config: dict[str, Any] | str | os.PathLike | None = None,
    workers: int = 1,
    overwrite: bool = False,
    progress: bool = True,
    stats: list[dict[str, Any]] | None = None,
    tasks: TaskMap | None = None,
) -> Path:
    """Generate (or resume) a building's passes in ``out_dir``; returns its path. ``building``: the building
    config (a dict, a JSON file or None for `waresynth.building_schema.BUILDING_DEFAULTS`); ``config``: the
    generator config, as for `waresynth.generate.generate_dataset`; ``tasks``: where the passes are written
    (`waresynth.generate.write_dataset`)."""
    seed, workers, spec, size = check_writer_args(seed, workers, spec, image_size)
    bcfg = load_building(building)
    cfg = load_config(config)
    plan = plan_building(bcfg, cfg, seed, size, spec.num_slots)
    manifest = {
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

    def beside(root: Path) -> None:  # the route and the ground truth next to the manifest
        atomic_write_json(root / ROUTE, route(plan))
        doc, rows = ground_truth(plan)
        atomic_write_json(root / GROUND_TRUTH / "building.json", doc)
        atomic_write_text(root / GROUND_TRUTH / "inventory.csv", inventory_csv(rows))

    plans = {p.name: (pass_row(plan, p), p.camera) for p in plan.passes}
    return write_dataset(
        Path(out_dir), manifest, overwrite, spec, cfg, size, workers, progress, stats, plans, beside, tasks
    )
