"""Which box stacks' depth a frame shows: the ground truth of "could a reader know how deep it is".

A stack's depth (its extent along Z) shows in an image only through a top face, a side face seen
through a gap, or its back edge. A stack counts as *seen* in a frame when its visible pixels
(instance image) reach, by the depth image, at least `SEEN` of the way from its front face to its
back. `benchmarks/layout_ceilings.py` scores oracles built on it, and training can weight the
top-view loss toward the stacks whose depth a window has shown (`network.data.WindowDataset`).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from layouts import LayoutSpec

SEEN = 0.9  #: fraction of a stack's depth its visible pixels must reach for its depth to count as seen


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
    """Indices of the stacks (among ``candidates``, default all) whose visible pixels reach `SEEN` of their depth."""
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
