"""Which box stacks' depth a frame shows: the ground truth of "could a reader know how deep it is";
and where a frame shows the row's front and rear uprights (`upright_faces`).

A stack's depth (its extent along Z) shows in an image only through a top face, a side face seen
through a gap, or its back edge. A stack counts as *seen* in a frame when its visible pixels
(instance image) reach, by the depth image, at least `SEEN` of the way from its front face to its
back. `research/layout_ceilings.py` scores oracles built on it, and training can weight the
top-view loss toward the stacks whose depth a window has shown (`network.data.WindowDataset`).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from layouts import LayoutSpec
from layouts.errors import InputError
from waresynth.semantics import RACK

SEEN = 0.9  #: fraction of a stack's depth its visible pixels must reach for its depth to count as seen
#: metres from the rack's back to the middle of the rear uprights' front faces (uprights are 6-10 cm wide)
REAR_UPRIGHT_FACE = 0.08
#: metres either side of a face's depth that still count as that face (covers the widths and side faces)
UPRIGHT_TOLERANCE = 0.12


def scene_stacks(scene: dict[str, Any]) -> list[dict[str, Any]]:
    """Every stack of a scene: level, footprint (x, z, yaw, w, d, hx, hz) and its boxes' instance ids."""
    out: dict[str, dict[str, Any]] = {}
    for rack in scene["racks"]:
        for level, shelf in enumerate(rack["shelves"]):
            for b in shelf["boxes"]:
                st = out.setdefault(
                    b["stack_id"],
                    {"level": level, "x": b["center"][0], "z": b["center"][2], "yaw": b["yaw"],
                     "w": b["size"][0], "d": b["size"][2], "ids": []},
                )  # fmt: skip
                st["ids"].append(int(b["instance_id"]))
    for st in out.values():
        c, s = abs(math.cos(st["yaw"])), abs(math.sin(st["yaw"]))
        st["hx"] = 0.5 * (c * st["w"] + s * st["d"])  # half the footprint's extent along X
        st["hz"] = 0.5 * (s * st["w"] + c * st["d"])  # half the footprint's extent along Z
        st["ids"] = np.asarray(st["ids"], np.int32)
    return list(out.values())


def seen_stacks(
    stacks: list[dict[str, Any]],
    depth: np.ndarray,
    instance: np.ndarray,
    cam_z: float,
    candidates: list[int] | None = None,
) -> set[int]:
    """Indices of the stacks (among ``candidates``, default all) whose visible pixels reach `SEEN` of their depth.

    ``depth``: metres along world Z from the camera (`waresynth.dataset.Sequence.level_depth`; a level
    camera's Z-depth image)."""
    seen = set()
    ids = np.unique(instance)
    for k in range(len(stacks)) if candidates is None else candidates:
        st = stacks[k]
        if not np.isin(st["ids"], ids).any():
            continue
        m = np.isin(instance, st["ids"]) & (depth > 0)
        if m.any():
            reach = cam_z + float(depth[m].max()) - (st["z"] - st["hz"])
            if reach >= SEEN * 2 * st["hz"]:
                seen.add(k)
    return seen


def stack_columns(st: dict[str, Any], spec: LayoutSpec, cam_x: float) -> tuple[int, int]:
    """Half-open range ``[c0, c1)`` of the layout columns whose centres lie on the stack's footprint."""
    u0, u1 = spec.x_to_col(st["x"] - st["hx"] - cam_x), spec.x_to_col(st["x"] + st["hx"] - cam_x)
    c0 = max(int(math.ceil(float(u0) - 0.5)), 0)
    c1 = min(int(math.floor(float(u1) - 0.5)) + 1, spec.size)
    return c0, max(c0, c1)


def stack_column_map(
    stacks: list[dict[str, Any]],
    values: dict[int, float],
    spec: LayoutSpec,
    levels: list[int],
    cam_x: float,
    fill: float = 0.0,
) -> np.ndarray:
    """float32 ``(R, D)`` per slot and layout column: ``values[k]`` on the columns of stack ``k`` (on the
    slot showing its level, ``levels[r]``, camera at ``cam_x``), ``fill`` elsewhere."""
    out = np.full((spec.num_slots, spec.size), fill, np.float32)
    for k, v in values.items():
        st = stacks[k]
        if st["level"] in levels:
            c0, c1 = stack_columns(st, spec, cam_x)
            out[levels.index(st["level"]), c0:c1] = v
    return out


class SeenTracker:
    """Which stacks' depth a generated sequence has shown so far, frame by frame (frames in order)."""

    def __init__(self, seq: Any) -> None:
        for name in ("level_depth", "instance", "scene"):
            if not callable(getattr(seq, name, None)):
                raise InputError(f"{seq.name}: visibility needs the generator's depth, instance and scene files")
        self.seq = seq
        self.stacks = scene_stacks(seq.scene())
        self.sofar: set[int] = set()
        self.now: set[int] = set()

    def add(self, i: int) -> None:
        """Frame ``i`` (frames in order)."""
        cam_z = float(self.seq.frame(i)["camera_position"][2])
        self.now = seen_stacks(self.stacks, self.seq.level_depth(i), self.seq.instance(i), cam_z)
        self.sofar |= self.now

    def labels(self, i: int) -> np.ndarray:
        """int ``(R, D)`` per slot and layout column: 2 = a stack whose depth frame ``i`` sees, 1 = seen
        only earlier, 0 = not seen yet, -1 = no stack."""
        rec, spec = self.seq.frame(i), self.seq.spec
        levels = [int(sl["level"]) for sl in rec.get("slots", [])[: spec.num_slots]]
        values = {k: 2 if k in self.now else 1 if k in self.sofar else 0 for k in range(len(self.stacks))}
        return stack_column_map(self.stacks, values, spec, levels, float(rec["camera_position"][0]), -1).astype(int)


def upright_faces(
    semantic: np.ndarray, depth: np.ndarray, distance: float, rack_depth: float
) -> tuple[np.ndarray, np.ndarray]:
    """Boolean masks ``(H, W)`` of a frame's mapped-row rack pixels (uprights and beams; semantic `RACK`)
    whose depth (metres along Z from the camera) puts them on the front plane, and at the rear uprights'
    face `REAR_UPRIGHT_FACE` in front of the rack's back; each within `UPRIGHT_TOLERANCE`."""
    semantic, depth = np.asarray(semantic), np.asarray(depth, np.float64)
    if semantic.shape != depth.shape:
        raise InputError(f"semantic {semantic.shape} and depth {depth.shape} images differ in shape")
    rack = semantic == RACK
    front = rack & (np.abs(depth - distance) < UPRIGHT_TOLERANCE)
    rear = rack & (np.abs(depth - (distance + rack_depth - REAR_UPRIGHT_FACE)) < UPRIGHT_TOLERANCE)
    return front, rear
