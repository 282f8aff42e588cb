"""Export a WareSynth dataset to the RackLay/MVRackLay layout, COCO instance segmentation or YOLO.

Every exporter reads the dataset with `waresynth.dataset.open_dataset`, builds the whole export in
a temporary sibling folder and renames it into place at the end, so an interrupted run leaves no
half export under the final name. Output bytes depend only on the dataset (no dates, no absolute
paths, sorted JSON keys), so the same dataset always exports to the same bytes.

Formats (see docs/export.md for the folder trees):

``racklay``
    ``images/NNNNNN.png``, ``topLayouts/topNNNNNN.npy`` and ``frontLayouts/frontNNNNNN.npy``
    (``(R, D, D)`` uint8 with RackLay's codes 0 / 115 / 255), numbered by one running index over
    all sequences; ``splits/<split>_files.txt`` (RackLay: one index a line) and
    ``splits/<split>_temporal_files.txt`` (MVRackLay: image paths in frame order, each sequence
    closed by a ``,``); ``visible.npy`` ``(N, D)`` bool, the layout columns in view per frame;
    ``cameras.json``, what RackLay's format lacks and training needs (intrinsics, board heights,
    per-frame camera records). `load_racklay_export` reads it back, as frames or as sequences.
``coco``
    ``images/<split>/<seq>_<frame>.png`` and ``annotations/instances_<split>.json`` with
    compressed-RLE masks for the categories box, shelf and rack.
``yolo``
    ``images/<split>/...png``, ``labels/<split>/...txt`` (``class cx cy w h`` normalised to
    [0, 1], or YOLO-seg polygons ``class x1 y1 x2 y2 ...``), ``<split>.txt`` image lists and
    ``data.yaml``.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from scipy import ndimage
from tqdm import tqdm

from layouts.camera import Intrinsics
from layouts.camera_record import CAMERA_ANGLE_KEYS, camera_angles
from layouts.codecs import RACKLAY_CODES, FrameLayouts, from_racklay, to_racklay, validate_stack
from layouts.errors import InputError
from layouts.fileio import (
    atomic_save_npy,
    atomic_write_bytes,
    atomic_write_json,
    atomic_write_text,
    load_json,
    load_npy,
)
from layouts.spec import LayoutSpec
from waresynth.dataset import check_frame_index

EXPORT_FORMATS: tuple[str, ...] = ("coco", "yolo", "racklay")
EXPORT_VERSION = 1

#: Object categories of the COCO and YOLO exports, in class order (YOLO class id = index,
#: COCO category id = index + 1). ``rack`` is the steel frame (uprights and beams).
CATEGORIES: tuple[str, ...] = ("box", "shelf", "rack")

#: Connected components of the shelf / rack semantic masks smaller than this many pixels are
#: dropped (slivers at occlusion boundaries are not useful objects).
MIN_COMPONENT_PIXELS = 4

_SPLIT_ORDER = ("train", "val", "test")
RACKLAY_MANIFEST = "racklay_export.json"
#: what RackLay's format lacks and training needs: per sequence its intrinsics, the board heights it
#: sees and every frame's camera record (position, distance to the rack, slot boards)
RACKLAY_CAMERAS = "cameras.json"
#: the RackLay export's own version: 2 added `RACKLAY_CAMERAS`; version 1 exports still read (layouts only)
RACKLAY_VERSION = 2


# ----------------------------------------------------------------------------- objects per frame
@dataclass
class FrameObject:
    """One annotated object in one image: its category, pixel mask and source ids."""

    category: str
    mask: np.ndarray  #: bool (H, W)
    instance_id: int | None = None  #: id in the instance image (None for a connected component)
    object_id: str | None = None  #: stable scene id (scene.json ``instances``), when listed

    @property
    def bbox(self) -> tuple[int, int, int, int]:
        """Pixel bounding box ``(x0, y0, x1, y1)``, inclusive-exclusive (x1, y1 one past the last pixel)."""
        return mask_bbox(self.mask)


def mask_bbox(mask: np.ndarray) -> tuple[int, int, int, int]:
    """``(x0, y0, x1, y1)`` of a non-empty bool mask, with ``x1``/``y1`` one past the last pixel."""
    rows = np.flatnonzero(mask.any(axis=1))
    cols = np.flatnonzero(mask.any(axis=0))
    if rows.size == 0:
        raise ValueError("mask_bbox of an empty mask")
    return int(cols[0]), int(rows[0]), int(cols[-1]) + 1, int(rows[-1]) + 1


@dataclass(frozen=True)
class InstanceInfo:
    """What an instance id stands for: the scene object's stable id and its semantic class name."""

    object_id: str
    semantic: str


