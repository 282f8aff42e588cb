"""What every exporter shares: the checked dataset, its output folder written whole (`run_staged`), split names,
file copies and the record of the source dataset."""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

from tqdm import tqdm

from layouts.errors import InputError
from layouts.fileio import atomic_write_bytes
from layouts.publish import output_folder
from waresynth.exporters.objects import FrameObject, InstanceInfo, frame_objects, instance_table

#: version of the COCO and YOLO exports (`export.json`)
EXPORT_VERSION = 1

#: the dataset splits in the order exports list them (others follow, sorted)
SPLIT_ORDER = ("train", "val", "test")


def progress_bar(it: Any, total: int, desc: str, progress: bool) -> Iterator:
    """``it`` wrapped in a frame progress bar (silent unless ``progress``)."""
    return iter(tqdm(it, total=total, desc=desc, unit="frame", disable=not progress, leave=False))


def split_names(dataset: Any) -> list[str]:
    """Splits present in the dataset: train, val, test first, then any other, sorted."""
    present = {s.split for s in dataset.sequences()}
    return [s for s in SPLIT_ORDER if s in present] + sorted(present - set(SPLIT_ORDER))


def check_split_name(split: str, root: Path) -> str:
    """``split``, refused unless it is usable in file names (letters, digits, ``_`` and ``-``)."""
    if not split or not all(c.isalnum() or c in "_-" for c in split):
        raise InputError(f"{root}: split name {split!r} is not usable in file names")
    return split


def split_frames(
    dataset: Any, split: str, fmt: str, tmp: Path, progress: bool
) -> Iterator[tuple[Any, int, str, list[FrameObject]]]:
    """Every frame of ``split`` (its name checked, `check_split_name`) in order, behind the progress bar
    ``export FMT SPLIT``: its image copied to ``tmp/images/SPLIT/STEM.png``, then ``(seq, index, STEM, its
    annotated objects)`` (`frame_stem`, `waresynth.exporters.objects.frame_objects`)."""
    check_split_name(split, dataset.root)
    seqs = dataset.sequences(split)
    total = sum(s.num_frames for s in seqs)
    frames = ((seq, i) for seq in seqs for i in range(seq.num_frames))
    tables: dict[str, dict[int, InstanceInfo]] = {}
    for seq, i in progress_bar(frames, total, f"export {fmt} {split}", progress):
        if seq.name not in tables:
            tables[seq.name] = instance_table(seq)
        stem = frame_stem(seq.name, i)
        copy_file(seq.rgb_path(i), tmp / "images" / split / f"{stem}.png")
        yield seq, i, stem, frame_objects(seq, i, tables[seq.name])


def frame_stem(seq_name: str, index: int) -> str:
    """File stem of one frame in the COCO and YOLO exports: ``<seq>_<frame:06d>``."""
    return f"{seq_name}_{index:06d}"


def copy_file(src: Path, dst: Path) -> None:
    """Copy ``src`` to ``dst`` atomically (one-line error when ``src`` cannot be read)."""
    try:
        data = Path(src).read_bytes()
    except FileNotFoundError:
        raise InputError(f"{src}: file not found") from None
    except OSError as e:
        raise InputError(f"{src}: cannot read ({e.strerror})") from None
    atomic_write_bytes(dst, data)


def open_checked(dataset_dir: str | os.PathLike) -> Any:
    """Open the WareSynth dataset at ``dataset_dir``, refusing a missing folder or one without a manifest."""
    from waresynth.dataset import open_dataset

    root = Path(dataset_dir)
    if not root.exists():
        raise InputError(f"{root}: dataset folder not found")
    if not root.is_dir():
        raise InputError(f"{root}: not a folder (expected a WareSynth dataset folder)")
    if not (root / "manifest.json").is_file():
        raise InputError(f"{root}: not a WareSynth dataset (no manifest.json)")
    return open_dataset(root)


def is_export(folder: Path) -> bool:
    """Whether ``folder`` is an earlier export (its record `export.json` or ``racklay_export.json`` there)."""
    return any((folder / n).is_file() for n in ("export.json", "racklay_export.json"))


def run_staged(
    build: Callable[[Any, Path, bool], dict],
    dataset_dir: str | os.PathLike,
    out_dir: str | os.PathLike,
    overwrite: bool,
    progress: bool,
) -> Path:
    """Open and check the dataset, let ``build`` fill a stage that replaces ``out_dir`` whole when complete
    (`layouts.publish.output_folder`: an export owns all of its folder)."""
    dataset = open_checked(dataset_dir)
    if not dataset.sequences():
        raise InputError(f"{dataset.root}: dataset has no sequences")
    with output_folder(out_dir, None, command="export", earlier=is_export, inputs={"DIR": dataset.root},
                       overwrite=overwrite) as st:  # fmt: skip
        build(dataset, st, progress)
    return Path(out_dir)


def source_record(dataset: Any) -> dict[str, Any]:
    w, h = dataset.image_size
    return {
        "dataset": Path(dataset.root).name,
        "seed": int(dataset.seed),
        "image_size": [int(w), int(h)],
        "spec": dataset.spec.to_dict(),
    }
