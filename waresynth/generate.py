"""Dataset writer: many sequences (scene + camera path each) rendered with ground truth to disk.

Layout on disk: docs/conventions.md ("WareSynth dataset on disk") and docs/waresynth.md.
Sequence k's seed comes from ``numpy.random.SeedSequence(seed).spawn(N)[k]``, so its bytes do
not depend on the worker count; each sequence is written under a temporary name and renamed
when complete, so an interrupted run resumes where it stopped and a re-run gives identical bytes.
"""

from __future__ import annotations

import json
import math
import multiprocessing as mp
import os
import shutil
from collections.abc import Callable
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from layouts.camera_record import CAMERA_ANGLE_KEYS
from layouts.errors import InputError
from layouts.fileio import atomic_write_json, load_json
from layouts.publish import discard, is_stage_name, is_write_failure, lock, publish, stage, write_failed
from layouts.spec import LayoutSpec
from layouts.tasks import TaskMap, process_map
from waresynth.config import load_config
from waresynth.dataset import DATASET_FORMAT, DATASET_VERSION
from waresynth.look import NEUTRAL
from waresynth.row_plan import CameraPlan, RowPlan
from waresynth.sequence_writer import write_sequence

SPLITS = ("train", "val", "test")
MANIFEST = "manifest.json"


def sequence_name(k: int) -> str:
    return f"seq_{k:05d}"


def sequence_seeds(seed: int, n: int) -> list[int]:
    """Independent per-sequence seeds (63-bit ints) from one dataset seed."""
    return [int(c.generate_state(1, np.uint64)[0] >> np.uint64(1)) for c in np.random.SeedSequence(seed).spawn(n)]


def assign_splits(seed: int, n: int, fractions: tuple[float, float, float]) -> list[str]:
    """Split sequences by the seed; every split with a positive fraction gets one when n allows."""
    counts = [int(math.floor(f * n)) for f in fractions]
    rema = sorted(range(3), key=lambda i: (-(fractions[i] * n - counts[i]), i))
    for i in rema[: n - sum(counts)]:
        counts[i] += 1
    positive = [i for i in range(3) if fractions[i] > 0]
    if n >= len(positive):
        for i in positive:
            if counts[i] == 0:
                j = max(range(3), key=lambda k: counts[k])
                counts[j] -= 1
                counts[i] += 1
    labels = [SPLITS[i] for i in range(3) for _ in range(counts[i])]
    order = np.random.default_rng([seed, 0x5D117]).permutation(n)
    out = [""] * n
    for label, k in zip(labels, order):
        out[int(k)] = label
    return out


def _worker(args: tuple) -> dict[str, Any]:
    root, entry, spec_d, cfg, image_size, nthreads, planned = args
    spec = LayoutSpec.from_dict(spec_d)
    return write_sequence(Path(root), entry, spec, cfg, tuple(image_size), nthreads, planned=planned)


def _pool_context() -> mp.context.BaseContext:
    """Fork while this process has not rendered (no Open3D threads to inherit; workers start at
    once with everything imported); otherwise fork from a clean forkserver that imported the
    renderer once."""
    from waresynth import render

    methods = mp.get_all_start_methods()
    if not render.RENDERER_USED and "fork" in methods:
        return mp.get_context("fork")
    if "forkserver" in methods:
        ctx = mp.get_context("forkserver")
        ctx.set_forkserver_preload(["waresynth.generate"])
        return ctx
    return mp.get_context("spawn")


# ----------------------------------------------------------------------------- whole dataset
def build_manifest(
    *,
    num_sequences: int,
    frames: int,
    image_size: tuple[int, int],
    spec: LayoutSpec,
    seed: int,
    cfg: dict[str, Any],
    splits: tuple[float, float, float],
) -> dict[str, Any]:
    """The manifest of the whole (unsharded) dataset: everything that fixes its bytes."""
    labels = assign_splits(seed, num_sequences, splits)
    seeds = sequence_seeds(seed, num_sequences)
    entries = [
        {"name": sequence_name(k), "split": labels[k], "seed": seeds[k], "frames": frames} for k in range(num_sequences)
    ]
    return {
        "format": DATASET_FORMAT,
        "version": DATASET_VERSION,
        "seed": seed,
        "config": cfg,
        "spec": spec.to_dict(),
        "image_size": [int(image_size[0]), int(image_size[1])],
        "splits": [float(f) for f in splits],
        "sequences": entries,
    }