def instance_table(seq: Any) -> dict[int, InstanceInfo]:
    """Instance id -> `InstanceInfo`, from the ``instances`` list of scene.json (or meta.json).

    Entries look like ``{"instance_id": 7, "id": "rack_00/shelf_01/box_003", "semantic": "box"}``.
    Returns ``{}`` when the dataset has no such mapping; categories then come from the pixels.
    """
    for source in (_scene_or_empty(seq), seq.meta):
        raw = source.get("instances") if isinstance(source, dict) else None
        if raw is None:
            continue
        if not isinstance(raw, list):
            raise InputError(f"{seq.root}: 'instances' must be a list of objects, got {type(raw).__name__}")
        out: dict[int, InstanceInfo] = {}
        for entry in raw:
            try:
                iid = int(entry["instance_id"])
                out[iid] = InstanceInfo(str(entry.get("id", entry.get("object_id"))), str(entry.get("semantic", "")))
            except (KeyError, TypeError, ValueError):
                raise InputError(f"{seq.root}: 'instances' has a bad entry {entry!r}") from None
        return out
    return {}


def _scene_or_empty(seq: Any) -> dict:
    try:
        scene = seq.scene()
    except InputError:
        return {}
    return scene if isinstance(scene, dict) else {}


def _components(mask: np.ndarray, category: str) -> list[FrameObject]:
    labels, n = ndimage.label(mask, structure=np.ones((3, 3), bool))
    if n == 0:
        return []
    sizes = np.bincount(labels.ravel(), minlength=n + 1)
    return [FrameObject(category, labels == k) for k in range(1, n + 1) if sizes[k] >= MIN_COMPONENT_PIXELS]


def frame_objects(seq: Any, index: int, table: dict[int, InstanceInfo] | None = None) -> list[FrameObject]:
    """The objects of one frame (boxes, shelf boards, rack frames), in instance-id order.

    Each instance id of the instance image is one object, even when occlusion splits it into
    pieces. Its category is the ``semantic`` of the dataset's ``instances`` table (``table``,
    read from the sequence when None), or the majority semantic class of its pixels when the id
    is not listed; ids of other classes (clutter, floor, walls) are skipped. Shelf or rack pixels
    without an instance id, if a dataset has any, become 8-connected components of at least
    `MIN_COMPONENT_PIXELS` pixels.
    """
    from waresynth import semantics

    inst = np.asarray(seq.instance(index))
    sem = np.asarray(seq.semantic(index))
    if inst.shape != sem.shape or inst.ndim != 2:
        raise InputError(
            f"{seq.instance_path(index)}: instance image {inst.shape} does not match semantic image {sem.shape}"
        )
    table = instance_table(seq) if table is None else table
    by_sem = {semantics.BOX: "box", semantics.SHELF: "shelf", semantics.RACK: "rack"}
    objects: list[FrameObject] = []
    ids = np.unique(inst)
    for iid in ids[ids > 0].tolist():
        m = inst == iid
        info = table.get(iid)
        if info is not None:
            category = info.semantic
        else:
            category = by_sem.get(int(np.bincount(sem[m]).argmax()), "")
        if category in CATEGORIES:
            objects.append(FrameObject(category, m, iid, info.object_id if info else None))
    for sid, name in ((semantics.SHELF, "shelf"), (semantics.RACK, "rack")):
        objects += _components((sem == sid) & (inst == 0), name)
    return objects


# ----------------------------------------------------------------------------- COCO RLE
def rle_counts(mask: np.ndarray) -> list[int]:
    """Uncompressed COCO RLE counts of a bool mask: alternating run lengths in column-major
    order, starting with a (possibly empty) run of zeros."""
    flat = np.asarray(mask, dtype=bool).ravel(order="F")
    if flat.size == 0:
        return [0]
    change = np.flatnonzero(flat[1:] != flat[:-1]) + 1
    bounds = np.concatenate([[0], change, [flat.size]])
    counts = np.diff(bounds).tolist()
    if flat[0]:
        counts = [0, *counts]
    return [int(c) for c in counts]


