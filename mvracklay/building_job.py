"""``mvracklay map``: many passes -> one building map (`stitching.building.pipeline`), its inventory and scenes.

Input: a folder holding ``route.json`` (a generated building, `mvracklay generate --building`) or a route file
of one's own (`stitching.building.route`): each pass's ``sequence`` names its sequence folder, image folder or
video, relative to the route file. Each pass is mapped as a row on its own (``--layouts gt``: its ground-truth
layouts; else the network, as `mvracklay run` maps footage) into ``MAP/passes/FOLDER/`` (`pass_folder`: never a
path out of MAP), a task per pass on the local machine's processes or on a Ray cluster (`mvracklay.parallel`); a
pass whose row map is there from an earlier run with the same settings is not mapped again. Then the passes are
placed by the route, registered where they overlap and fused, and ``MAP/building.json``, ``building.glb``,
``building.rrd``, ``inventory.csv`` and ``inventory.json`` are staged and swapped in whole
(`layouts.publish.output_folder`).
MAP follows `mvracklay run`'s rules: never an input, inside one or holding one; missing, empty or an earlier
map's folder unless ``overwrite``; one command at a time (`layouts.publish.lock`).

``locations``: a location list (`layouts.location_list`, CSV) or an earlier building map (its folder or its
``building.json``) whose codes, bays and spans the map takes (`stitching.building.fuse_passes`). With the network and
no ``checkpoint``, the shipped model made for the frames' size maps the passes (`choose_model`).
"""

from __future__ import annotations

import contextlib
import hashlib
import io
import json
import os
import re
import sys
import time
from dataclasses import asdict, dataclass, field, fields, is_dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from tqdm import tqdm

from layouts.errors import InputError
from layouts.fileio import atomic_write_json, load_json
from layouts.location_list import ListedLocation, read_location_list
from layouts.locations import DEFAULT_CODE, check_code_format
from layouts.publish import output_folder, staged
from stitching.building.config import BuildingConfig
from stitching.building.map import BuildingMap, write_inventory
from stitching.building.route import Route, load_route, perturb
from stitching.warehouse_map import WarehouseMap

if TYPE_CHECKING:
    from mvracklay.settings import ComputeSettings, OutputSettings, RunConfig

ROUTE = "route.json"
PASSES = "passes"
OUTPUTS = ("building.json", "building.glb", "building.rrd", "inventory.csv", "inventory.json")
#: what a pass's folder holds besides the run's outputs: the settings it was mapped with
PASS_RECORD = "pass.json"
_PLAIN = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]*$")


@dataclass
class PassTask:
    """One pass to map: where its frames are, where its row map goes, how (picklable: a process or Ray task)."""

    name: str
    source: str
    out: str
    layouts: str  #: "gt" or "net"
    run: RunConfig | None = None  #: how "net" maps the pass (`pass_run`)
    key: str = ""  #: digest of what decides the row map (a stored one with another key is mapped again)


@dataclass
class BuildingResult:
    source: Path  #: the folder the route's passes are relative to
    out: Path
    map: BuildingMap
    mapped: int  #: passes mapped by this run (the rest were there from an earlier one)
    inventory: list[dict[str, Any]]
    written: list[str] = field(default_factory=list)  #: the outputs' file names, in MAP
    worker_peak_mb: float = 0.0  #: the most memory a process mapping a pass held (0: none mapped)
    seconds: float = 0.0  #: wall time of mapping the passes (0: none mapped)
    wall: float = 0.0  #: wall time of the whole map


