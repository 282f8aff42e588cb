"""The box-depth head's inputs kept in a folder between fits (``--keep-cache``).

A kept cache has one part per dataset folder (`part_name`), each with a record of what it depends on
(`cache_key`: the frozen trunk, the head's inputs, the sequences, the frames chosen), so later fits of
other seeds, epochs or head designs on the same trunk, or on more datasets, skip the streamed passes
already made (`network.training.box_cache`). A part's record is written last: an interrupted pass is
redone, never used.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import replace
from pathlib import Path
from typing import Any

import torch

from layouts.errors import InputError
from layouts.fileio import atomic_write_json
from network.model.net import MVRackLay
from network.training.box_cache import (
    ALL_FRAMES,
    CACHE_FIELDS,
    CACHE_RECORD,
    Cache,
    Chain,
    FrameChoice,
    StreamedPass,
    cache_part,
    open_shard,
    shard_name,
)


def model_key(model: MVRackLay) -> dict[str, Any]:
    """What a cache of head inputs takes from the model: the frozen trunk's weights (a digest), the inputs the
    head reads (parallax maps or not), the box-logit offsets and, when not fp32, the trunk graph's precision
    (`network.model.frozen.set_precision`; caches made before it keep their keys)."""
    digest = hashlib.sha256()
    for k, v in sorted(model.state_dict().items()):
        if not k.startswith("box_depth."):
            digest.update(k.encode())
            digest.update(v.detach().cpu().contiguous().view(-1).view(torch.uint8).numpy().tobytes())
    return {
        "trunk_sha256": digest.hexdigest(),
        "parallax": bool(model.cfg.box_parallax),
        "box_logit_offset": {k: float(v) for k, v in sorted(model.box_logit_offset.items())},
        **({} if model.graph_precision == "fp32" else {"precision": model.graph_precision}),
    }


def cache_key(model: MVRackLay | dict[str, Any], seqs: list[Any], choice: FrameChoice = ALL_FRAMES) -> dict[str, Any]:
    """What a cache of head inputs depends on: the model's part (`model_key`, or the model to take it from),
    the training sequences (folders, frame counts and, for one seen through JPEG, its quality), in order, and
    which of their frames (`FrameChoice`)."""
    base = model if isinstance(model, dict) else model_key(model)
    return {**base, "sequences": [sequence_key(s) for s in seqs], **choice.key()}


def sequence_key(seq: Any) -> list[Any]:
    """A sequence's part of `cache_key`: its folder and frame count, and its JPEG quality when compressed
    (`network.data.CompressedSequence`; plain sequences keep the keys of caches made before it)."""
    key: list[Any] = [str(Path(seq.root).resolve()), int(seq.num_frames)]
    quality = getattr(seq, "jpeg_quality", None)
    return key if quality is None else [*key, int(quality)]


def open_kept_cache(folder: Path, key: dict[str, Any]) -> list[Cache] | None:
    """The complete cache in ``folder`` (one piece, or one per shard of a pass split over processes) if it
    was made for ``key``; None if the folder holds none (or an unfinished one); a one-line error if it holds
    another model's or other data's inputs."""
    path = folder / CACHE_RECORD
    if not path.is_file():
        return None
    try:
        rec = json.loads(path.read_text())
        n = int(rec["slots"])
        shards = [int(k) for k in rec.get("shards", [])]
        same = rec["key"] == key
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise InputError(f"{path}: not a box-depth input cache record ({e})") from None
    if not same:
        raise InputError(
            f"--keep-cache {folder}: holds the inputs of another checkpoint, head inputs, trunk precision, training "
            "sequences or choice of frames; give another --keep-cache folder (or remove this one)"
        )
    if not shards:
        return [open_shard(folder, n)]
    if sum(shards) != n:
        raise InputError(f"{path}: its shards' slots do not add up to its own; remove the folder to rebuild it")
    return [c for c in (open_shard(folder / shard_name(k), m) for k, m in enumerate(shards)) if c is not None]


def part_name(folder: Path) -> str:
    """The name of the kept-cache part that holds the inputs of the sequences in ``folder``: readable (the
    folder's name) and unique (a digest of its resolved path)."""
    path = str(Path(folder).resolve())
    return f"{Path(path).name}-{hashlib.sha256(path.encode()).hexdigest()[:8]}"


def by_folder(seqs: list[Any]) -> list[tuple[Path, list[Any]]]:
    """``seqs`` in runs of the same parent folder (a dataset), in order."""
    runs: list[tuple[Path, list[Any]]] = []
    for s in seqs:
        parent = Path(s.root).resolve().parent
        if runs and runs[-1][0] == parent:
            runs[-1][1].append(s)
        else:
            runs.append((parent, [s]))
    return runs


def move_single_part(folder: Path) -> None:
    """A cache kept in the earlier layout (its files and record in ``folder`` itself, one dataset's sequences)
    is moved into its part's folder, where `kept_cache` looks for it (renames only: nothing is rewritten)."""
    record = folder / CACHE_RECORD
    if not record.is_file():
        return
    try:
        first = json.loads(record.read_text())["key"]["sequences"][0][0]
    except (OSError, ValueError, KeyError, TypeError, IndexError) as e:
        raise InputError(f"{record}: not a box-depth input cache record ({e})") from None
    sub = folder / part_name(Path(first).parent)
    if sub.exists():
        raise InputError(f"--keep-cache {folder}: holds a cache both in {folder} and in {sub}; remove one")
    sub.mkdir()
    for k in CACHE_FIELDS:
        if (folder / f"{k}.npy").is_file():
            (folder / f"{k}.npy").rename(sub / f"{k}.npy")
    record.rename(sub / CACHE_RECORD)  # last: the part counts as finished only with all its files


def kept_cache(job: StreamedPass, seqs: list[Any], folder: Path) -> tuple[Chain, int]:
    """``(chain, reused)``: the inputs of ``seqs`` streamed as ``job`` says (but to the end: no ``deadline``), kept in
    ``folder``, one part (`part_name`) per folder the sequences sit in, so a fit on more data reuses the parts
    already made. A part with a finished cache for this model and its sequences is reused (``reused`` counts
    them), an absent or unfinished one is made (`cache_part`, its record written last: an interrupted pass is
    redone, never used)."""
    move_single_part(folder)
    parts, reused = [], 0
    base = model_key(job.model)  # the trunk's digest once, not per part
    for parent, group in by_folder(seqs):
        sub = folder / part_name(parent)
        key = cache_key(base, group, job.choice)
        kept = open_kept_cache(sub, key)
        if kept is not None:
            parts.extend(kept)
            reused += 1
            continue
        sub.mkdir(parents=True, exist_ok=True)
        made, shards, _ = cache_part(replace(job, deadline=None), group, sub)
        rec: dict[str, Any] = {"key": key, "slots": sum(len(c) for c in made)}
        atomic_write_json(sub / CACHE_RECORD, rec if shards is None else {**rec, "shards": shards})
        parts.extend(made)
    return Chain(parts), reused