def rle_string(counts: list[int]) -> str:
    """COCO's compressed RLE string (the LEB128-like code of ``maskApi.c rleToString``)."""
    out = bytearray()
    for i, c in enumerate(counts):
        x = int(c) - (int(counts[i - 2]) if i > 2 else 0)
        more = True
        while more:
            ch = x & 0x1F
            x >>= 5
            more = (x != -1) if (ch & 0x10) else (x != 0)
            if more:
                ch |= 0x20
            out.append(ch + 48)
    return out.decode("ascii")


def mask_to_rle(mask: np.ndarray) -> dict[str, Any]:
    """COCO compressed RLE ``{"size": [h, w], "counts": str}`` of a bool mask."""
    h, w = mask.shape
    return {"size": [int(h), int(w)], "counts": rle_string(rle_counts(mask))}


# ----------------------------------------------------------------------------- helpers
def _progress(it: Any, total: int, desc: str, progress: bool) -> Iterator:
    return iter(tqdm(it, total=total, desc=desc, unit="frame", disable=not progress, leave=False))


def _split_names(dataset: Any) -> list[str]:
    """Splits present in the dataset: train, val, test first, then any other, sorted."""
    present = {s.split for s in dataset.sequences()}
    return [s for s in _SPLIT_ORDER if s in present] + sorted(present - set(_SPLIT_ORDER))


def _check_split_name(split: str, root: Path) -> str:
    if not split or not all(c.isalnum() or c in "_-" for c in split):
        raise InputError(f"{root}: split name {split!r} is not usable in file names")
    return split


def _frame_stem(seq_name: str, index: int) -> str:
    return f"{seq_name}_{index:06d}"


def _copy_file(src: Path, dst: Path) -> None:
    try:
        data = Path(src).read_bytes()
    except FileNotFoundError:
        raise InputError(f"{src}: file not found") from None
    except OSError as e:
        raise InputError(f"{src}: cannot read ({e.strerror})") from None
    atomic_write_bytes(dst, data)


def _open(dataset_dir: str | os.PathLike) -> Any:
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
class _Staging:
    """A temporary folder beside ``out`` that replaces ``out`` only once complete."""

    out: Path
    overwrite: bool
    tmp: Path = field(init=False)

    def __post_init__(self) -> None:
        if self.out.exists():
            if not self.out.is_dir():
                raise InputError(f"{self.out}: exists and is not a folder")
            if any(self.out.iterdir()) and not self.overwrite:
                raise InputError(f"{self.out}: output folder exists and is not empty (pass --overwrite to replace it)")
        self.out.parent.mkdir(parents=True, exist_ok=True)
        self.tmp = Path(tempfile.mkdtemp(prefix=f".{self.out.name}.", suffix=".partial", dir=self.out.parent))

    def commit(self) -> Path:
        old = None
        if self.out.exists():
            old = Path(tempfile.mkdtemp(prefix=f".{self.out.name}.", suffix=".old", dir=self.out.parent))
            os.replace(self.out, old / "x")
        os.replace(self.tmp, self.out)
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)
        return self.out

    def abort(self) -> None:
        shutil.rmtree(self.tmp, ignore_errors=True)


def _run_staged(
    build: Callable[[Any, Path, bool], dict],
    dataset_dir: str | os.PathLike,
    out_dir: str | os.PathLike,
    overwrite: bool,
    progress: bool,
) -> Path:
    """Open and check the dataset, let ``build`` fill a staging folder, then move it to ``out_dir``."""
    dataset = _open(dataset_dir)
    out = Path(out_dir)
    src, dst = Path(dataset.root).resolve(), out.resolve()
    if dst == src or src in dst.parents or dst in src.parents:
        raise InputError(f"{out}: output folder must lie outside the dataset folder {dataset.root}")
    if not dataset.sequences():
        raise InputError(f"{dataset.root}: dataset has no sequences")
    stage = _Staging(out, overwrite)
    try:
        build(dataset, stage.tmp, progress)
    except BaseException:
        stage.abort()
        raise
    return stage.commit()