def parse_shard(shard: tuple[int, int] | str) -> tuple[int, int]:
    """``"i/n"`` or ``(i, n)`` -> ``(i, n)`` with ``0 <= i < n`` (one-line error otherwise)."""
    if isinstance(shard, str):
        parts = shard.split("/")
        try:
            i, n = (int(p) for p in parts)
        except ValueError:
            raise InputError(f"--shard must be I/N (e.g. 0/4), got {shard!r}") from None
    elif isinstance(shard, (tuple, list)) and len(shard) == 2:
        i, n = shard
    else:
        raise InputError(f"shard must be (index, count) or 'I/N', got {shard!r}")
    n = _check_int("shard count", n, 1, 100000)
    i = _check_int("shard index", i, 0, n - 1)
    return i, n


def shard_manifest(full: dict[str, Any], index: int, count: int) -> dict[str, Any]:
    """Shard ``index`` of ``count``: sequences k with ``k % count == index`` plus a ``shard`` record."""
    seqs = full["sequences"]
    return {
        **full,
        "sequences": [e for k, e in enumerate(seqs) if k % count == index],
        "shard": {"index": index, "count": count, "num_sequences": len(seqs)},
    }


def _check_int(name: str, v: Any, lo: int, hi: int) -> int:
    if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or not lo <= v <= hi:
        raise InputError(f"{name} must be an integer in [{lo}, {hi}], got {v!r}")
    return int(v)


def _same_dataset_problem(root: Path, manifest: dict[str, Any]) -> str | None:
    """None when ``root`` holds this very dataset (complete or not), else why it does not."""
    mpath = root / MANIFEST
    if not mpath.is_file():
        return f"{root}: not empty and not a WareSynth dataset"
    try:
        old = load_json(mpath)
    except InputError as e:
        return str(e)
    if not isinstance(old, dict) or old.get("format") != DATASET_FORMAT:
        return f"{mpath}: not a WareSynth manifest"
    manifest = json.loads(json.dumps(manifest))
    cfg = old.get("config") if isinstance(old.get("config"), dict) else {}
    # Keys added since a dataset was written take the value that reproduces it.
    if isinstance(cfg.get("camera"), dict):  # written before the camera could rotate: it was level
        for k in CAMERA_ANGLE_KEYS:
            cfg["camera"].setdefault(k, [0.0, 0.0])
    if isinstance(cfg.get("sensor"), dict):  # written before pixels could be supersampled or blurred
        cfg["sensor"].setdefault("supersample", 1)
        cfg["sensor"].setdefault("motion_blur", [0.0, 0.0])
    for section, keys in NEUTRAL.items():  # written before the look (`waresynth.look`): it was neutral
        if isinstance(cfg.get(section), dict):
            for k, v in keys.items():
                cfg[section].setdefault(k, v)
    if isinstance(cfg.get("rack"), dict):
        cfg["rack"].setdefault("board_textures", ["wood"])
    if old != manifest:
        diff = sorted(k for k in set(old) | set(manifest) if old.get(k) != manifest.get(k))
        return f"{root}: holds a different WareSynth dataset ({', '.join(diff)} differ)"
    return None


def _prepare_root(root: Path, manifest: dict[str, Any], overwrite: bool) -> Path:
    """Where the dataset is written: ``root`` (made, or accepted for resuming), or with ``overwrite`` a stage that
    replaces a foreign ``root`` whole once complete (`layouts.publish.stage`); a foreign one is refused otherwise."""
    if root.exists() and not root.is_dir():
        raise InputError(f"{root}: exists and is not a directory")
    if root.is_dir() and any(not is_stage_name(p.name) for p in root.iterdir()):
        problem = _same_dataset_problem(root, manifest)
        if problem is not None and not overwrite:
            raise InputError(f"{problem}; choose another folder or pass --overwrite")
        if problem is not None:
            resolved = root.resolve()
            if (
                resolved == Path(resolved.anchor)
                or resolved == Path.home().resolve()
                or Path.cwd().resolve().is_relative_to(resolved)
            ):
                raise InputError(
                    f"{root}: refusing to overwrite a filesystem root, the home folder or the working folder"
                )
            return stage(root, "output folder")
    root.mkdir(parents=True, exist_ok=True)
    return root


