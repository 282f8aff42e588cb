"""What every exporter shares: the checked dataset, a staging folder that replaces the output folder only
once complete, split names, file copies and the record of the source dataset."""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from tqdm import tqdm

from layouts.errors import InputError
from layouts.fileio import atomic_write_bytes
from layouts.publish import (
    check_writable,
    discard,
    is_stage_name,
    is_write_failure,
    lock,
    publish,
    stage,
    write_failed,
)

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


@dataclass
class Staging:
    """A staging folder on ``out``'s filesystem that replaces ``out``'s content only once complete
    (`layouts.publish`: a failed or interrupted export leaves ``out`` as it was)."""

    out: Path
    overwrite: bool
    tmp: Path = field(init=False)

    def __post_init__(self) -> None:
        if self.out.exists():
            if not self.out.is_dir():
                raise InputError(f"{self.out}: exists and is not a folder")
            if any(not is_stage_name(p.name) for p in self.out.iterdir()) and not self.overwrite:
                raise InputError(f"{self.out}: output folder exists and is not empty (pass --overwrite to replace it)")
        check_writable(self.out, "output folder")
        self.tmp = stage(self.out, "output folder")

    def commit(self) -> Path:
        publish(self.tmp, self.out, managed=None, what="output folder")
        return self.out

    def abort(self) -> None:
        discard(self.tmp)


def run_staged(
    build: Callable[[Any, Path, bool], dict],
    dataset_dir: str | os.PathLike,
    out_dir: str | os.PathLike,
    overwrite: bool,
    progress: bool,
) -> Path:
    """Open and check the dataset, let ``build`` fill a staging folder, then move it to ``out_dir``."""
    dataset = open_checked(dataset_dir)
    out = Path(out_dir)
    src, dst = Path(dataset.root).resolve(), out.resolve()
    if dst == src or src in dst.parents or dst in src.parents:
        raise InputError(f"{out}: output folder must lie outside the dataset folder {dataset.root}")
    if not dataset.sequences():
        raise InputError(f"{dataset.root}: dataset has no sequences")
    with lock(out, "output folder"):  # one export into OUT at a time
        stage = Staging(out, overwrite)
        try:
            build(dataset, stage.tmp, progress)
        except BaseException as e:
            stage.abort()
            if is_write_failure(e, stage.tmp):  # a full disk while staging: one line, the earlier export whole
                raise write_failed(e, out, "output folder") from None
            raise
        return stage.commit()


def source_record(dataset: Any) -> dict[str, Any]:
    w, h = dataset.image_size
    return {
        "dataset": Path(dataset.root).name,
        "seed": int(dataset.seed),
        "image_size": [int(w), int(h)],
        "spec": dataset.spec.to_dict(),
    }