def _source_record(dataset: Any) -> dict[str, Any]:
    w, h = dataset.image_size
    return {
        "dataset": Path(dataset.root).name,
        "seed": int(dataset.seed),
        "image_size": [int(w), int(h)],
        "spec": dataset.spec.to_dict(),
    }


# ----------------------------------------------------------------------------- RackLay
def _export_racklay(dataset: Any, tmp: Path, progress: bool) -> dict:
    """RackLay / MVRackLay folder: images, 0/115/255 layout stacks, split and temporal split files."""
    spec: LayoutSpec = dataset.spec
    seqs = dataset.sequences()
    total = sum(s.num_frames for s in seqs)
    splits = _split_names(dataset)
    records: list[dict[str, Any]] = []
    split_indices: dict[str, list[int]] = {s: [] for s in splits}
    temporal: dict[str, list[str]] = {s: [] for s in splits}
    visible = np.zeros((total, spec.size), bool)
    have_visible = True
    cameras: dict[str, Any] = {}
    index = 0

    def frames() -> Iterator[tuple[Any, int]]:
        for seq in seqs:
            for i in range(seq.num_frames):
                yield seq, i

    for seq, i in _progress(frames(), total, "export racklay", progress):
        if i == 0:
            _check_split_name(seq.split, dataset.root)
            records.append({"name": seq.name, "split": seq.split, "first": index, "frames": seq.num_frames})
            cameras[seq.name] = {
                "intrinsics": seq.intrinsics.to_dict(),
                **dict(zip(CAMERA_ANGLE_KEYS, seq.camera_angles)),
                "board_ys": seq.visible_board_ys(),
                "frames": [seq.frame(k) for k in range(seq.num_frames)],
            }
        lay: FrameLayouts = seq.layouts(i)
        lay.validate(spec, str(seq.root / "layouts" / f"{i:06d}.npz"))
        _copy_file(seq.rgb_path(i), tmp / "images" / f"{index:06d}.png")
        atomic_save_npy(tmp / "topLayouts" / f"top{index:06d}.npy", to_racklay(lay.top))
        atomic_save_npy(tmp / "frontLayouts" / f"front{index:06d}.npy", to_racklay(lay.front))
        if lay.visible is None:
            have_visible = False
        else:
            visible[index] = lay.visible
        split_indices[seq.split].append(index)
        temporal[seq.split].append(f"images/{index:06d}.png\n")
        if i == seq.num_frames - 1:
            temporal[seq.split].append(",")
        index += 1

    for s in splits:
        atomic_write_text(tmp / "splits" / f"{s}_files.txt", "".join(f"{k}\n" for k in split_indices[s]))
        atomic_write_text(tmp / "splits" / f"{s}_temporal_files.txt", "".join(temporal[s]))
    if have_visible:
        atomic_save_npy(tmp / "visible.npy", visible)
    atomic_write_json(tmp / RACKLAY_CAMERAS, {"sequences": cameras})
    manifest = {
        "format": "racklay",
        "version": RACKLAY_VERSION,
        "cameras": RACKLAY_CAMERAS,
        "source": _source_record(dataset),
        "spec": spec.to_dict(),
        "num_frames": total,
        "codes": {name: RACKLAY_CODES[cid] for cid, name in enumerate(("background", "shelf", "box"))},
        "splits": splits,
        "visible": have_visible,
        "sequences": records,
    }
    atomic_write_json(tmp / RACKLAY_MANIFEST, manifest)
    return manifest