@dataclass(frozen=True)
class DatasetSettings:
    """A WareSynth dataset to write (`generate_dataset`): what it holds and how it is written."""

    num_sequences: int  #: sequences, one scene and camera path each
    frames: int  #: frames per sequence
    image_size: tuple[int, int] = (256, 256)  #: (width, height) in pixels
    spec: LayoutSpec | None = None  #: the layouts' spec; None: the default
    seed: int = 0  #: same seed and config, same bytes
    config: dict[str, Any] | str | os.PathLike | None = None  #: a dict, a JSON path or None (the defaults)
    splits: tuple[float, float, float] = (0.9, 0.05, 0.05)  #: train, val, test fractions
    #: ``(i, n)`` or ``"i/n"``: only the sequences k with ``k % n == i`` (`waresynth.shards.merge_shards` joins them)
    shard: tuple[int, int] | str | None = None
    workers: int = 1  #: local worker processes
    overwrite: bool = False  #: replace a non-empty folder that is not this same dataset
    progress: bool = True


def generate_dataset(
    out_dir: str | os.PathLike,
    settings: DatasetSettings,
    *,
    stats: list[dict[str, Any]] | None = None,
    tasks: TaskMap | None = None,
) -> Path:
    """Generate (or resume) the WareSynth dataset ``settings`` describes in ``out_dir``; returns its path.

    Complete sequences already on disk are skipped; a non-empty folder that is not this same
    dataset is refused unless ``settings.overwrite``. ``stats``, when a list, receives one cost record per
    sequence written (see `write_sequence`). ``tasks``: where the sequences are written (`write_dataset`).
    """
    if not isinstance(settings, DatasetSettings):
        raise InputError(f"settings must be a DatasetSettings, got {type(settings).__name__}")
    num_sequences, frames, image_size, spec = (
        settings.num_sequences,
        settings.frames,
        settings.image_size,
        settings.spec,
    )
    seed, config, workers, splits, shard = (
        settings.seed,
        settings.config,
        settings.workers,
        settings.splits,
        settings.shard,
    )
    num_sequences = _check_int("num_sequences", num_sequences, 1, 100000)
    frames = _check_int("frames", frames, 1, 100000)
    seed, workers, spec, (w, h) = check_writer_args(seed, workers, spec, image_size)
    if not (
        isinstance(splits, (tuple, list))
        and len(splits) == 3
        and all(isinstance(f, (int, float)) and not isinstance(f, bool) and f >= 0 for f in splits)
        and abs(sum(splits) - 1.0) < 1e-6
    ):
        raise InputError(f"splits must be three fractions (train, val, test) >= 0 summing to 1, got {splits!r}")
    if shard is not None:
        shard = parse_shard(shard)
    cfg = load_config(config)
    root = Path(out_dir)
    manifest = build_manifest(
        num_sequences=num_sequences,
        frames=frames,
        image_size=(w, h),
        spec=spec,
        seed=seed,
        cfg=cfg,
        splits=tuple(float(f) for f in splits),
    )
    if shard is not None:
        manifest = shard_manifest(manifest, *shard)
    return write_dataset(
        root, manifest, settings.overwrite, spec, cfg, (w, h), workers, settings.progress, stats, tasks=tasks
    )


def check_writer_args(
    seed: Any, workers: Any, spec: Any, image_size: Any
) -> tuple[int, int, LayoutSpec, tuple[int, int]]:
    """The arguments every dataset writer takes, checked (one line each): seed, workers, spec (None: the
    default), image size ``(width, height)``."""
    seed = _check_int("seed", seed, 0, 2**63 - 1)
    workers = _check_int("workers", workers, 1, 256)
    spec = LayoutSpec() if spec is None else spec
    if not isinstance(spec, LayoutSpec):
        raise InputError(f"spec must be a LayoutSpec, got {type(spec).__name__}")
    if not (isinstance(image_size, (tuple, list)) and len(image_size) == 2):
        raise InputError(f"image_size must be (width, height), got {image_size!r}")
    size = (_check_int("image width", image_size[0], 16, 8192), _check_int("image height", image_size[1], 16, 8192))
    return seed, workers, spec, size


