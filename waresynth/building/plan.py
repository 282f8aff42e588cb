"""A building's plan: aisles between rack rows, one planned row (`RowPlan`) per rack face, and the passes
that scan the faces (long faces in overlapping passes, some faces twice).

Building frame (docs/waresynth.md, "Buildings"): metres, X along the aisles, Y down (floor Y = 0), Z across them.
Aisle ``a`` (from 1) has a face on each side: ``L`` at its lower Z, ``R`` at its higher Z; rows of two
aisles stand back to back. Bays are numbered from 1 along +X on both sides, from the rack positions alone, so
a bay's number (and location code, `waresynth.building.truth`) is the same in every scan. A face's row is
planned in its own row frame (X along the face, the camera looking +Z at its front, Z = 0): for an R face
building = (x, y, front + z), for an L face building = (-x, y, front - z) (a half turn about Y).
Every random choice comes from the building's seed: the face plans from one stream per face, each pass's
camera from its own, so a face scanned twice, or two overlapping passes, show the same racks and boxes.
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from layouts.camera import Intrinsics
from layouts.errors import InputError
from waresynth.building.rack_build import face_kind, lay_bays, rack_ends
from waresynth.config import draw_hfov
from waresynth.draws import uniform
from waresynth.generate import sequence_seeds
from waresynth.row_plan import CameraPlan, RackPlan, RowPlan, visible_levels
from waresynth.scene_builder import (
    sample_levels,
    sample_rack_stacks,
    sample_row_look,
)


def sample_pass_camera(
    rng: np.random.Generator, cfg: dict[str, Any], intr: Intrinsics, plan: RowPlan, want: int
) -> tuple[float, float]:
    """A (distance, height) from the config's ranges from which a camera sees ``want`` of the planned row's
    levels (the first of 200 draws that does; else the draw that sees the most, at least one)."""
    cc = cfg["camera"]
    best, seen = None, 0
    for _ in range(200):
        distance, height = uniform(rng, cc["distance"]), uniform(rng, cc["height"])
        n = len(visible_levels(intr, height, distance, plan.levels, plan.thickness, plan.top))
        if n > seen:
            best, seen = (distance, height), n
        if n >= want:
            break
    if best is None:
        raise InputError("config: camera.height/distance never make a shelf of a planned row visible; widen the ranges")
    return best


@dataclass
class Face:
    """One rack face: its aisle and side, the Z of its front, its bays' X ranges (building frame) and its row."""

    aisle: int
    side: str
    front_z: float
    bays: list[tuple[float, float]]  #: bay b (from 1) spans bays[b - 1] along building X
    row: RowPlan  #: in the face's row frame, racks ``rack_BB`` (BB = bay) in row-frame X order
    build: str = "apart"  #: how its racks are built (`waresynth.building.rack_build.KINDS`)

    @property
    def sign(self) -> float:
        """Row-frame X and Z times this are building X and Z minus the front (+1: R face, -1: L face)."""
        return 1.0 if self.side == "R" else -1.0

    def to_building(self, x: float, y: float, z: float) -> tuple[float, float, float]:
        return (self.sign * x, y, self.front_z + self.sign * z)


@dataclass
class Pass:
    """One pass along a face: its sequence's name and seed, the camera as planned (row frame), the bays it sees
    and the levels in its layouts' slots."""

    name: str
    seed: int
    face: int  #: index into `Building.faces`
    frames: int
    camera: CameraPlan
    bays: list[int]
    levels: list[int]  #: levels (from 0, lowest) the pass's layouts hold
    scan: int  #: 1, or 2 for the second scan of a face scanned twice
    direction: str  #: "+X" or "-X": the way the camera travels in the building frame


@dataclass
class Building:
    config: dict[str, Any]
    faces: list[Face] = field(default_factory=list)
    passes: list[Pass] = field(default_factory=list)
    aisles: list[dict[str, float]] = field(default_factory=list)  #: each aisle's Z range