def export_racklay(
    dataset_dir: str | os.PathLike, out_dir: str | os.PathLike, *, overwrite: bool = False, progress: bool = True
) -> Path:
    """Write the RackLay/MVRackLay layout of a dataset to ``out_dir`` (read it back with `load_racklay_export`)."""
    return _run_staged(_export_racklay, dataset_dir, out_dir, overwrite, progress)


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
        if split is not None and split not in _SPLIT_ORDER:
            raise InputError(f"split must be one of {_SPLIT_ORDER} or None, got {split!r}")
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
        return self.root / "images" / f"{self._check(index):06d}.png"

    def rgb(self, index: int) -> np.ndarray:
        """uint8 ``(H, W, 3)`` image of frame ``index``."""
        from PIL import Image, UnidentifiedImageError

        p = self.image_path(index)
        try:
            with Image.open(p) as im:
                return np.asarray(im.convert("RGB"))
        except FileNotFoundError:
            raise InputError(f"{p}: file not found") from None
        except (UnidentifiedImageError, OSError) as e:
            raise InputError(f"{p}: not a readable image ({e})") from None

    def layouts(self, index: int) -> FrameLayouts:
        """Class-id layouts (0/1/2) of frame ``index``, with its visible columns when exported."""
        i = self._check(index)
        top = self._stack(self.root / "topLayouts" / f"top{i:06d}.npy")
        front = self._stack(self.root / "frontLayouts" / f"front{i:06d}.npy")
        vis = self.visible[i].copy() if self.visible is not None else None
        return FrameLayouts(top, front, vis)

    def _stack(self, path: Path) -> np.ndarray:
        return validate_stack(from_racklay(load_npy(path), str(path)), self.spec, str(path))

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
        if split not in self.splits:
            raise InputError(f"{self.root}: no split {split!r} (have {self.splits})")
        return self.root / "splits" / f"{split}_{kind}.txt"

    def split_indices(self, split: str) -> list[int]:
        """Frame indices of ``split`` from ``splits/<split>_files.txt`` (RackLay's list)."""
        p = self._split_file(split, "files")
        out = []
        for n, line in enumerate(_read_text(p).splitlines(), 1):
            try:
                out.append(self._check(int(line)))
            except (ValueError, InputError):
                raise InputError(f"{p}:{n}: not a frame index of this export: {line!r}") from None
        return out

    def temporal_sequences(self, split: str) -> list[list[int]]:
        """Ordered frame indices per sequence of ``split``, parsed like MVRackLay's
        ``temporal_readlines``: chunks separated by ``,``, one image path a line."""
        p = self._split_file(split, "temporal_files")
        chunks = _read_text(p).split(",")[:-1]
        out = []
        for chunk in chunks:
            idx = []
            for line in chunk.split("\n")[:-1]:
                name = Path(line).name
                try:
                    idx.append(self._check(int(Path(name).stem)))
                except (ValueError, InputError):
                    raise InputError(f"{p}: not an image of this export: {line!r}") from None
            out.append(idx)
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
    if manifest.get("version") not in (1, RACKLAY_VERSION):
        raise InputError(
            f"{root / RACKLAY_MANIFEST}: export version {manifest.get('version')!r} not supported "
            f"(this version reads 1 and {RACKLAY_VERSION})"
        )
    return RackLayExport(root, manifest)


# ----------------------------------------------------------------------------- COCO
def _export_coco(dataset: Any, tmp: Path, progress: bool) -> dict:
    """COCO instance segmentation: one annotation file per split, compressed-RLE masks."""
    w, h = dataset.image_size
    categories = [{"id": k + 1, "name": n, "supercategory": "warehouse"} for k, n in enumerate(CATEGORIES)]
    cat_id = {n: k + 1 for k, n in enumerate(CATEGORIES)}
    summary: dict[str, Any] = {"format": "coco", "version": EXPORT_VERSION, "source": _source_record(dataset)}
    counts: dict[str, dict[str, int]] = {}
    image_id = ann_id = 0
    for split in _split_names(dataset):
        _check_split_name(split, dataset.root)
        seqs = dataset.sequences(split)
        images: list[dict[str, Any]] = []
        anns: list[dict[str, Any]] = []
        per_cat = dict.fromkeys(CATEGORIES, 0)
        total = sum(s.num_frames for s in seqs)
        frames = ((seq, i) for seq in seqs for i in range(seq.num_frames))
        tables: dict[str, dict[int, InstanceInfo]] = {}
        for seq, i in _progress(frames, total, f"export coco {split}", progress):
            if seq.name not in tables:
                tables[seq.name] = instance_table(seq)
            image_id += 1
            name = f"{_frame_stem(seq.name, i)}.png"
            _copy_file(seq.rgb_path(i), tmp / "images" / split / name)
            images.append(
                {"id": image_id, "file_name": name, "width": int(w), "height": int(h), "sequence": seq.name, "frame": i}
            )
            for obj in frame_objects(seq, i, tables[seq.name]):
                ann_id += 1
                x0, y0, x1, y1 = obj.bbox
                ann: dict[str, Any] = {
                    "id": ann_id,
                    "image_id": image_id,
                    "category_id": cat_id[obj.category],
                    "segmentation": mask_to_rle(obj.mask),
                    "area": int(obj.mask.sum()),
                    "bbox": [x0, y0, x1 - x0, y1 - y0],
                    "iscrowd": 0,
                }
                if obj.instance_id is not None:
                    ann["instance_id"] = obj.instance_id
                if obj.object_id is not None:
                    ann["object_id"] = obj.object_id
                anns.append(ann)
                per_cat[obj.category] += 1
        coco = {
            "info": {
                "description": f"WareSynth dataset {Path(dataset.root).name}, split {split}",
                "version": str(EXPORT_VERSION),
            },
            "licenses": [],
            "images": images,
            "annotations": anns,
            "categories": categories,
        }
        text = json.dumps(coco, separators=(",", ":"), sort_keys=True) + "\n"
        atomic_write_text(tmp / "annotations" / f"instances_{split}.json", text)
        counts[split] = {"images": len(images), **per_cat}
    summary["counts"] = counts
    summary["splits"] = list(counts)
    atomic_write_json(tmp / "export.json", summary)
    return summary