def write_dataset(
    root: Path,
    manifest: dict[str, Any],
    overwrite: bool,
    spec: LayoutSpec,
    cfg: dict[str, Any],
    image_size: tuple[int, int],
    workers: int,
    progress: bool,
    stats: list[dict[str, Any]] | None = None,
    plans: dict[str, tuple[RowPlan, CameraPlan]] | None = None,
    beside: Callable[[Path], None] | None = None,
    tasks: TaskMap | None = None,
) -> Path:
    """Write (or resume) the dataset ``manifest`` describes in ``root``: the folder checked, the manifest (and
    what ``beside`` writes next to it), stale temporary folders removed, the sequences not yet complete written
    (``plans``: `write_sequence`'s planned rows by name). A full disk is one line; the finished sequences stay
    and the same command resumes.

    ``tasks`` (a `layouts.tasks.TaskMap`): where the sequences are written, one task each rendering on one
    thread (`mvracklay.parallel.task_map` runs them as Ray tasks); ``root`` must then be a folder every worker
    sees at the same path. None: this process (``workers`` 1, all cores to the renderer) or ``workers`` local
    processes. The bytes are the same either way."""
    if tasks is not None and not callable(tasks):
        raise InputError(f"tasks must be a function (fn, items) -> (key, result) pairs, got {type(tasks).__name__}")
    with lock(root, "output folder"):  # one writer at a time
        into = _prepare_root(root, manifest, overwrite)
        try:
            how = _Writing(spec, cfg, image_size, workers, progress, stats, plans or {}, tasks)
            _fill(into, manifest, how, beside)
        except BaseException as e:
            if into != root:
                discard(into)  # a foreign folder replaced only once the new dataset is whole
            if is_write_failure(e, into):  # a full disk: one line; what is kept depends on where it was written
                raise write_failed(e, root, "output folder", RESUMABLE if into == root else "") from None
            raise
        if into != root:
            publish(into, root, None, "output folder")
    return root


@dataclass(frozen=True)
class _Writing:
    """How `write_dataset` writes the sequences: its arguments of that name, passed on together."""

    spec: LayoutSpec
    cfg: dict[str, Any]
    image_size: tuple[int, int]
    workers: int
    progress: bool
    stats: list[dict[str, Any]] | None
    plans: dict[str, tuple[RowPlan, CameraPlan]]  #: the planned row and camera of sequences by name
    tasks: TaskMap | None


def _fill(root: Path, manifest: dict[str, Any], how: _Writing, beside: Callable[[Path], None] | None) -> None:
    """`write_dataset`'s writing into ``root`` (the dataset's folder, or the stage that replaces it)."""
    atomic_write_json(root / MANIFEST, manifest)
    if beside is not None:
        beside(root)
    entries = manifest["sequences"]
    for e in entries:
        shutil.rmtree(root / f".{e['name']}.tmp", ignore_errors=True)
    todo = [e for e in entries if not (root / e["name"] / "meta.json").is_file()]
    if todo:
        _write_sequences(root, todo, how)


#: what is kept when writing the sequences fails (`write_failed`)
RESUMABLE = "; the sequences finished so far are kept: run the same command again to resume"


def _write_sequences(root: Path, todo: list[dict[str, Any]], how: _Writing) -> None:
    """Write the sequences ``todo`` in this process (all cores to the renderer), in a pool of ``how.workers`` or
    through ``how.tasks`` (`write_dataset`)."""
    spec, cfg, image_size, plans, tasks = how.spec, how.cfg, how.image_size, how.plans, how.tasks
    cores = os.cpu_count() or 1
    workers = min(how.workers, len(todo))
    frames = sum(int(e["frames"]) for e in todo)
    bar = tqdm(total=frames, unit="frame", desc="generate", disable=not how.progress, dynamic_ncols=True)
    try:
        if tasks is None and workers == 1:
            for e in todo:
                st = write_sequence(
                    root, e, spec, cfg, image_size, cores, lambda: bar.update(1), planned=plans.get(e["name"])
                )
                if how.stats is not None:
                    how.stats.append(st)
            return
        if tasks is None:
            nthreads = max(1, cores // workers)
            tasks = partial(process_map, workers=workers, mp_context=_pool_context())
        else:
            nthreads = 1
        where = str(root.resolve())  # a worker's working folder may differ from this one's
        jobs = [(e["name"], (where, e, spec.to_dict(), cfg, image_size, nthreads, plans.get(e["name"]))) for e in todo]
        results = iter(tasks(_worker, jobs))
        try:
            for name, st in results:
                if not (root / str(name) / "meta.json").is_file():
                    raise InputError(
                        f"{root}: sequence {name} was written where this machine does not see it; "
                        "the output folder must be one every worker sees at the same path (a shared filesystem)"
                    )
                bar.update(int(st["frames"]))
                if how.stats is not None:
                    how.stats.append(st)
        finally:  # stopped early: the tasks not started are cancelled, the running ones waited for
            getattr(results, "close", lambda: None)()
    finally:
        bar.close()
