"""RackLay / MVRackLay export and its reader.

A drop-in for the authors' code (see `waresynth.exporters.racklay_lists` for the rules it follows):
``img/NNNNNN.png``, ``topLayouts/topNNNNNN.npy`` and ``topLayouts/frontNNNNNN.npy`` (``(S, D, D)`` uint8
with RackLay's codes 0 / 115 / 255, S = ``slots`` >= R, slots past the dataset's R all 0), numbered by one
running index over all sequences; ``splits/warehouse/{train,val[,test]}_files.txt`` (RackLay: absolute image
paths) and ``..._temporal_files.txt`` (MVRackLay: the same in frame order, each sequence closed by ``,``);
``visible.npy`` ``(N, D)`` bool, the layout columns in view per frame; ``cameras.json``, what RackLay's
format lacks and training needs (intrinsics, board heights, per-frame camera records).
`load_racklay_export` reads it back (and the version 1 / 2 layout, ``images/`` and ``frontLayouts/``), as
frames or as sequences (`ExportSequence`, read like `waresynth.dataset.Sequence`).
"""

from __future__ import annotations

import functools
import os
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from layouts.camera import Intrinsics
from layouts.camera_record import CAMERA_ANGLE_KEYS, camera_angles
from layouts.codecs import RACKLAY_CODES, FrameLayouts, from_racklay, to_racklay, validate_stack
from layouts.errors import InputError
from layouts.fileio import atomic_save_npy, atomic_write_json, atomic_write_text, load_json, load_npy
from layouts.spec import LayoutSpec
from waresynth.dataset import check_frame_index
from waresynth.exporters.common import (
    SPLIT_ORDER,
    check_split_name,
    copy_file,
    progress_bar,
    run_staged,
    source_record,
    split_names,
)
from waresynth.exporters.racklay_lists import (
    DEFAULT_SLOTS,
    IMAGE_DIR,
    LAYOUT_DIR,
    LIST_DIR,
    check_out_path,
    list_frame,
    list_texts,
)

RACKLAY_MANIFEST = "racklay_export.json"
#: what RackLay's format lacks and training needs: per sequence its intrinsics, the board heights it
#: sees and every frame's camera record (position, distance to the rack, slot boards)
RACKLAY_CAMERAS = "cameras.json"
#: the RackLay export's own version: 2 added `RACKLAY_CAMERAS`; 3 is the reference code's layout (``img/``,
#: both views in ``topLayouts/``, absolute-path lists in ``splits/warehouse/``, ``slots`` per stack).
#: Versions 1 and 2 still read (1: layouts only)
RACKLAY_VERSION = 3


def _padded(stack: np.ndarray, slots: int) -> np.ndarray:
    """RackLay codes of a ``(R, D, D)`` class stack, zero slots appended up to ``slots``."""
    out = np.zeros((slots, *stack.shape[1:]), np.uint8)
    out[: stack.shape[0]] = to_racklay(stack)
    return out


def _export_racklay(dataset: Any, tmp: Path, progress: bool, root: str, slots: int) -> dict:
    """RackLay / MVRackLay folder: images, 0/115/255 layout stacks, the reference split lists."""
    spec: LayoutSpec = dataset.spec
    if slots < spec.num_slots:
        raise InputError(
            f"--slots {slots}: the dataset's layouts have {spec.num_slots} shelf slots, pass at least that"
        )
    seqs = dataset.sequences()
    total = sum(s.num_frames for s in seqs)
    splits = split_names(dataset)
    records: list[dict[str, Any]] = []
    visible = np.zeros((total, spec.size), bool)
    have_visible = True
    cameras: dict[str, Any] = {}
    index = 0

    def frames() -> Iterator[tuple[Any, int]]:
        for seq in seqs:
            for i in range(seq.num_frames):
                yield seq, i

    for seq, i in progress_bar(frames(), total, "export racklay", progress):
        if i == 0:
            check_split_name(seq.split, dataset.root)
            records.append({"name": seq.name, "split": seq.split, "first": index, "frames": seq.num_frames})
            cameras[seq.name] = {
                "intrinsics": seq.intrinsics.to_dict(),
                **dict(zip(CAMERA_ANGLE_KEYS, seq.camera_angles)),
                "board_ys": seq.visible_board_ys(),
                "frames": [seq.frame(k) for k in range(seq.num_frames)],
            }
        lay: FrameLayouts = seq.layouts(i)
        lay.validate(spec, str(seq.root / "layouts" / f"{i:06d}.npz"))
        copy_file(seq.rgb_path(i), tmp / IMAGE_DIR / f"{index:06d}.png")
        atomic_save_npy(tmp / LAYOUT_DIR / f"top{index:06d}.npy", _padded(lay.top, slots))
        atomic_save_npy(tmp / LAYOUT_DIR / f"front{index:06d}.npy", _padded(lay.front, slots))
        if lay.visible is None:
            have_visible = False
        else:
            visible[index] = lay.visible
        index += 1

    texts, plan = list_texts(records, root)
    for name, text in texts.items():
        atomic_write_text(tmp / LIST_DIR / name, text)
    if have_visible:
        atomic_save_npy(tmp / "visible.npy", visible)
    atomic_write_json(tmp / RACKLAY_CAMERAS, {"sequences": cameras})
    manifest = {
        "format": "racklay",
        "version": RACKLAY_VERSION,
        "cameras": RACKLAY_CAMERAS,
        "source": source_record(dataset),
        "spec": spec.to_dict(),
        "num_frames": total,
        "codes": {name: RACKLAY_CODES[cid] for cid, name in enumerate(("background", "shelf", "box"))},
        "splits": splits,
        "slots": slots,
        "lists": {"folder": LIST_DIR, "root": root, **plan},
        "visible": have_visible,
        "sequences": records,
    }
    atomic_write_json(tmp / RACKLAY_MANIFEST, manifest)
    return manifest