def export_coco(
    dataset_dir: str | os.PathLike, out_dir: str | os.PathLike, *, overwrite: bool = False, progress: bool = True
) -> Path:
    """Write COCO instance segmentation (images + ``annotations/instances_<split>.json``) to ``out_dir``."""
    return _run_staged(_export_coco, dataset_dir, out_dir, overwrite, progress)


# ----------------------------------------------------------------------------- YOLO
def yolo_box(bbox: tuple[int, int, int, int], width: int, height: int) -> tuple[float, float, float, float]:
    """Pixel box ``(x0, y0, x1, y1)`` (x1/y1 exclusive) -> normalised ``(cx, cy, w, h)`` in [0, 1]."""
    x0, y0, x1, y1 = bbox
    return ((x0 + x1) / 2 / width, (y0 + y1) / 2 / height, (x1 - x0) / width, (y1 - y0) / height)


def mask_polygon(mask: np.ndarray, tolerance: float = 0.75) -> np.ndarray:
    """Outline of a bool mask as one polygon ``(N, 2)`` of continuous ``(x, y)`` pixel coordinates.

    Each 8-connected piece is traced along its pixel edges (marching squares at level 0.5) and
    simplified (Douglas-Peucker, ``tolerance`` pixels); pieces are joined into one ring by a
    there-and-back bridge between their nearest vertices, as single-polygon formats such as
    YOLO-seg need. Holes are not represented.
    """
    from skimage.measure import approximate_polygon, find_contours

    if not np.any(mask):
        raise ValueError("mask_polygon of an empty mask")
    x0, y0, x1, y1 = mask_bbox(mask)
    labels, _ = ndimage.label(mask[y0:y1, x0:x1], structure=np.ones((3, 3), bool))
    poly: np.ndarray | None = None
    for k, box in enumerate(ndimage.find_objects(labels), 1):
        padded = np.pad(labels[box] == k, 1).astype(np.float64)  # the piece's bounding box only
        rings = find_contours(padded, 0.5)
        ring = max(rings, key=len)[:-1]  # closed ring: drop the repeated end point
        ring = approximate_polygon(ring, tolerance) if len(ring) > 4 else ring
        # (row, col) of the padded crop -> continuous (x, y) of the image (pixel c spans [c, c+1)).
        ring = ring[:, ::-1] + (x0 + box[1].start - 0.5, y0 + box[0].start - 0.5)
        if poly is None:
            poly = ring
            continue
        d = ((poly[:, None, :] - ring[None, :, :]) ** 2).sum(-1)
        i, j = np.unravel_index(int(np.argmin(d)), d.shape)
        rolled = np.roll(ring, -j, axis=0)
        poly = np.concatenate([poly[: i + 1], rolled, rolled[:1], poly[i:]])
    assert poly is not None
    return poly


