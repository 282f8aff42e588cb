"""Torch-free reader for WareSynth datasets (format in docs/conventions.md and docs/waresynth.md).

>>> ds = open_dataset("data/waresynth")                 # doctest: +SKIP
>>> seq = ds.sequences("train")[0]                      # doctest: +SKIP
>>> rgb, lay = seq.rgb(0), seq.layouts(0)               # doctest: +SKIP
"""

from __future__ import annotations

import os
import re
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np

from layouts.camera import Intrinsics
from layouts.camera_record import camera_angles
from layouts.canonical import camera_rotation
from layouts.codecs import FrameLayouts, LayoutFolder
from layouts.errors import InputError
from layouts.fileio import load_json
from layouts.spec import LayoutSpec
from waresynth.imageio import read_png

SPLITS = ("train", "val", "test")
DATASET_FORMAT = "waresynth"  #: manifest.json "format"
DATASET_VERSION = 1  #: manifest.json "version"; bump when the on-disk meaning changes


_NAME_RE = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.-]{0,127}")


def check_sequence_name(name: Any, source: str | os.PathLike) -> str:
    """A manifest's sequence name must be a plain folder name inside the dataset: no path
    separators, no ``..``, not absolute (a manifest must not point outside its dataset)."""
    if not isinstance(name, str) or not _NAME_RE.fullmatch(name):
        raise InputError(f"{source}: sequence name {name!r} is not a plain folder name inside the dataset, refused")
    return name


def require_level_camera(seq: Any, what: str) -> None:
    """A one-line refusal when ``what`` (something that reads a generated frame's depth or semantic images
    as a level camera's) is asked of a sequence whose camera was turned."""
    angles = tuple(getattr(seq, "camera_angles", None) or (0.0, 0.0, 0.0))
    if any(angles):
        name = getattr(seq, "root", getattr(seq, "name", "sequence"))
        raise InputError(
            f"{name}: {what} needs a level camera's images, but this camera is turned (roll / pitch / yaw "
            f"{angles[0]:g} / {angles[1]:g} / {angles[2]:g} deg); use data generated with camera.roll_deg, "
            "pitch_deg and yaw_deg at [0, 0]"
        )


class Sequence:
    """One camera sequence: images, ground-truth layouts, per-frame records and the scene."""

    def __init__(self, root: Path, name: str, split: str, spec: LayoutSpec):
        self.root = Path(root)
        self.name = name
        self.split = split
        self.spec = spec
        if not self.root.is_dir():
            raise InputError(f"{self.root}: sequence folder not found (incomplete dataset? re-run generate to resume)")

    def __repr__(self) -> str:
        return f"Sequence({self.name!r}, split={self.split!r}, frames={self.num_frames})"

    @cached_property
    def meta(self) -> dict[str, Any]:
        path = self.root / "meta.json"
        meta = load_json(path)
        from waresynth.meta_schema import check_meta

        check_meta(meta, str(path))  # the declared schema (`waresynth.meta_schema`)
        if not isinstance(meta.get("frames"), list):
            raise InputError(f"{path}: not a WareSynth sequence meta.json (no frames list)")
        return meta

    @cached_property
    def intrinsics(self) -> Intrinsics:
        return Intrinsics.from_dict(self.meta.get("intrinsics"), str(self.root / "meta.json"))

    @property
    def num_frames(self) -> int:
        return len(self.meta["frames"])

    @cached_property
    def camera_angles(self) -> tuple[float, float, float]:
        """The camera's (roll, pitch, yaw) in degrees, as generated; (0, 0, 0) for a level camera."""
        return camera_angles(self.meta.get("camera"), str(self.root / "meta.json"))

    def __len__(self) -> int:
        return self.num_frames

    def _index(self, i: int) -> int:
        return check_frame_index(i, self.num_frames, self.name)

    def frame(self, i: int) -> dict[str, Any]:
        """Per-frame record: index, camera_position, distance, rack_mid_z, slots, visible_fraction."""
        return self.meta["frames"][self._index(i)]

    def rgb_path(self, i: int) -> Path:
        return self.root / "rgb" / f"{self._index(i):06d}.png"

    def depth_path(self, i: int) -> Path:
        return self.root / "depth" / f"{self._index(i):06d}.png"

    def semantic_path(self, i: int) -> Path:
        return self.root / "semantic" / f"{self._index(i):06d}.png"

    def instance_path(self, i: int) -> Path:
        return self.root / "instance" / f"{self._index(i):06d}.png"

    def rgb(self, i: int) -> np.ndarray:
        """uint8 (H, W, 3)."""
        return read_png(self.rgb_path(i), np.uint8, channels=3)

    def depth(self, i: int) -> np.ndarray:
        """float32 (H, W) Z depth in metres; 0 where no surface was hit."""
        return read_png(self.depth_path(i), np.uint16).astype(np.float32) / np.float32(1000.0)

    def level_depth(self, i: int) -> np.ndarray:
        """float32 (H, W): each pixel's surface as far ahead as a level camera measures it (world Z from
        the camera, metres; 0 where nothing was hit). `depth` itself for a level camera."""
        depth = self.depth(i)
        if not any(self.camera_angles):
            return depth
        return self.intrinsics.level_depth(depth, camera_rotation(*self.camera_angles))

    def semantic(self, i: int) -> np.ndarray:
        """uint8 (H, W) ids of `waresynth.semantics`."""
        return read_png(self.semantic_path(i), np.uint8)

    def instance(self, i: int) -> np.ndarray:
        """int32 (H, W) instance ids (scene.json "instances"; 0 = none)."""
        return read_png(self.instance_path(i), np.uint16).astype(np.int32)

    @cached_property
    def layout_folder(self) -> LayoutFolder:
        return LayoutFolder(self.root / "layouts")

    def layouts(self, i: int) -> FrameLayouts:
        """Ground-truth top/front layouts (R, D, D) and visible columns of frame ``i``."""
        return self.layout_folder.read(self._index(i))

    def scene(self) -> dict[str, Any]:
        """The world-frame scene (racks -> shelves -> boxes, clutter, walls, instances)."""
        path = self.root / "scene.json"
        d = load_json(path)
        if not isinstance(d, dict) or "racks" not in d:
            raise InputError(f"{path}: not a WareSynth scene.json (no racks)")
        return d

    def camera_positions(self) -> np.ndarray:
        """(N, 3) float64 world camera positions, one per frame."""
        return np.array([f["camera_position"] for f in self.meta["frames"]], np.float64).reshape(-1, 3)

    @cached_property
    def _board_ys(self) -> list[float]:
        try:
            shelves = self.scene()["racks"][0]["shelves"]
            return [float(shelves[k]["board_top_y"]) for k in self.meta["visible_levels"]]
        except (KeyError, IndexError, TypeError, ValueError):
            return []

    def visible_board_ys(self) -> list[float]:
        """World Y of the board top of every shelf level the camera path sees (all frames share them; [] if unknown)."""
        return list(self._board_ys)


