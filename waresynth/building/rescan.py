"""A rescan of a generated building (``mvracklay generate OUT2 --building --rescan OUT``): OUT's stock re-planned
from its manifest, checked against its ground truth, and what a rescan takes from OUT and may change.

A rescan keeps OUT's racks and stacks (the building config's `RACK_KEYS`, the generator config's ``rack`` and
``boxes``, the image size and layout spec); its building config may differ in the pass keys (``pass_length``,
``overlap``, ``twice_share``) and ``changes``, its generator config in anything else. OUT may itself be a
rescan: its manifest's ``rescan_of`` names the seed the racks were planned from and the change sets applied
since, so its stock is planned again exactly (docs/waresynth.md, "Rescans").
"""

from __future__ import annotations

import copy
import hashlib
import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from layouts.errors import InputError
from layouts.fileio import load_json
from layouts.spec import LayoutSpec
from waresynth.building.changes import apply_changes
from waresynth.building.plan import Building, plan_building
from waresynth.building.schema import RACK_KEYS, change_rates, load_building
from waresynth.building.truth import ground_truth
from waresynth.config import load_config

#: the generator config's sections the racks and stacks are drawn from: a rescan keeps them
STOCK_SECTIONS = ("rack", "boxes")


@dataclass
class Rescan:
    """What a rescan of ``source`` writes from: its building and generator configs, spec, image size, OUT's stock
    (the building as OUT's ground truth holds it) and the manifest's ``rescan_of`` record."""

    source: Path
    building: dict[str, Any]  #: the rescan's building config, ``changes`` filled in
    config: dict[str, Any]
    spec: LayoutSpec
    image_size: tuple[int, int]
    stock: Building
    record: dict[str, Any] = field(default_factory=dict)

    @property
    def depth(self) -> int:
        """1 for a rescan of an original building, 2 for a rescan of a rescan, ..."""
        return len(self.record["earlier_changes"]) + 1


def digest(bcfg: dict[str, Any]) -> str:
    """sha256 of a building config's canonical JSON (sorted keys, no spaces)."""
    return hashlib.sha256(json.dumps(bcfg, sort_keys=True, separators=(",", ":")).encode()).hexdigest()


def pass_seed(seed: int, depth: int) -> int:
    """The seed a rescan's passes and cameras are drawn from: the run's seed and the rescan's depth, so a rescan
    with OUT's own seed still draws cameras of its own."""
    return int(np.random.SeedSequence([seed, 0x2E5C, depth]).generate_state(1, np.uint64)[0] >> 1)


def _int(v: Any) -> bool:
    return isinstance(v, int) and not isinstance(v, bool) and 0 <= v < 2**63


def _read(source: Path) -> dict[str, Any]:
    """OUT's manifest when it is a building dataset; one line else."""
    from waresynth.dataset import read_manifest

    if not source.is_dir():
        raise InputError(f"--rescan {source}: not a folder")
    try:
        mpath, m = read_manifest(source)
    except InputError as e:
        raise InputError(f"--rescan: {e}") from None
    keys = ("building", "config", "seed", "spec", "image_size")
    if not isinstance(m.get("building"), dict) or any(k not in m for k in keys):
        raise InputError(f"--rescan {source}: not a building dataset (written by `generate --building`)")
    if not _int(m["seed"]):
        raise InputError(f"{mpath}: seed must be a non-negative integer, got {m['seed']!r}")
    return m


def _chain(source: Path, m: dict[str, Any]) -> tuple[int, list[dict[str, Any]]]:
    """(the seed OUT's racks were planned from, the change sets applied since, in order) from its manifest."""
    if "rescan_of" not in m:
        return m["seed"], []
    r = m["rescan_of"]
    bad = InputError(f"{source / 'manifest.json'}: rescan_of must hold racks_seed and earlier_changes")
    if not isinstance(r, dict) or not _int(r.get("racks_seed")) or not isinstance(r.get("earlier_changes"), list):
        raise bad
    earlier = []
    for c in r["earlier_changes"]:
        if not isinstance(c, dict) or not _int(c.get("seed")):
            raise bad
        earlier.append({"seed": c["seed"], "rates": change_rates(c.get("rates"), "rescan_of.earlier_changes.rates")})
    rates = change_rates(m["building"].get("changes"), f"{source / 'manifest.json'}: building.changes")
    return r["racks_seed"], [*earlier, {"seed": m["seed"], "rates": rates}]