def export_racklay(
    dataset_dir: str | os.PathLike,
    out_dir: str | os.PathLike,
    *,
    overwrite: bool = False,
    progress: bool = True,
    slots: int = DEFAULT_SLOTS,
) -> Path:
    """Write the RackLay/MVRackLay layout of a dataset to ``out_dir``, ``slots`` shelf slots a stack (the
    reference code's ``--num_racks``); the split lists name ``out_dir``'s absolute path. Read it back with
    `load_racklay_export`."""
    if isinstance(slots, bool) or not isinstance(slots, int) or not 1 <= slots <= 16:
        raise InputError(f"--slots must be an integer from 1 to 16, got {slots!r}")
    root = check_out_path(Path(out_dir))
    build = functools.partial(_export_racklay, root=root, slots=slots)
    return run_staged(build, dataset_dir, out_dir, overwrite, progress)


@dataclass(frozen=True)
class RackLaySequence:
    """One sequence of a RackLay export: its frames are ``first .. first + frames - 1``."""

    name: str
    split: str
    first: int
    frames: int

    @property
    def indices(self) -> list[int]:
        return list(range(self.first, self.first + self.frames))


class RackLayExport:
    """Reader of a folder written by `export_racklay` (see `load_racklay_export`)."""

    def __init__(self, root: Path, manifest: dict[str, Any]):
        self.root = root
        self.manifest = manifest
        src = str(root / RACKLAY_MANIFEST)
        self.spec = LayoutSpec.from_dict(manifest.get("spec"), src)
        try:
            self.num_frames = int(manifest["num_frames"])
            self.splits: list[str] = [str(s) for s in manifest["splits"]]
            self.records = [
                RackLaySequence(str(r["name"]), str(r["split"]), int(r["first"]), int(r["frames"]))
                for r in manifest["sequences"]
            ]
        except (KeyError, TypeError, ValueError) as e:
            raise InputError(f"{src}: malformed RackLay export manifest ({e!r})") from None
        covered = sorted(k for s in self.records for k in s.indices)
        if covered != list(range(self.num_frames)):
            raise InputError(f"{src}: sequences do not cover frames 0..{self.num_frames - 1} exactly once")
        self.version = int(manifest.get("version", 1))
        lists = manifest.get("lists") if self.version >= 3 else None
        #: the reference lists' names (train, val and test when present), version 3
        self.lists: list[str] = [k for k in ("train", "val", "test") if isinstance(lists, dict) and k in lists]
        self.slots = int(manifest.get("slots", self.spec.num_slots))
        self._visible: np.ndarray | None = None
        self._cameras: dict[str, Any] | None = None
        src_size = manifest.get("source", {}).get("image_size") if isinstance(manifest.get("source"), dict) else None
        self.image_size: tuple[int, ...] = tuple(int(v) for v in src_size) if isinstance(src_size, list) else ()

    def __len__(self) -> int:
        return self.num_frames

    def sequences(self, split: str | None = None) -> list[ExportSequence]:
        """Readers of the export's sequences (of one split, or all), with the interface of
        `waresynth.dataset.Sequence` that training and evaluation read: images, layouts and the
        camera records of `RACKLAY_CAMERAS` (an export without them cannot train the network)."""
        if split is not None and split not in SPLIT_ORDER:
            raise InputError(f"split must be one of {SPLIT_ORDER} or None, got {split!r}")
        cams = self.camera_records()
        return [ExportSequence(self, r, cams.get(r.name)) for r in self.records if split is None or r.split == split]

    def camera_records(self) -> dict[str, Any]:
        """``{sequence name: {"intrinsics", "board_ys", "frames"}}`` from `RACKLAY_CAMERAS` (checked once)."""
        if self._cameras is None:
            p = self.root / RACKLAY_CAMERAS
            if not self.manifest.get("cameras"):
                raise InputError(
                    f"{self.root}: this RackLay export has no camera records ({RACKLAY_CAMERAS}; written from "
                    f"export version {RACKLAY_VERSION}): training needs the intrinsics, camera distance and board "
                    "heights, re-export the dataset with this version"
                )
            d = load_json(p)
            seqs = d.get("sequences") if isinstance(d, dict) else None
            if not isinstance(seqs, dict):
                raise InputError(f"{p}: expected an object with a 'sequences' object")
            for r in self.records:
                e = seqs.get(r.name)
                if not isinstance(e, dict) or not isinstance(e.get("frames"), list) or len(e["frames"]) != r.frames:
                    raise InputError(f"{p}: sequence {r.name} needs a record of each of its {r.frames} frames")
                for k, f in enumerate(e["frames"]):
                    pos = f.get("camera_position") if isinstance(f, dict) else None
                    if not (isinstance(pos, list) and len(pos) == 3 and all(isinstance(v, (int, float)) for v in pos)):
                        raise InputError(f"{p}: sequence {r.name} frame {k}: camera_position must be 3 numbers")
                if not isinstance(e.get("board_ys", []), list):
                    raise InputError(f"{p}: sequence {r.name}: board_ys must be a list of numbers")
            self._cameras = seqs
        return self._cameras

    def _check(self, index: int) -> int:
        return check_frame_index(index, self.num_frames, self.root)

    def image_path(self, index: int) -> Path:
        return self.root / (IMAGE_DIR if self.version >= 3 else "images") / f"{self._check(index):06d}.png"

    def rgb(self, index: int) -> np.ndarray:
        """uint8 ``(H, W, 3)`` image of frame ``index``."""
        from waresynth.imageio import read_rgb

        return read_rgb(self.image_path(index))

    def layouts(self, index: int) -> FrameLayouts:
        """Class-id layouts (0/1/2) of frame ``index``, with its visible columns when exported."""
        i = self._check(index)
        top = self._stack(self.root / LAYOUT_DIR / f"top{i:06d}.npy")
        front = self._stack(self.root / (LAYOUT_DIR if self.version >= 3 else "frontLayouts") / f"front{i:06d}.npy")
        vis = self.visible[i].copy() if self.visible is not None else None
        return FrameLayouts(top, front, vis)

    def _stack(self, path: Path) -> np.ndarray:
        """The ``(R, D, D)`` class stack of a file (the zero slots past R that version 3 appends dropped)."""
        arr = from_racklay(load_npy(path), str(path))
        if self.slots > self.spec.num_slots and arr.ndim == 3 and arr.shape[0] == self.slots:
            arr = arr[: self.spec.num_slots]
        return validate_stack(arr, self.spec, str(path))

    @property
    def visible(self) -> np.ndarray | None:
        """``(N, D)`` bool columns in view per frame, or None when the export has none."""
        if self._visible is None and self.manifest.get("visible"):
            p = self.root / "visible.npy"
            v = load_npy(p)
            if v.dtype != bool or v.shape != (self.num_frames, self.spec.size):
                raise InputError(f"{p}: expected bool ({self.num_frames}, {self.spec.size}), got {v.dtype} {v.shape}")
            self._visible = v
        return self._visible

    def _split_file(self, split: str, kind: str) -> Path:
        have = self.lists if self.version >= 3 else self.splits
        if split not in have:
            raise InputError(f"{self.root}: no split {split!r} (have {have})")
        folder = self.root / (LIST_DIR if self.version >= 3 else "splits")
        return folder / f"{split}_{kind}.txt"

    def _list_index(self, line: str, source: str) -> int:
        try:
            return self._check(list_frame(line, source))
        except InputError:
            raise InputError(f"{source}: not an image of this export: {line!r}") from None

    def split_indices(self, split: str) -> list[int]:
        """Frame indices of ``split`` from its RackLay list (``splits/warehouse/<split>_files.txt``;
        version 1 / 2: ``splits/<split>_files.txt``, one index a line)."""
        p = self._split_file(split, "files")
        return [self._list_index(line, f"{p}:{n}") for n, line in enumerate(_read_text(p).splitlines(), 1)]

    def temporal_sequences(self, split: str) -> list[list[int]]:
        """Ordered frame indices per sequence of ``split``, parsed like MVRackLay's
        ``temporal_readlines``: chunks separated by ``,``, one image path a line."""
        p = self._split_file(split, "temporal_files")
        chunks = _read_text(p).split(",")[:-1]
        out = []
        for chunk in chunks:
            out.append([self._list_index(line, str(p)) for line in chunk.split("\n")[:-1]])
        return out

    def windows(self, split: str, seq_len: int) -> list[list[int]]:
        """MVRackLay's training samples: for every frame, the ``seq_len`` frames ending at it, the
        sequence's first frame repeated in front where the history is short."""
        if isinstance(seq_len, bool) or not isinstance(seq_len, int) or seq_len < 1:
            raise InputError(f"seq_len must be a positive integer, got {seq_len!r}")
        out = []
        for frames in self.temporal_sequences(split):
            padded = [frames[0]] * seq_len + frames
            out += [padded[i - seq_len + 1 : i + 1] for i in range(seq_len, len(padded))]
        return out


