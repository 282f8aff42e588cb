"""Reader of a dataset in the RackLay / MVRackLay authors' published layout, for training and evaluation.

The layout their loaders read (``racklay/dataloader.py``)::

    ROOT/img/<name>.png                    RGB (e.g. 9_000000.png)
    ROOT/topLayouts/top<name>.npy          (S, D, D) codes 0 / 115 / 255, S = 4 and D = 512 in their data
    ROOT/topLayouts/front<name>.npy        (or ROOT/frontLayouts/front<name>.npy)
    ROOT/splits/warehouse/<split>_temporal_files.txt   MVRackLay: image paths, each sequence closed by ","
    ROOT/splits/warehouse/<split>_files.txt            RackLay: image paths, one a line

The lists may also lie in ``ROOT/splits/`` or ``ROOT`` itself. Their paths are the authors' (absolute, from
another machine): a listed path is read as ``ROOT/img/`` + the part after its last ``img/``. A RackLay
list makes every listed frame a sequence of its own; a temporal list's chunks are the sequences.

What the layout lacks and this toolkit's network reads (the camera): the intrinsics, the camera-to-rack
distance, the camera's motion and the board heights. The reader uses a `DEFAULT_HFOV_DEG` camera at
`DEFAULT_DISTANCE_M` at rest, with no board heights (slot anchors unknown), and says so in `note`.
The metric extents are `LayoutSpec`'s defaults.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from layouts.camera import Intrinsics
from layouts.codecs import FrameLayouts, from_racklay
from layouts.errors import InputError
from layouts.fileio import load_npy
from layouts.spec import LayoutSpec

#: horizontal field of view assumed for the images (the toolkit's default camera)
DEFAULT_HFOV_DEG = 60.0
#: camera-to-rack distance assumed for every frame (equals `network.preprocess.DEFAULT_DISTANCE`)
DEFAULT_DISTANCE_M = 2.6
LIST_FOLDERS = ("splits/warehouse", "splits", ".")
SPLITS = ("train", "val", "test")


def is_published_layout(root: Path) -> bool:
    """A folder in the authors' layout: ``img/`` and ``topLayouts/``, no manifest of ours."""
    return (root / "img").is_dir() and (root / "topLayouts").is_dir() and not (root / "manifest.json").exists()


def _read_list(path: Path) -> str:
    try:
        return path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as e:
        raise InputError(f"{path}: cannot read ({e})") from None


def _local_name(line: str, source: Path) -> str:
    """The image name (``9_000000``) of a listed path, wherever the authors' machine kept it."""
    name = line.strip().split("img/")[-1]
    if not name.endswith(".png") or "/" in name:
        raise InputError(f"{source}: expected a path ending in img/<name>.png, got {line!r}")
    return name[: -len(".png")]


