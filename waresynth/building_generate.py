"""``mvracklay generate OUT --building [FILE]``: every pass of a planned building (`waresynth.building`) as a
sequence of a WareSynth dataset, with the route record and the building's ground truth.

``OUT`` is a WareSynth dataset (manifest.json, one folder per pass, all in the test split; every reader of a
dataset reads it) plus ``OUT/route.json`` (`waresynth.building.route`) and ``OUT/ground_truth/building.json``
and ``inventory.csv`` (`waresynth.building_truth`). As for any dataset, the same seed and configs give the same
bytes whatever the worker count, and a re-run skips the complete passes.
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path
from typing import Any

from layouts.errors import InputError
from layouts.fileio import atomic_write_json, atomic_write_text
from layouts.publish import is_write_failure, write_failed
from layouts.spec import LayoutSpec
from waresynth.building import pass_row, plan_building, route
from waresynth.building_schema import load_building
from waresynth.building_truth import ground_truth, inventory_csv
from waresynth.config import load_config
from waresynth.dataset import DATASET_FORMAT, DATASET_VERSION
from waresynth.generate import MANIFEST, RESUMABLE, _check_int, _prepare_root, _write_sequences

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
) -> Path:
    """Generate (or resume) a building's passes in ``out_dir``; returns its path. ``building``: the building
    config (a dict, a JSON file or None for `waresynth.building_schema.BUILDING_DEFAULTS`); ``config``: the
    generator config, as for `waresynth.generate.generate_dataset`."""
    seed = _check_int("seed", seed, 0, 2**63 - 1)
    workers = _check_int("workers", workers, 1, 256)
    spec = LayoutSpec() if spec is None else spec
    if not isinstance(spec, LayoutSpec):
        raise InputError(f"spec must be a LayoutSpec, got {type(spec).__name__}")
    if not (isinstance(image_size, (tuple, list)) and len(image_size) == 2):
        raise InputError(f"image_size must be (width, height), got {image_size!r}")
    size = (_check_int("image width", image_size[0], 16, 8192), _check_int("image height", image_size[1], 16, 8192))
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
    root = Path(out_dir)
    _prepare_root(root, manifest, overwrite)
    atomic_write_json(root / MANIFEST, manifest)
    atomic_write_json(root / ROUTE, route(plan))
    doc, rows = ground_truth(plan)
    atomic_write_json(root / GROUND_TRUTH / "building.json", doc)
    atomic_write_text(root / GROUND_TRUTH / "inventory.csv", inventory_csv(rows))
    for stale in root.glob(".pass_*.tmp"):
        shutil.rmtree(stale)
    todo = [e for e in manifest["sequences"] if not (root / e["name"] / "meta.json").is_file()]
    plans = {p.name: (pass_row(plan, p), p.camera) for p in plan.passes}
    if todo:
        try:
            _write_sequences(root, todo, spec, cfg, size, workers, progress, stats, plans)
        except OSError as e:
            if not is_write_failure(e, root):
                raise
            raise write_failed(e, root, "output folder", RESUMABLE) from None
    return root
