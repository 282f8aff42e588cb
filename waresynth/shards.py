"""Join shards written by ``mvracklay generate --shard I/N`` into one WareSynth dataset.

Shard i of n holds the sequences k with ``k % n == i`` (round robin, so every shard gets the
same number of sequences give or take one) and a manifest with the shard's subset plus a
``shard`` record ``{index, count, num_sequences}``. Merging checks that every shard has the
same settings, that together they hold each sequence exactly once and that each is complete,
then moves (or hard-links) the sequence folders into OUT and writes the whole manifest last,
atomically. The result is byte-identical to an unsharded run of the same command. An
interrupted merge is resumed by running it again: sequences already in OUT are accepted.
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path
from typing import Any

from tqdm import tqdm

from layouts.errors import InputError
from layouts.fileio import atomic_write_json, load_json
from layouts.publish import is_write_failure, lock, refuse_overlap, write_failed
from layouts.spec import LayoutSpec
from waresynth.dataset import check_sequence_name, read_manifest
from waresynth.generate import MANIFEST, build_manifest

#: manifest keys that must agree between shards (they fix every sequence's bytes)
SETTINGS = ("format", "version", "seed", "config", "spec", "image_size", "splits")


def _read_shard(folder: Path) -> dict[str, Any]:
    mpath, m = read_manifest(folder, "shard")
    shard = m.get("shard")
    if not (
        isinstance(shard, dict) and all(isinstance(shard.get(k), int) for k in ("index", "count", "num_sequences"))
    ):
        raise InputError(f"{mpath}: not a shard (no shard record; it was not written with --shard I/N)")
    missing = [k for k in (*SETTINGS, "sequences") if k not in m]
    if missing:
        raise InputError(f"{mpath}: manifest lacks {missing}")
    if not isinstance(m["sequences"], list):
        raise InputError(f"{mpath}: 'sequences' must be a list")
    for e in m["sequences"]:
        if not isinstance(e, dict):
            raise InputError(f"{mpath}: sequence entries must be objects")
        check_sequence_name(e.get("name"), mpath)
    return m


def _expected_manifest(first: dict[str, Any], source: Path) -> dict[str, Any]:
    """Rebuild the unsharded manifest from a non-empty shard's settings (this validates them)."""
    try:
        w, h = first["image_size"]
        return build_manifest(
            num_sequences=int(first["shard"]["num_sequences"]),
            frames=int(first["sequences"][0]["frames"]),
            image_size=(int(w), int(h)),
            spec=LayoutSpec.from_dict(first["spec"], str(source)),
            seed=int(first["seed"]),
            cfg=first["config"],
            splits=tuple(float(f) for f in first["splits"]),
        )
    except InputError:
        raise
    except (TypeError, ValueError, KeyError, IndexError) as e:
        raise InputError(f"{source}: malformed shard manifest ({type(e).__name__}: {e})") from None