@dataclass(frozen=True)
class MapSettings:
    """What a building map is made from (`map_building`).

    ``layouts``: ``"gt"`` (a generated building's ground-truth layouts) or ``"net"`` (the network); ``run``: how
    the network maps a pass (`mvracklay.settings.RunConfig`: ``checkpoint``, ``distance``, ``camera_height``, the
    inference; None: its defaults), the map's `ComputeSettings` giving its threads, device and precision;
    ``pose_noise``: (metres, degrees) added to the route's poses, seeded by ``seed``; ``code`` / ``positions``: the
    location code format and positions per level (default: the building config's, else
    `layouts.locations.DEFAULT_CODE` and 1); ``locations``: a location list or an earlier map whose codes the map
    takes (`load_locations`); ``building``: how passes are placed, registered and fused
    (`stitching.building.config.BuildingConfig`)."""

    layouts: str = "net"
    run: RunConfig | None = None
    pose_noise: tuple[float, float] | None = None
    seed: int = 0
    code: str | None = None
    positions: int | None = None
    locations: str | os.PathLike | None = None
    building: BuildingConfig = field(default_factory=BuildingConfig)

    def __post_init__(self) -> None:
        from mvracklay.settings import RunConfig

        if self.layouts not in ("gt", "net"):
            raise InputError(f"--layouts must be 'gt' or 'net', got {self.layouts!r}")
        if not isinstance(self.building, BuildingConfig):
            raise InputError(f"MapSettings.building must be a BuildingConfig, got {type(self.building).__name__}")
        if self.run is not None and not isinstance(self.run, RunConfig):
            raise InputError(f"MapSettings.run must be a RunConfig, got {type(self.run).__name__}")
        base = RunConfig()
        mine = [n for n in COMPUTE_FIELDS if self.run is not None and getattr(self.run, n) != getattr(base, n)]
        if mine:
            raise InputError(f"MapSettings.run: {', '.join(mine)} are the map's (ComputeSettings), not the run's")


#: the `RunConfig` fields a pass takes from the map's `ComputeSettings`
COMPUTE_FIELDS = ("threads", "device", "precision")
#: the `RunConfig` fields a network pass's key always names (the others only where they are not the default)
KEY_FIELDS = ("checkpoint", "distance", "camera_height", "device", "rrd", "progress")


