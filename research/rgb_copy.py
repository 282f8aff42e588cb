"""One way to write a copy of a generated dataset whose RGB frames were changed, the rest hard-linked.

Used by ``turn_dataset.py`` (a turned camera), ``compress_dataset.py`` (a compressing camera) and
``distort_dataset.py`` (a lens).
"""

from __future__ import annotations

import json
import os
import shutil
from collections.abc import Callable
from pathlib import Path

import numpy as np
from PIL import Image
from tqdm import tqdm


def _link_or_copy(src: str, dst: str) -> None:
    try:
        os.link(src, dst)
    except OSError:
        shutil.copy2(src, dst)


def write_rgb_copy(
    src: Path,
    dst: Path,
    seqs: list,
    change: Callable[[np.ndarray, object], np.ndarray],
    desc: str,
    record: tuple[str, dict],
    finish: Callable[[Path], None] | None = None,
) -> int:
    """Copy dataset ``src`` (whose opened ``seqs`` are given) to ``dst`` with each ``SEQ/rgb/*.png`` replaced
    by ``change(rgb, seq)``; everything else hard-linked (copied where links fail). The copy is written
    under ``DST.partial`` and renamed when whole; ``record`` = (file name, what was done) is written at its
    root; ``finish(copy_root)``, when given, runs last, before the rename (it must unlink a file
    before writing it: every file but the frames is a hard link into ``src``). Returns the number of
    frames changed. ``dst`` must not exist (the caller says so to its user)."""
    tmp = dst.with_name(dst.name + ".partial")
    shutil.rmtree(tmp, ignore_errors=True)
    shutil.copytree(src, tmp, copy_function=_link_or_copy)
    frames = 0
    with tqdm(total=sum(s.num_frames for s in seqs), desc=desc, unit="frame") as bar:
        for seq in seqs:
            for path in sorted((tmp / seq.root.relative_to(src) / "rgb").glob("*.png")):
                with Image.open(path) as im:
                    rgb = np.asarray(im.convert("RGB"))
                path.unlink()  # a hard link: never write through it into the source
                Image.fromarray(change(rgb, seq)).save(path)
                frames += 1
                bar.update(1)
    if finish is not None:
        finish(tmp)
    name, said = record
    (tmp / name).write_text(json.dumps(said, indent=2) + "\n")
    tmp.rename(dst)
    return frames