def _plan(out: Path, shard_dirs: list[Path]) -> tuple[dict[str, Any], dict[str, Path | None]]:
    """Validate the shards and OUT; return the merged manifest and, per sequence, its shard folder
    (None when an interrupted merge already put it in OUT)."""
    if not shard_dirs:
        raise InputError("give at least one SHARD_DIR")
    manifests = [_read_shard(d) for d in shard_dirs]
    ref, ref_dir = manifests[0], shard_dirs[0]
    for m, d in zip(manifests[1:], shard_dirs[1:]):
        diff = [k for k in SETTINGS if m[k] != ref[k]]
        for k in ("count", "num_sequences"):
            if m["shard"][k] != ref["shard"][k]:
                diff.append(f"shard.{k}")
        if diff:
            raise InputError(f"{d}: generated with other settings than {ref_dir} ({', '.join(diff)} differ)")
    count = ref["shard"]["count"]
    seen: dict[int, Path] = {}
    for m, d in zip(manifests, shard_dirs):
        i = m["shard"]["index"]
        if i in seen:
            raise InputError(f"{d}: shard {i}/{count} given twice (also {seen[i]})")
        seen[i] = d
    frames_by = [m["sequences"][0].get("frames") for m in manifests if m["sequences"]]
    if len(set(frames_by)) > 1:
        raise InputError(f"{shard_dirs[0]}: shards have different frame counts {sorted(set(map(str, frames_by)))}")
    source = next((d for m, d in zip(manifests, shard_dirs) if m["sequences"]), ref_dir)
    first = next((m for m in manifests if m["sequences"]), ref)
    full = _expected_manifest(first, source / MANIFEST)
    for k in SETTINGS:
        full[k] = ref[k]  # keep the shards' own spelling (the same bytes as an unsharded run)
    want = {e["name"]: e for e in full["sequences"]}
    owner: dict[str, Path] = {}
    for m, d in zip(manifests, shard_dirs):
        for e in m["sequences"]:
            name = e["name"]
            if name in owner:
                raise InputError(f"{d}: sequence {name} is also in {owner[name]} (overlapping shards)")
            if want.get(name) != e:
                raise InputError(f"{d / MANIFEST}: entry {name} does not belong to this dataset")
            owner[name] = d
    absent = [n for n in want if n not in owner]
    if absent:
        missing_shards = sorted(set(range(count)) - set(seen))
        raise InputError(
            f"{out}: sequences missing from the shards given: {', '.join(absent[:3])}"
            f"{' ...' if len(absent) > 3 else ''} (shards {missing_shards} of {count} not given?)"
        )
    if out.exists() and not out.is_dir():
        raise InputError(f"{out}: exists and is not a directory")
    resolved = {d.resolve() for d in shard_dirs}
    if out.exists() and out.resolve() in resolved:
        raise InputError(f"{out}: is one of the shards; merge into a new folder")
    if out.is_dir():
        for p in out.iterdir():
            if p.name == MANIFEST:
                old = load_json(p)
                if old != full:
                    raise InputError(f"{p}: OUT holds a different dataset; choose an empty folder")
            elif not (p.name in want or (p.name.startswith(".") and p.name.endswith(".tmp"))):
                raise InputError(f"{out}: not empty ({p.name} is not part of this dataset); choose an empty folder")
    plan: dict[str, Path | None] = {}
    for name, d in owner.items():
        if (d / name / "meta.json").is_file():
            plan[name] = d
        elif (out / name / "meta.json").is_file():
            plan[name] = None  # moved there by an interrupted merge
        else:
            raise InputError(f"{d / name}: sequence incomplete or missing (re-run that shard's generate to finish it)")
    return full, plan


def _link_tree(src: Path, dst: Path) -> None:
    """Hard-link every file of ``src`` into ``dst`` (copy where links are impossible)."""

    def link(s: str, d: str) -> None:
        try:
            os.link(s, d)
        except OSError:
            shutil.copy2(s, d)

    shutil.copytree(src, dst, copy_function=link)


def merge_shards(
    out_dir: str | os.PathLike, shard_dirs: list[str | os.PathLike], *, link: bool = False, progress: bool = True
) -> Path:
    """Join shard folders into one dataset at ``out_dir``; returns its path.

    Sequence folders are moved (``link=True``: hard-linked, the shards stay intact). Every check
    runs before anything moves; the manifest is written last, atomically, so ``out_dir`` only
    reads as a dataset once it holds every sequence.
    """
    out = Path(out_dir)
    shards = [Path(d) for d in shard_dirs]
    refuse_overlap([out], {f"SHARD_DIR {i + 1}": d for i, d in enumerate(shards) if d.exists()}, "OUT")
    full, plan = _plan(out, shards)
    with lock(out, "OUT"):  # one merge into OUT at a time; it resumes in place, the manifest written last
        try:
            _move(out, plan, full, link, progress)
        except OSError as e:
            if not is_write_failure(e, out):
                raise
            raise write_failed(
                e, out, "OUT", "; what was moved is in OUT: run the same command again to go on"
            ) from None
    return out


def _move(out: Path, plan: dict[str, Path | None], full: dict[str, Any], link: bool, progress: bool) -> None:
    """`merge_shards`'s moves into ``out``, its manifest last."""
    out.mkdir(parents=True, exist_ok=True)
    for stale in out.glob(".*.tmp"):
        shutil.rmtree(stale) if stale.is_dir() else stale.unlink()
    for name, src in tqdm(sorted(plan.items()), desc="merge", unit="seq", disable=not progress):
        if src is None:
            continue
        dst = out / name
        if dst.exists():
            shutil.rmtree(dst)  # a partial leftover without meta.json
        if link:
            tmp = out / f".{name}.tmp"
            _link_tree(src / name, tmp)
            os.replace(tmp, dst)
        else:
            try:
                os.rename(src / name, dst)
            except OSError:  # another filesystem: copy under a temporary name, then drop the source
                tmp = out / f".{name}.tmp"
                shutil.copytree(src / name, tmp)
                os.replace(tmp, dst)
                shutil.rmtree(src / name)
    atomic_write_json(out / MANIFEST, full, fsync=True)