def _export_yolo(dataset: Any, tmp: Path, progress: bool, segments: bool = False) -> dict:
    """YOLO detection (or YOLO-seg polygons): per-image label files, split image lists and data.yaml."""
    w, h = dataset.image_size
    cls = {n: k for k, n in enumerate(CATEGORIES)}
    splits = _split_names(dataset)
    counts: dict[str, dict[str, int]] = {}
    for split in splits:
        _check_split_name(split, dataset.root)
        seqs = dataset.sequences(split)
        total = sum(s.num_frames for s in seqs)
        frames = ((seq, i) for seq in seqs for i in range(seq.num_frames))
        listing: list[str] = []
        per_cat = dict.fromkeys(CATEGORIES, 0)
        tables: dict[str, dict[int, InstanceInfo]] = {}
        for seq, i in _progress(frames, total, f"export yolo {split}", progress):
            if seq.name not in tables:
                tables[seq.name] = instance_table(seq)
            stem = _frame_stem(seq.name, i)
            _copy_file(seq.rgb_path(i), tmp / "images" / split / f"{stem}.png")
            lines = []
            for obj in frame_objects(seq, i, tables[seq.name]):
                if segments:
                    xy = np.clip(mask_polygon(obj.mask) / (w, h), 0.0, 1.0)
                    coords = " ".join(f"{v:.6f}" for v in xy.ravel())
                else:
                    coords = " ".join(f"{v:.6f}" for v in yolo_box(obj.bbox, w, h))
                lines.append(f"{cls[obj.category]} {coords}\n")
                per_cat[obj.category] += 1
            atomic_write_text(tmp / "labels" / split / f"{stem}.txt", "".join(lines))
            listing.append(f"./images/{split}/{stem}.png\n")
        atomic_write_text(tmp / f"{split}.txt", "".join(listing))
        counts[split] = {"images": len(listing), **per_cat}
    task = "segmentation (labels: class x1 y1 x2 y2 ... polygon" if segments else "detection (labels: class cx cy w h"
    yaml = [
        f"# WareSynth dataset exported for YOLO {task}, normalised to [0, 1]).",
        "# Paths are relative to this file's folder.",
    ]
    yaml += [f"{s}: {s}.txt" for s in splits]
    yaml.append(f"nc: {len(CATEGORIES)}")
    yaml.append("names:")
    yaml += [f"  {k}: {n}" for k, n in enumerate(CATEGORIES)]
    atomic_write_text(tmp / "data.yaml", "\n".join(yaml) + "\n")
    summary = {
        "format": "yolo",
        "task": "segment" if segments else "detect",
        "version": EXPORT_VERSION,
        "source": _source_record(dataset),
        "counts": counts,
        "splits": splits,
    }
    atomic_write_json(tmp / "export.json", summary)
    return summary


def export_yolo(
    dataset_dir: str | os.PathLike,
    out_dir: str | os.PathLike,
    *,
    overwrite: bool = False,
    progress: bool = True,
    segments: bool = False,
) -> Path:
    """Write YOLO labels (boxes, or polygons with ``segments=True``), image lists and ``data.yaml``."""

    def build(dataset: Any, tmp: Path, progress: bool) -> dict:
        return _export_yolo(dataset, tmp, progress, segments)

    return _run_staged(build, dataset_dir, out_dir, overwrite, progress)


_EXPORTERS: dict[str, Callable[..., Path]] = {"coco": export_coco, "yolo": export_yolo, "racklay": export_racklay}


def export_dataset(
    dataset_dir: str | os.PathLike,
    out_dir: str | os.PathLike,
    fmt: str,
    *,
    overwrite: bool = False,
    progress: bool = True,
    yolo_segments: bool = False,
) -> Path:
    """Export the WareSynth dataset at ``dataset_dir`` to ``out_dir`` in format ``fmt`` (one of
    `EXPORT_FORMATS`); ``yolo_segments`` writes YOLO-seg polygons instead of boxes. Returns the
    output folder."""
    if fmt not in _EXPORTERS:
        raise InputError(f"format must be one of {', '.join(EXPORT_FORMATS)}, got {fmt!r}")
    if yolo_segments and fmt != "yolo":
        raise InputError(f"polygon labels (segment task) exist only for the yolo format, not {fmt!r}")
    if fmt == "yolo":
        return export_yolo(dataset_dir, out_dir, overwrite=overwrite, progress=progress, segments=yolo_segments)
    return _EXPORTERS[fmt](dataset_dir, out_dir, overwrite=overwrite, progress=progress)