def check_frame_index(i: Any, num_frames: int, owner: str | os.PathLike) -> int:
    """``i`` as an int if it indexes one of ``num_frames`` frames, else one line naming ``owner``."""
    if isinstance(i, bool) or not isinstance(i, (int, np.integer)) or not 0 <= i < num_frames:
        raise InputError(f"{owner}: frame index must be an integer in [0, {num_frames}), got {i!r}")
    return int(i)


def read_manifest(folder: Path, kind: str = "dataset") -> tuple[Path, dict[str, Any]]:
    """``(path, manifest)`` of a dataset (or shard) folder, checking its format and version."""
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError(f"{folder}: {kind} folder not found")
    mpath = folder / "manifest.json"
    if not mpath.is_file():
        raise InputError(f"{folder}: not a WareSynth {kind} (no manifest.json)")
    m = load_json(mpath)
    if not isinstance(m, dict) or m.get("format") != DATASET_FORMAT:
        raise InputError(f"{mpath}: not a WareSynth manifest (format is not {DATASET_FORMAT!r})")
    if m.get("version") != DATASET_VERSION:
        raise InputError(f"{mpath}: dataset version {m.get('version')!r} is not supported (want {DATASET_VERSION})")
    return mpath, m


class Dataset:
    """A WareSynth dataset folder: the manifest plus its sequences."""

    def __init__(self, root: str | os.PathLike):
        self.root = Path(root)
        mpath, m = read_manifest(self.root)
        for key in ("seed", "config", "spec", "image_size", "sequences"):
            if key not in m:
                raise InputError(f"{mpath}: manifest lacks {key!r}")
        self.manifest: dict[str, Any] = m
        self.spec = LayoutSpec.from_dict(m["spec"], str(mpath))
        self.config: dict[str, Any] = m["config"]
        try:
            w, h = m["image_size"]
            self.image_size: tuple[int, int] = (int(w), int(h))
            self.seed = int(m["seed"])
        except (TypeError, ValueError):
            raise InputError(f"{mpath}: image_size must be [width, height] and seed an integer") from None
        seqs = m["sequences"]
        if not isinstance(seqs, list):
            raise InputError(f"{mpath}: 'sequences' must be a list")
        self._entries: dict[str, dict[str, Any]] = {}
        for e in seqs:
            if not isinstance(e, dict):
                raise InputError(f"{mpath}: sequence entries must be objects, got {type(e).__name__}")
            name = check_sequence_name(e.get("name"), mpath)
            if e.get("split") not in SPLITS:
                raise InputError(f"{mpath}: sequence {name} has split {e.get('split')!r}, not one of {SPLITS}")
            if name in self._entries:
                raise InputError(f"{mpath}: sequence {name} listed twice")
            self._entries[name] = e

    def __repr__(self) -> str:
        return f"Dataset({str(self.root)!r}, sequences={len(self._entries)})"

    def sequences(self, split: str | None = None) -> list[Sequence]:
        """Sequences in manifest order, optionally of one split ('train', 'val', 'test')."""
        if split is not None and split not in SPLITS:
            raise InputError(f"split must be one of {SPLITS} or None, got {split!r}")
        return [self.sequence(n) for n, e in self._entries.items() if split is None or e["split"] == split]

    def sequence(self, name: str) -> Sequence:
        if name not in self._entries:
            raise InputError(f"{self.root}: no sequence named {name!r}")
        return Sequence(self.root / name, name, self._entries[name]["split"], self.spec)

    def complete(self) -> bool:
        """True when every sequence of the manifest is on disk."""
        return all((self.root / n / "meta.json").is_file() for n in self._entries)


def open_dataset(root: str | os.PathLike) -> Dataset:
    """Open a WareSynth dataset folder (one-line `InputError` if it is not one)."""
    return Dataset(root)