def _differ(a: dict[str, Any], b: dict[str, Any], keys: tuple[str, ...] | list[str]) -> list[str]:
    return [k for k in keys if json.dumps(a.get(k), sort_keys=True) != json.dumps(b.get(k), sort_keys=True)]


def open_rescan(
    source: str | os.PathLike,
    *,
    building: dict[str, Any] | str | os.PathLike | None,
    config: dict[str, Any] | str | os.PathLike | None,
    spec: LayoutSpec | dict[str, Any] | None,
    image_size: tuple[int, int] | None,
) -> Rescan:
    """Read and check a rescan of ``source``: the options given (None: OUT's; ``spec`` a `LayoutSpec` or a dict
    of the fields given) must keep OUT's racks (one line naming what differs); OUT's stock is planned again and
    must match its ``ground_truth/building.json``."""
    source = Path(source)
    m = _read(source)
    try:
        base = load_building(copy.deepcopy(m["building"]))
    except InputError as e:
        raise InputError(f"{source / 'manifest.json'}: {e}") from None
    bcfg = copy.deepcopy(base) if building is None else load_building(building)
    differ = _differ(bcfg, base, RACK_KEYS)
    if differ:
        raise InputError(
            f"--rescan {source}: the building config differs from its own in {', '.join(differ)} (a rescan keeps "
            "the racks: only pass_length, overlap, twice_share and changes may differ)"
        )
    bcfg["changes"] = change_rates(bcfg.get("changes"), "--building: changes")
    cfg = load_config(copy.deepcopy(m["config"]))
    if config is not None:
        given = load_config(config)
        differ = _differ(given, cfg, STOCK_SECTIONS)
        if differ:
            raise InputError(
                f"--rescan {source}: --config differs from its config in {', '.join(differ)} (a rescan keeps the "
                f"racks and boxes: only the other sections may differ)"
            )
        cfg = given
    own_spec = LayoutSpec.from_dict(m["spec"], f"{source / 'manifest.json'}: spec")
    given = spec.to_dict() if isinstance(spec, LayoutSpec) else dict(spec or {})
    differ = {k: v for k, v in given.items() if own_spec.to_dict().get(k) != v}
    if differ:
        said = ", ".join(f"{k} {v} (its own {own_spec.to_dict().get(k)})" for k, v in differ.items())
        raise InputError(f"--rescan {source}: the layout spec (--slots / --layout-size) differs from its own: {said}")
    size = m["image_size"]
    if not (isinstance(size, list) and len(size) == 2 and all(_int(v) for v in size)):
        raise InputError(f"{source / 'manifest.json'}: image_size must be [width, height], got {size!r}")
    if image_size is not None and tuple(image_size) != tuple(size):
        raise InputError(
            f"--rescan {source}: image size {tuple(image_size)} differs from its own {tuple(size)} (--size)"
        )
    racks_seed, chain = _chain(source, m)
    stock = plan_building(base, cfg, racks_seed, (size[0], size[1]), own_spec.num_slots)
    for c in chain:
        stock, _ = apply_changes(stock, c["rates"], c["seed"], cfg)
    truth = source / "ground_truth" / "building.json"
    if not truth.is_file():
        raise InputError(f"--rescan {source}: no ground_truth/building.json (an interrupted building?)")
    if load_json(truth) != json.loads(json.dumps(ground_truth(stock)[0])):
        raise InputError(f"{truth}: not the building its manifest plans (edited, or written by another version)")
    record = {"seed": m["seed"], "building_sha256": digest(m["building"]), "racks_seed": racks_seed,
              "earlier_changes": chain}  # fmt: skip
    return Rescan(source, bcfg, cfg, own_spec, (size[0], size[1]), stock, record)