def _face_row(rng: np.random.Generator, cfg: dict[str, Any], bcfg: dict[str, Any], side: str,
              bays: list[tuple[float, float]], depth: float, kind: str = "apart",
              touch: list[bool] | None = None) -> RowPlan:  # fmt: skip
    """The face's row: levels, uprights, density, materials and every bay's stacks, drawn in bay order
    (``kind`` and ``touch``: how its racks are built, `waresynth.building.rack_build.lay_bays`)."""
    levels, thickness, top = sample_levels(rng, {**cfg, "rack": {**cfg["rack"], "levels": bcfg["levels"]}})
    density, preset, rack_mat, board_mat, uw = sample_row_look(rng, cfg)
    row = RowPlan(levels, thickness, top, depth, uw, density, preset, rack_mat, board_mat)
    sign = 1.0 if side == "R" else -1.0
    for b, (x0, x1) in enumerate(bays, start=1):
        lo, hi = sorted((sign * x0, sign * x1))
        shared = rack_ends(kind, touch or [], b, side == "L")
        stacks = sample_rack_stacks(rng, cfg, preset, lo, hi, 0.0, depth, levels, thickness, top, uw, shared)
        row.racks.append(RackPlan(f"rack_{b:02d}", lo, hi, stacks, shared))
    row.racks.sort(key=lambda r: r.x_min)
    row.gaps = [(a.x_max, b.x_min) for a, b in zip(row.racks, row.racks[1:]) if b.x_min > a.x_max]
    return row


def _spans(lo: float, hi: float, length: float, overlap: float) -> list[tuple[float, float]]:
    """Split the travel [lo, hi] into passes of at most ``length`` that share ``overlap`` metres."""
    total = hi - lo
    n = 1 if total <= length else math.ceil((total - overlap) / (length - overlap))
    each = (total + (n - 1) * overlap) / n
    return [(lo + k * (each - overlap), lo + k * (each - overlap) + each) for k in range(n)]


def half_view(intr: Intrinsics, distance: float, depth: float) -> float:
    """Half the X span of the rack row a camera sees at its back (as the sampled rows are made)."""
    return (distance + depth) * intr.width / (2 * intr.fx)


def plan_building(bcfg: dict[str, Any], cfg: dict[str, Any], seed: int, image_size: tuple[int, int],
                  num_slots: int) -> Building:  # fmt: skip
    """The whole building from its config, the generator config and the seed (same inputs, same plan)."""
    building = Building(copy.deepcopy(bcfg))
    layout = np.random.default_rng(np.random.SeedSequence([seed, 0xB1D]))
    z = 0.0
    face_specs = []
    for a in range(1, bcfg["aisles"] + 1):
        if a > 1:
            z += uniform(layout, bcfg["back_gap"])
        depth_l, width, depth_r = (
            uniform(layout, bcfg["depth"]),
            uniform(layout, bcfg["aisle_width"]),
            uniform(layout, bcfg["depth"]),
        )
        front_l = z + depth_l
        front_r = front_l + width
        building.aisles.append({"aisle": a, "z_min": front_l, "z_max": front_r})
        face_specs += [(a, "L", front_l, depth_l), (a, "R", front_r, depth_r)]
        z = front_r + depth_r
    for k, (a, side, front, depth) in enumerate(face_specs):
        rng = np.random.default_rng(np.random.SeedSequence([seed, 0xFACE, k]))
        kind, runs = face_kind(bcfg, seed, k)
        bays, touch = lay_bays(rng, bcfg, kind, runs)
        row = _face_row(rng, cfg, bcfg, side, bays, depth, kind, touch)
        building.faces.append(Face(a, side, front, bays, row, kind))
    _plan_passes(building, layout, cfg, seed, image_size, num_slots)
    return building