class PublishedDataset:
    """The sequences of a folder in the authors' layout (see the module docstring)."""

    def __init__(self, root: Path) -> None:
        self.root = root
        self.lists: dict[str, list[list[str]]] = {}
        for split in SPLITS:
            found = self._find_list(split)
            if found is not None:
                self.lists[split] = found
        if not self.lists:
            raise InputError(
                f"{root}: no split lists (splits/warehouse/{{train,val}}_temporal_files.txt or _files.txt, as "
                "the RackLay / MVRackLay code reads them)"
            )
        first = next(n for seqs in self.lists.values() for s in seqs for n in s)
        probe = self._stack(first, "top")
        self.spec = LayoutSpec(num_slots=probe.shape[0], size=probe.shape[1])
        self.image_size = self._image_size(first)
        w, h = self.image_size
        self.intrinsics = Intrinsics.from_fov(w, h, DEFAULT_HFOV_DEG)
        #: the one line training and evaluation print: what is missing and what is used instead
        self.note = (
            f"{root}: the authors' RackLay layout has no camera records: using a {DEFAULT_HFOV_DEG:g} deg "
            f"horizontal field of view, a camera-to-rack distance of {DEFAULT_DISTANCE_M:g} m, a camera at rest "
            f"and no board heights (slot anchors unknown); metric extents {self.spec.x_extent:g} x "
            f"{self.spec.z_extent:g} x {self.spec.h_extent:g} m; {self.spec.num_slots} slots, {self.spec.size}x"
            f"{self.spec.size} layouts"
        )

    def _find_list(self, split: str) -> list[list[str]] | None:
        for folder in LIST_FOLDERS:
            p = self.root / folder / f"{split}_temporal_files.txt"
            if p.is_file():
                chunks = _read_list(p).split(",")[:-1]  # as MVRackLay's temporal_readlines
                return [[_local_name(x, p) for x in c.split("\n")[:-1]] for c in chunks if c.strip()]
            p = self.root / folder / f"{split}_files.txt"
            if p.is_file():
                return [[_local_name(x, p)] for x in _read_list(p).splitlines() if x.strip()]
        return None

    def _image_size(self, name: str) -> tuple[int, int]:
        from PIL import Image, UnidentifiedImageError

        p = self.image_path(name)
        try:
            with Image.open(p) as im:
                return im.size
        except FileNotFoundError:
            raise InputError(f"{p}: file not found") from None
        except (UnidentifiedImageError, OSError) as e:
            raise InputError(f"{p}: not a readable image ({e})") from None

    def image_path(self, name: str) -> Path:
        return self.root / "img" / f"{name}.png"

    def layout_path(self, name: str, view: str) -> Path:
        p = self.root / "topLayouts" / f"{view}{name}.npy"
        alt = self.root / "frontLayouts" / f"front{name}.npy"
        return alt if view == "front" and not p.exists() and alt.exists() else p

    def _stack(self, name: str, view: str) -> np.ndarray:
        p = self.layout_path(name, view)
        arr = from_racklay(load_npy(p), str(p))
        if arr.ndim != 3 or arr.shape[1] != arr.shape[2]:
            raise InputError(f"{p}: expected an (S, D, D) layout stack, got shape {arr.shape}")
        if hasattr(self, "spec") and arr.shape != self.spec.shape:
            raise InputError(f"{p}: shape {arr.shape} differs from the first layout's {self.spec.shape}")
        return arr

    def sequences(self, split: str | None = None) -> list[PublishedSequence]:
        """The sequences of one split's list (train, val, test), or of all of them."""
        if split is not None and split not in SPLITS:
            raise InputError(f"split must be one of {SPLITS} or None, got {split!r}")
        out = []
        for s in SPLITS if split is None else (split,):
            out += [PublishedSequence(self, f"{s}_{k:04d}", s, names) for k, names in enumerate(self.lists.get(s, []))]
        return out


class PublishedSequence:
    """One sequence of a `PublishedDataset`, read like `waresynth.dataset.Sequence` (default camera)."""

    def __init__(self, data: PublishedDataset, name: str, split: str, names: list[str]) -> None:
        self.data = data
        self.root = data.root
        self.name = name
        self.split = split
        self.spec = data.spec
        self.names = names
        self.num_frames = len(names)
        self.intrinsics = data.intrinsics
        self.camera_angles = (0.0, 0.0, 0.0)

    def __repr__(self) -> str:
        return f"PublishedSequence({self.name!r}, split={self.split!r}, frames={self.num_frames})"

    def __len__(self) -> int:
        return self.num_frames

    def _name(self, i: int) -> str:
        if isinstance(i, bool) or not isinstance(i, (int, np.integer)) or not 0 <= i < self.num_frames:
            raise InputError(f"{self.name}: frame index {i!r} out of range 0..{self.num_frames - 1}")
        return self.names[int(i)]

    def rgb(self, i: int) -> np.ndarray:
        from waresynth.imageio import read_rgb

        return read_rgb(self.data.image_path(self._name(i)))

    def layouts(self, i: int) -> FrameLayouts:
        n = self._name(i)
        return FrameLayouts(self.data._stack(n, "top"), self.data._stack(n, "front"), None)

    def frame(self, i: int) -> dict[str, Any]:
        self._name(i)
        return {"camera_position": [0.0, 0.0, 0.0], "distance": DEFAULT_DISTANCE_M, "slots": []}

    def camera_positions(self) -> np.ndarray:
        return np.zeros((self.num_frames, 3))

    def visible_board_ys(self) -> list[float]:
        return []


def open_published(root: str | os.PathLike) -> PublishedDataset:
    """Open a folder in the authors' RackLay / MVRackLay layout (one-line errors on bad input)."""
    root = Path(root)
    if not is_published_layout(root):
        raise InputError(f"{root}: not a RackLay / MVRackLay folder (needs img/ and topLayouts/)")
    return PublishedDataset(root)
