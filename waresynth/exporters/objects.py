"""The annotated objects of a WareSynth frame (boxes, shelf boards, rack frames), shared by the COCO and
YOLO exporters: one `FrameObject` per instance id, its category from the dataset's ``instances`` table."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy import ndimage

from layouts.errors import InputError

#: Object categories of the COCO and YOLO exports, in class order (YOLO class id = index,
#: COCO category id = index + 1). ``rack`` is the steel frame (uprights and beams).
CATEGORIES: tuple[str, ...] = ("box", "shelf", "rack")

#: Connected components of the shelf / rack semantic masks smaller than this many pixels are
#: dropped (slivers at occlusion boundaries are not useful objects).
MIN_COMPONENT_PIXELS = 4


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