def _plan_passes(building: Building, layout: np.random.Generator, cfg: dict[str, Any], seed: int,
                 image_size: tuple[int, int], num_slots: int) -> None:  # fmt: skip
    """Passes along every face (a second scan of ``twice_share`` of them, the other way), seeds and cameras."""
    bcfg = building.config
    todo: list[tuple[int, tuple[float, float], float, int]] = []
    for k, face in enumerate(building.faces):
        lo, hi = face.bays[0][0], face.bays[-1][1]
        spans = _spans(lo, hi, bcfg["pass_length"], uniform(layout, bcfg["overlap"]))
        forward = 1.0 if layout.random() < 0.5 else -1.0
        scans = 2 if layout.random() < bcfg["twice_share"] else 1
        for scan in range(1, scans + 1):
            direction = forward if scan == 1 else -forward
            for span in spans if direction > 0 else spans[::-1]:
                todo.append((k, span, direction, scan))
    seeds = sequence_seeds(seed ^ 0xB17D, len(todo)) if todo else []
    for p, ((k, (x0, x1), direction, scan), pseed) in enumerate(zip(todo, seeds)):
        face = building.faces[k]
        intr = Intrinsics.from_fov(image_size[0], image_size[1], draw_hfov(cfg, pseed))
        rng = np.random.default_rng(np.random.SeedSequence([seed, 0xCA, p]))
        distance, height = sample_pass_camera(rng, cfg, intr, face.row, min(num_slots, len(face.row.levels)))
        step = uniform(rng, cfg["camera"]["step"])
        frames = max(1, math.ceil((x1 - x0) / step - 1e-9) + 1) if x1 > x0 else 1
        step = (x1 - x0) / (frames - 1) if frames > 1 else step
        start = x0 if direction > 0 else x1
        # the row frame's X runs the other way on an L face
        local_step = direction * face.sign * step
        camera = CameraPlan(distance, height, local_step + 0.0, face.sign * start + 0.0)
        hv = half_view(intr, distance, face.row.depth)
        bays = [b for b, (bx0, bx1) in enumerate(face.bays, start=1) if bx1 > x0 - hv and bx0 < x1 + hv]
        row = face.row
        levels = visible_levels(intr, height, distance, row.levels, row.thickness, row.top)[:num_slots]
        way = "+X" if direction > 0 else "-X"
        building.passes.append(Pass(f"pass_{p:03d}", pseed, k, frames, camera, bays, levels, scan, way))


def replan_passes(building: Building, bcfg: dict[str, Any], cfg: dict[str, Any], seed: int,
                  image_size: tuple[int, int], num_slots: int) -> Building:  # fmt: skip
    """The same racks scanned anew: passes, their seeds and cameras drawn from ``seed`` alone (a rescan), under
    the pass keys of ``bcfg`` (`pass_length`, `overlap`, `twice_share`); the faces are shared, not copied."""
    out = replace(building, config=copy.deepcopy(bcfg), passes=[])
    _plan_passes(out, np.random.default_rng(np.random.SeedSequence([seed, 0x2E5C])), cfg, seed, image_size, num_slots)
    return out


def pass_row(building: Building, p: Pass) -> RowPlan:
    """The racks a pass's scene holds: the bays it sees and a neighbour either side (the face's own plans)."""
    face = building.faces[p.face]
    keep = {f"rack_{b:02d}" for b in range(min(p.bays) - 1, max(p.bays) + 2)}
    racks = [r for r in face.row.racks if r.id in keep]
    gaps = [(a.x_max, b.x_min) for a, b in zip(racks, racks[1:]) if b.x_min > a.x_max]
    return replace(face.row, racks=racks, gaps=gaps)


def route(building: Building) -> dict[str, Any]:
    """``route.json``: each pass's face, start pose and direction in the building frame, frames, step, bays."""
    passes = []
    for p in building.passes:
        face = building.faces[p.face]
        cam = p.camera
        x, _, z = face.to_building(cam.x0, -cam.height, -cam.distance)
        passes.append({
            "sequence": p.name,
            "aisle": face.aisle,
            "side": face.side,
            "scan": p.scan,
            "start": {"x": round(x, 6), "z": round(z, 6), "heading_deg": 90.0 if face.side == "R" else -90.0},
            "height": round(cam.height, 6),
            "direction": p.direction,
            "step": round(abs(cam.step), 6),
            "frames": p.frames,
            "bays": p.bays,
            "levels": [k + 1 for k in p.levels],
            "row_frame": {"front_z": round(face.front_z, 6), "flip": face.side == "L"},
        })  # fmt: skip
    return {
        "frame": "building: metres, X along the aisles, Y down (floor 0), Z across; heading from +X toward +Z",
        "aisles": building.aisles,
        "faces": floor_plan(building),
        "passes": passes,
    }


def floor_plan(building: Building) -> list[dict[str, Any]]:
    """What a floor plan and the racks' specification tell of each face: its aisle and side, the Z of its front
    line, the X its racks span (first to last upright) and its boards' heights above the floor (lowest first).
    No bay or box: those the map finds."""
    return [
        {
            "aisle": f.aisle,
            "side": f.side,
            "front_z": round(f.front_z, 6),
            "x_min": round(f.bays[0][0], 6),
            "x_max": round(f.bays[-1][1], 6),
            "levels_m": [round(v, 6) for v in f.row.levels],
        }
        for f in building.faces
    ]