class ExportSequence:
    """One sequence of a RackLay export, read like `waresynth.dataset.Sequence` (what the network needs)."""

    def __init__(self, export: RackLayExport, record: RackLaySequence, cameras: dict[str, Any] | None) -> None:
        self.export = export
        self.root = export.root
        self.name = record.name
        self.split = record.split
        self.spec = export.spec
        self.num_frames = record.frames
        self._first = record.first
        self._cam = cameras or {}
        src = f"{export.root / RACKLAY_CAMERAS} ({record.name})"
        self.intrinsics = Intrinsics.from_dict(self._cam.get("intrinsics"), src)
        self.camera_angles = camera_angles(self._cam, src)  #: (roll, pitch, yaw) degrees, as generated

    def __repr__(self) -> str:
        return f"ExportSequence({self.name!r}, split={self.split!r}, frames={self.num_frames})"

    def __len__(self) -> int:
        return self.num_frames

    def _index(self, i: int) -> int:
        """Frame ``i`` of this sequence, checked (the export's index is ``first + i``)."""
        return check_frame_index(i, self.num_frames, self.name)

    def rgb(self, i: int) -> np.ndarray:
        return self.export.rgb(self._first + self._index(i))

    def layouts(self, i: int) -> FrameLayouts:
        return self.export.layouts(self._first + self._index(i))

    def frame(self, i: int) -> dict[str, Any]:
        """Per-frame camera record: camera_position, distance, slots (board_top_y per slot), ..."""
        return self._cam["frames"][self._index(i)]

    def camera_positions(self) -> np.ndarray:
        return np.array([f["camera_position"] for f in self._cam["frames"]], np.float64).reshape(-1, 3)

    def visible_board_ys(self) -> list[float]:
        return [float(y) for y in self._cam.get("board_ys", [])]


def _read_text(path: Path) -> str:
    try:
        return path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise InputError(f"{path}: file not found") from None
    except (OSError, UnicodeDecodeError) as e:
        raise InputError(f"{path}: cannot read ({e})") from None


def load_racklay_export(root: str | os.PathLike) -> RackLayExport:
    """Open a RackLay/MVRackLay export written by `export_racklay` (one-line errors on bad input)."""
    root = Path(root)
    if not root.is_dir():
        raise InputError(f"{root}: RackLay export folder not found")
    manifest = load_json(root / RACKLAY_MANIFEST)
    if not isinstance(manifest, dict) or manifest.get("format") != "racklay":
        raise InputError(f"{root / RACKLAY_MANIFEST}: not a RackLay export manifest")
    if manifest.get("version") not in (1, 2, RACKLAY_VERSION):
        raise InputError(
            f"{root / RACKLAY_MANIFEST}: export version {manifest.get('version')!r} not supported "
            f"(this version reads 1 to {RACKLAY_VERSION})"
        )
    return RackLayExport(root, manifest)