def pass_threads(compute: ComputeSettings) -> int:
    """The threads of one pass: ``--threads`` as given, or ``auto`` shared out (a task per CPU: one each on a Ray
    cluster, the machine's free cores split among the local ``workers``)."""
    from mvracklay.threads import resolve_threads

    threads = resolve_threads(compute.threads)
    if compute.threads == "auto" and (compute.ray is not None or compute.workers > 1):
        threads = 1 if compute.ray is not None else max(1, threads // compute.workers)
    return threads


def pass_run(settings: MapSettings, compute: ComputeSettings) -> RunConfig:
    """How the network maps each pass: ``settings.run`` on the map's compute settings, without a recording or
    progress bar of its own (the building has them)."""
    from mvracklay.settings import RunConfig

    run = settings.run or RunConfig()
    return replace(run, threads=pass_threads(compute), device=compute.device, precision=compute.precision,
                   rrd=False, progress=False)  # fmt: skip


def pass_key(source: str, layouts: str, run: RunConfig | None) -> str:
    """The digest of what decides a pass's row map: its frames, the layouts and the run settings (`KEY_FIELDS`, and
    the others set away from their default), never the thread count (it changes the speed, not the row map)."""
    from mvracklay.settings import RunConfig

    decides: dict[str, Any] = {}
    if run is not None:
        base = RunConfig()
        for f in fields(run):
            value = getattr(run, f.name)
            if f.name != "threads" and (f.name in KEY_FIELDS or value != getattr(base, f.name)):
                decides[f.name] = asdict(value) if is_dataclass(value) else value
    text = json.dumps([source, layouts, decides], sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def resolve_route(path: str | os.PathLike) -> tuple[Route, Path]:
    """The route and the folder its passes' paths are relative to, from a dataset folder or a route file."""
    p = Path(path)
    if p.is_dir():
        if not (p / ROUTE).is_file():
            raise InputError(f"{p}: no {ROUTE} (not a building dataset; give a route file for own footage)")
        p = p / ROUTE
    elif not p.is_file():
        raise InputError(f"{p}: not found")
    route = load_route(p)
    base = p.parent
    for pose in route.passes:
        if not (base / pose.sequence).exists():
            raise InputError(f"{p}: pass {pose.sequence!r}: {base / pose.sequence} not found")
    return route, base


def load_locations(path: str | os.PathLike) -> tuple[list[ListedLocation], str]:
    """(the locations, their source) of ``--locations``: a location list, or an earlier map's folder or
    building.json (its locations, so a rescan keeps the first survey's codes)."""
    p = Path(path)
    building = p / "building.json" if p.is_dir() else p
    if p.is_dir() and not building.is_file():
        raise InputError(f"--locations {p}: a folder without building.json (give a location list or a map)")
    if building.suffix.lower() == ".json":
        return BuildingMap.load(building).listed(), str(building)
    return read_location_list(p), str(p)


def frame_size(route: Route, base: Path) -> int:
    """The shorter side (pixels) of the first pass's frames (a generated building's from its manifest)."""
    size = building_manifest(base).get("image_size")
    if isinstance(size, list) and len(size) == 2 and all(isinstance(v, int) and v > 0 for v in size):
        return min(size)
    from mvracklay.frames import open_source

    src = open_source(base / route.passes[0].sequence, prog="mvracklay map")
    return min(src.width, src.height)


def choose_model(size: int) -> str:
    """The shipped model for frames whose shorter side is ``size`` px: the one trained nearest that size (the
    larger of two as near), among those present. Measured on one building of 256 px frames: 81 % of locations
    exact with ``mvracklay-disc-4-256``, 59 % with the 128 px ``mvracklay-disc-4`` (docs/buildings.md)."""
    import math

    from mvracklay.models import SHIPPED, shipped_path

    have = [(n, _model_size(n)) for n in SHIPPED if shipped_path(n).is_file()]
    if not have:
        return SHIPPED[0]  # absent: the run's own message says so
    return min(have, key=lambda t: (abs(math.log2(t[1] / max(size, 1))), -t[1]))[0]


def _model_size(name: str) -> int:
    from mvracklay.models import shipped_path

    doc = load_json(shipped_path(name).with_suffix(".json"))
    return int(min(doc.get("input_size") or [128]))


def building_manifest(base: Path) -> dict[str, Any]:
    """A generated building's manifest.json ({} for a route of one's own)."""
    manifest = base / "manifest.json"
    doc = load_json(manifest) if manifest.is_file() else {}
    return doc if isinstance(doc, dict) else {}


def building_config(base: Path) -> dict[str, Any]:
    """A generated building's config (manifest.json's ``building``), {} for a route of one's own."""
    doc = building_manifest(base).get("building")
    return doc if isinstance(doc, dict) else {}


def map_pass(task: PassTask) -> tuple[float, list[str]]:
    """Map one pass as a row into ``task.out`` (``warehouse.json``, and the run's outputs for the network);
    returns the peak memory (MB) of the process that mapped it and the warnings it gave (`pass_warnings`), for the
    caller to print with the pass's name. Runs in a worker process or a Ray task."""
    with contextlib.redirect_stderr(io.StringIO()) as said:
        _map_pass(task)
    import resource

    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, pass_warnings(said.getvalue())


def pass_warnings(said: str) -> list[str]:
    """The lines a pass printed on stderr, each without the command it was printed as (``mvracklay run: ``)."""
    return [re.sub(r"^mvracklay[\w. -]*?: ", "", line) for line in said.splitlines() if line.strip()]


def _map_pass(task: PassTask) -> None:
    out = Path(task.out)
    if task.layouts == "gt":
        from mvracklay.reconstruction import gt_upright_columns, resolve_layouts
        from stitching.pipeline import stitch_folder

        folder = resolve_layouts(Path(task.source), "gt")
        ups = gt_upright_columns(Path(task.source), folder.spec.size, folder.spec.x_extent)
        done = stitch_folder(folder, uprights=ups, meta={"layouts": "gt", "source": task.source})
        with staged(out, ("warehouse.json", PASS_RECORD)) as st:
            done.map.save(st / "warehouse.json")
            _record(task, st)
    else:
        from mvracklay.frames import open_source
        from mvracklay.pipeline import run_pipeline

        run_pipeline(open_source(task.source, prog="mvracklay map"), out, task.run)
        _record(task, out)


def _record(task: PassTask, folder: Path) -> None:
    """The settings a pass was mapped with (`PASS_RECORD`), so a later run with the same ones reuses it."""
    atomic_write_json(folder / PASS_RECORD, {"key": task.key, "source": task.source, "layouts": task.layouts})


def _done(task: PassTask) -> bool:
    out = Path(task.out)
    try:
        return (out / "warehouse.json").is_file() and load_json(out / PASS_RECORD).get("key") == task.key
    except (InputError, AttributeError):
        return False


def pass_folder(index: int, sequence: str) -> str:
    """The folder of the route's ``index``-th pass under MAP/passes: its sequence's name when that is one plain
    name (a generated building's ``seq_00003``), else ``pass_NNN-NAME`` of the path's last part (an absolute path,
    ``../../x``, ``a/b``): a pass's outputs never land outside MAP, least of all in its own input."""
    if _PLAIN.match(sequence):
        return sequence
    tail = re.sub(r"[^A-Za-z0-9._-]+", "_", Path(sequence).name).strip("._") or "pass"
    return f"pass_{index:03d}-{tail}"


def pass_tasks(route: Route, base: Path, out: Path, layouts: str, run: RunConfig | None) -> list[PassTask]:
    """A task per pass of ``route``: its frames, its folder under ``out``/passes (`pass_folder`) and its key."""
    tasks, folders = [], {}
    run = run if layouts == "net" else None
    for k, pose in enumerate(route.passes):
        src = str((base / pose.sequence).resolve())
        name = pass_folder(k, pose.sequence)
        if folders.setdefault(name, pose.sequence) != pose.sequence:  # two passes' names alike once made plain
            name = f"pass_{k:03d}-{name}"
        tasks.append(PassTask(pose.sequence, src, str(out / PASSES / name), layouts, run, pass_key(src, layouts, run)))
    return tasks


def _is_map_folder(folder: Path) -> bool:
    """Whether ``folder`` is an earlier `map_building`'s output: its building.json a building map, or none yet
    and the passes mapped so far (an interrupted map, to go on from)."""
    from stitching.building.map import BUILDING_FORMAT

    building = folder / "building.json"
    if not building.exists():
        return (folder / PASSES).is_dir()
    try:
        doc = json.loads(building.read_text(encoding="utf-8"))
    except (OSError, ValueError, RecursionError):
        return False
    return isinstance(doc, dict) and doc.get("format") == BUILDING_FORMAT


def map_inputs(source: str | os.PathLike, tasks: list[PassTask], run: RunConfig | None) -> dict[str, Any]:
    """What MAP must never be, lie inside or hold: DATASET, each pass's footage and the checkpoint."""
    inputs: dict[str, Any] = {"DATASET": source}
    inputs.update({f"pass {t.name!r}": t.source for t in tasks})
    inputs["--checkpoint"] = run.checkpoint if run is not None else None
    return inputs


def map_building(
    source: str | os.PathLike,
    out: str | os.PathLike,
    settings: MapSettings | None = None,
    compute: ComputeSettings | None = None,
    outputs: OutputSettings | None = None,
) -> BuildingResult:
    """Map every pass of the route at ``source`` into ``out`` and fuse them (see the module docstring): what the
    map is made from by ``settings``; ``compute``: the processes (``workers``, or a Ray cluster at ``ray``) and each
    pass's ``threads``, ``device`` and ``precision``; ``outputs``: ``overwrite``, ``rrd`` (building.rrd) and
    ``quiet`` (no bars nor closing line on stderr) of `mvracklay.settings.OutputSettings` (its ``out``, when
    given, is ``out``)."""
    from mvracklay.parallel import run_tasks
    from mvracklay.settings import ComputeSettings, OutputSettings, check_range
    from stitching.building.export import export_building_glb, write_building_rrd
    from stitching.building.fuse_passes import check_listed
    from stitching.building.pipeline import build_map

    start = time.perf_counter()
    settings, compute, outputs = settings or MapSettings(), compute or ComputeSettings(), outputs or OutputSettings()
    if isinstance(compute.workers, bool) or not isinstance(compute.workers, int) or compute.workers < 1:
        raise InputError(f"--workers must be >= 1, got {compute.workers}")
    check_range(ComputeSettings, compute)
    if outputs.out is not None and Path(outputs.out) != Path(out):
        raise InputError(f"map_building: outputs.out {outputs.out} is not out {out}")
    layouts, pose_noise = settings.layouts, settings.pose_noise
    run = pass_run(settings, compute) if layouts == "net" else None
    if run is not None:
        run.validate()
    route, base = resolve_route(source)
    bcfg = building_config(base)
    code = settings.code or bcfg.get("code") or DEFAULT_CODE
    positions = int(settings.positions or bcfg.get("positions") or 1)
    check_code_format(code, positions)
    locations = settings.locations
    listed, listed_source = load_locations(locations) if locations is not None else (None, "")
    if listed is not None:
        check_listed(listed, route, listed_source)
    out = Path(out)
    model = None
    if run is not None:
        if run.checkpoint is None:
            from mvracklay.models import shipped_path

            px = frame_size(route, base)
            model = f"{choose_model(px)} (the shipped model for {px} px frames)"
            run = replace(run, checkpoint=str(shipped_path(model.split()[0])))
        else:
            model = str(run.checkpoint)
    tasks = pass_tasks(route, base, out, layouts, run)
    progress, rrd = not outputs.quiet, outputs.rrd
    # the passes are written into MAP/passes, then the building's files are staged and swapped in whole
    with output_folder(out, OUTPUTS, command="map", earlier=_is_map_folder, inputs=map_inputs(source, tasks, run),
                       overwrite=outputs.overwrite, untouched=(PASSES,), make=True) as st:  # fmt: skip
        todo = [t for t in tasks if not _done(t)]
        peak, folder, t0 = 0.0, {t.name: Path(t.out).name for t in todo}, time.perf_counter()
        for name, (mb, said) in run_tasks(map_pass, [(t.name, t) for t in todo], workers=compute.workers,
                                          ray=compute.ray, progress="map passes" if progress else None):  # fmt: skip
            peak = max(peak, mb)
            for line in said:  # on its own line, above the progress bar
                tqdm.write(f"mvracklay map: {folder[name]}: {line}", file=sys.stderr)
        seconds = time.perf_counter() - t0
        if pose_noise is not None:
            route = perturb(route, pose_noise[0], pose_noise[1], settings.seed)
        maps = {t.name: WarehouseMap.load(Path(t.out) / "warehouse.json") for t in tasks}
        meta = {
            "source": str(source), "layouts": layouts, "passes": len(tasks),
            "pose_noise": list(pose_noise) if pose_noise else None, "seed": settings.seed,
        } | ({"model": model} if model else {})  # fmt: skip
        bmap = build_map(route, maps, settings.building, code=code, positions=positions, meta=meta, listed=listed,
                         listed_source=listed_source)  # fmt: skip
        bmap.save(st / "building.json")
        export_building_glb(bmap, st / "building.glb")
        if rrd:
            write_building_rrd(bmap, maps, st / "building.rrd")
        rows = write_inventory(bmap, st)
    if progress:
        print(f"mvracklay map: {mapped_line(len(todo), len(tasks), out / PASSES)}", file=sys.stderr)
    written = [n for n in OUTPUTS if (out / n).is_file() and (rrd or n != "building.rrd")]
    return BuildingResult(base, out, bmap, len(todo), rows, written, peak, seconds, time.perf_counter() - start)


def mapped_line(mapped: int, passes: int, kept_in: Path) -> str:
    """How many passes this run mapped, and where the others were kept from (an earlier run's row maps)."""
    if mapped == passes:
        return f"{passes} passes mapped"
    if mapped == 0:
        return f"no pass mapped, all {passes} kept from {kept_in}"
    return f"{mapped} of {passes} passes mapped, the rest kept from {kept_in}"


def speed_line(res: BuildingResult) -> str:
    """The map's speed, as `mvracklay run` says its own: the wall time and the seconds a pass mapped took."""
    each = f", {res.seconds / res.mapped:.2f} s a pass mapped ({res.mapped})" if res.mapped else ", no pass mapped"
    return f"speed: {res.wall:.1f} s{each} (wall, this machine)"


def summary(res: BuildingResult) -> str:
    """What the building holds, in a few lines."""
    rows = res.inventory
    scanned = [r for r in rows if r["boxes"] != "not scanned"]
    boxes = sum(int(r["boxes"]) for r in scanned)
    faces = len(res.map.faces)
    racks = sum(len(f.map.racks) for f in res.map.faces)
    model = res.map.meta.get("model")
    listed = res.map.location_list
    return (
        f"{len(res.map.passes)} passes -> {faces} faces, {racks} bays, {len(rows)} locations "
        f"({len(rows) - len(scanned)} not scanned), {boxes} boxes"
        + (f"\nlocations from {listed}: {len(res.map.outside)} boxes outside every listed location" if listed else "")
        + (f"\nmodel: {model}" if model else "")
    )


def evaluate_against_truth(res: BuildingResult) -> dict[str, Any]:
    """The map's figures against a generated building's ``ground_truth/`` (`stitching.building.eval`)."""
    from layouts.locations import read_inventory
    from stitching.building.eval import evaluate_building

    truth = res.source / "ground_truth"
    if not (truth / "building.json").is_file() or not (truth / "inventory.csv").is_file():
        raise InputError(f"--evaluate: {truth} lacks building.json / inventory.csv (not a generated building)")
    rows = read_inventory((truth / "inventory.csv").read_text(), str(truth / "inventory.csv"))
    return evaluate_building(res.map, load_json(truth / "building.json"), rows).to_dict()
