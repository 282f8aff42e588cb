"""Layout file formats: native stacks, per-frame files, layout folders, RackLay's 0/115/255.

Native
    A view's layout is a ``uint8`` array ``(R, D, D)`` with class ids 0/1/2 (``.npy``).
Per-frame file
    ``NNNNNN.npz`` with ``top`` and ``front`` ``(R, D, D)`` uint8 and optionally ``visible``
    ``(D,)`` bool: the layout columns in view in that frame.
Layout folder
    ``spec.json`` (a `LayoutSpec`) plus one per-frame file per frame, named by frame index.
    This is what ``mvracklay predict`` writes and ``mvracklay reconstruct`` reads.
RackLay / MVRackLay
    the same classes stored as 0 / 115 / 255 in ``.npy`` stacks.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from layouts.classes import BACKGROUND, BOX, NUM_CLASSES, SHELF
from layouts.errors import LayoutError
from layouts.fileio import atomic_save_npy, atomic_save_npz, atomic_write_text, load_json, load_npy, load_npz
from layouts.spec import LayoutSpec

RACKLAY_CODES: dict[int, int] = {BACKGROUND: 0, SHELF: 115, BOX: 255}
_FRAME_RE = re.compile(r"^(\d{6})\.npz$")


def validate_stack(arr: np.ndarray, spec: LayoutSpec | None, name: str = "layout") -> np.ndarray:
    """Check a native ``(R, D, D)`` uint8 stack of class ids; return it, else one-line error."""
    if not isinstance(arr, np.ndarray):
        raise LayoutError(f"{name}: expected a numpy array, got {type(arr).__name__}")
    if arr.dtype != np.uint8:
        raise LayoutError(f"{name}: dtype must be uint8, got {arr.dtype}")
    if arr.ndim != 3 or arr.shape[1] != arr.shape[2]:
        raise LayoutError(f"{name}: shape must be (R, D, D), got {arr.shape}")
    if spec is not None and arr.shape != spec.shape:
        raise LayoutError(f"{name}: shape {arr.shape} does not match the layout spec {spec.shape}")
    if arr.size and int(arr.max()) >= NUM_CLASSES:
        raise LayoutError(f"{name}: class ids must be 0, 1 or 2, found {int(arr.max())}")
    return arr


def empty_stack(spec: LayoutSpec) -> np.ndarray:
    return np.zeros(spec.shape, np.uint8)


# ---------------------------------------------------------------- native single stacks
def save_native(path: str | os.PathLike, arr: np.ndarray) -> None:
    atomic_save_npy(path, validate_stack(arr, None, str(path)))


def load_native(path: str | os.PathLike, spec: LayoutSpec | None = None) -> np.ndarray:
    return validate_stack(load_npy(path), spec, str(path))


# ---------------------------------------------------------------- RackLay 0/115/255
def to_racklay(arr: np.ndarray) -> np.ndarray:
    """Class ids -> RackLay codes (0 / 115 / 255)."""
    validate_stack(arr, None)
    lut = np.zeros(256, np.uint8)
    for cid, code in RACKLAY_CODES.items():
        lut[cid] = code
    return lut[arr]


def from_racklay(arr: np.ndarray, name: str = "racklay layout") -> np.ndarray:
    """RackLay codes -> class ids. Any other value is refused (no silent rounding)."""
    a = np.asarray(arr)
    if a.dtype.kind not in "ui" and a.dtype.kind != "f":
        raise LayoutError(f"{name}: numeric array expected, got dtype {a.dtype}")
    if a.dtype.kind == "f" and not np.isfinite(a).all():
        raise LayoutError(f"{name}: contains NaN or infinity")
    if a.ndim == 2:
        a = a[None]
    if a.ndim != 3:
        raise LayoutError(f"{name}: shape must be (R, D, D) or (D, D), got {np.shape(arr)}")
    out = np.zeros(a.shape, np.uint8)
    known = np.zeros(a.shape, bool)
    for cid, code in RACKLAY_CODES.items():
        m = a == code
        out[m] = cid
        known |= m
    if not known.all():
        bad = np.unique(a[~known])[:5]
        raise LayoutError(f"{name}: values must be 0, 115 or 255, found {bad.tolist()}")
    return out


def save_racklay(path: str | os.PathLike, arr: np.ndarray) -> None:
    atomic_save_npy(path, to_racklay(arr))


def load_racklay(path: str | os.PathLike, spec: LayoutSpec | None = None) -> np.ndarray:
    arr = from_racklay(load_npy(path), str(path))
    return validate_stack(arr, spec, str(path))


# ---------------------------------------------------------------- per-frame files
@dataclass
class FrameLayouts:
    """Top and front stacks of one frame, plus the columns in view when known."""

    top: np.ndarray
    front: np.ndarray
    visible: np.ndarray | None = None

    def validate(self, spec: LayoutSpec | None, name: str = "frame layouts") -> FrameLayouts:
        validate_stack(self.top, spec, f"{name} (top)")
        validate_stack(self.front, spec, f"{name} (front)")
        if self.top.shape != self.front.shape:
            raise LayoutError(f"{name}: top {self.top.shape} and front {self.front.shape} shapes differ")
        if self.visible is not None:
            v = self.visible
            if not isinstance(v, np.ndarray):
                raise LayoutError(f"{name}: visible must be a numpy bool array, got {type(v).__name__}")
            if v.dtype != bool or v.shape != (self.top.shape[2],):
                raise LayoutError(
                    f"{name}: visible must be bool of shape ({self.top.shape[2]},), got {v.dtype} {v.shape}"
                )
        return self


def save_frame(path: str | os.PathLike, layouts: FrameLayouts) -> None:
    layouts.validate(None, str(path))
    arrays = {"top": layouts.top, "front": layouts.front}
    if layouts.visible is not None:
        arrays["visible"] = layouts.visible
    atomic_save_npz(path, **arrays)


def load_frame(path: str | os.PathLike, spec: LayoutSpec | None = None) -> FrameLayouts:
    d = load_npz(path, keys=("top", "front"))
    vis = d.get("visible")
    return FrameLayouts(d["top"], d["front"], vis).validate(spec, str(path))


# ---------------------------------------------------------------- layout folders
def frame_filename(index: int) -> str:
    return f"{index:06d}.npz"


def write_layout_spec(folder: str | os.PathLike, spec: LayoutSpec) -> None:
    atomic_write_text(Path(folder) / "spec.json", spec.to_json() + "\n")


def read_layout_spec(folder: str | os.PathLike) -> LayoutSpec:
    p = Path(folder) / "spec.json"
    return LayoutSpec.from_dict(load_json(p), str(p))


class LayoutFolder:
    """A folder of per-frame layout files with its ``spec.json``.

    >>> folder = LayoutFolder.create("out/layouts", spec)   # doctest: +SKIP
    >>> folder.write(0, FrameLayouts(top, front))           # doctest: +SKIP
    """

    def __init__(self, root: str | os.PathLike):
        self.root = Path(root)
        if not self.root.is_dir():
            raise LayoutError(f"{self.root}: layout folder not found")
        self.spec = read_layout_spec(self.root)

    @classmethod
    def create(cls, root: str | os.PathLike, spec: LayoutSpec) -> LayoutFolder:
        root = Path(root)
        root.mkdir(parents=True, exist_ok=True)
        spec_path = root / "spec.json"
        if spec_path.exists():
            old = read_layout_spec(root)
            if old != spec:
                raise LayoutError(f"{spec_path}: holds a different layout spec; use another folder")
        else:
            write_layout_spec(root, spec)
        return cls(root)

    def indices(self) -> list[int]:
        """Frame indices present, ascending."""
        out = []
        for name in os.listdir(self.root):
            m = _FRAME_RE.match(name)
            if m:
                out.append(int(m.group(1)))
        return sorted(out)

    def path(self, index: int) -> Path:
        return self.root / frame_filename(index)

    def write(self, index: int, layouts: FrameLayouts) -> None:
        layouts.validate(self.spec, str(self.path(index)))
        save_frame(self.path(index), layouts)

    def read(self, index: int) -> FrameLayouts:
        return load_frame(self.path(index), self.spec)

    def __len__(self) -> int:
        return len(self.indices())
