"""Sampling of a `waresynth.scene.Scene`: the rack row, its boxes, the background, lighting and camera path.

Everything is built from one ``numpy.random.Generator`` and the effective config, so a sequence seed
fully determines its scene. The stages of `build_scene` draw from the generator in a fixed order (row and camera,
racks, background, floor and wall, light and sensor, camera rotation, motion blur, the look of `waresynth.look`):
changing that order changes every generated dataset.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from layouts.camera import Intrinsics
from layouts.camera_record import CAMERA_ANGLE_KEYS
from layouts.errors import InputError
from waresynth import semantics as sem
from waresynth.draws import choice, colour, integer, uniform
from waresynth.look import draw_look, draw_motion_blur
from waresynth.row_plan import (
    CameraPlan,
    RackPlan,
    RowPlan,
    StackPlan,
    board_span,
    clear_heights,
    level_in_window,
    level_visible,
    slot_half_height,
    upright_centres,
    visible_levels,
)
from waresynth.scene import PATTERNS, Z_FRONT, Box, Camera, Material, Part, Rack, Scene, Shelf


class _Builder:
    """Accumulates parts, materials and instance ids while the scene is built."""

    def __init__(self) -> None:
        self.parts: list[Part] = []
        self.materials: list[Material] = []
        self.instances: list[dict[str, Any]] = []

    def material(self, m: Material) -> int:
        self.materials.append(m)
        return len(self.materials) - 1

    def instance(self, obj_id: str, semantic: int) -> int:
        iid = len(self.instances) + 1
        if iid > 65535:
            raise InputError("scene has more than 65535 objects; reduce the row length (frames x step)")
        self.instances.append({"instance_id": iid, "id": obj_id, "semantic": sem.SEMANTIC_NAMES[semantic]})
        return iid

    def cuboid(self, center, size, semantic: int, instance: int, material: int, yaw: float = 0.0) -> None:
        self.parts.append(
            Part(
                tuple(float(c) for c in center), tuple(float(s) for s in size), float(yaw), semantic, instance, material
            )
        )


# ----------------------------------------------------------------------------- row
def sample_levels(rng: np.random.Generator, cfg: dict[str, Any]) -> tuple[list[float], float, float]:
    rc = cfg["rack"]
    n = integer(rng, rc["levels"])
    thickness = uniform(rng, rc["board_thickness"])
    levels = [uniform(rng, rc["first_level"])]
    for _ in range(n - 1):
        levels.append(levels[-1] + uniform(rng, rc["spacing"]))
    top = levels[-1] + uniform(rng, rc["top_clearance"])
    return levels, thickness, top


def sample_stacks(
    rng: np.random.Generator,
    cfg: dict[str, Any],
    preset: dict[str, Any],
    clear_height: float,
    x_lo: float,
    x_hi: float,
    z_front: float,
    depth: float,
) -> list[StackPlan]:
    """Fill one board left to right with stacks whose yawed footprints stay on the board."""
    bc = cfg["boxes"]
    cursor = x_lo + uniform(rng, preset["gap"])
    out: list[StackPlan] = []
    limit = clear_height - bc["head_room"]
    while True:
        w, d, h = uniform(rng, bc["width"]), uniform(rng, bc["depth"]), uniform(rng, bc["height"])
        yaw = (
            math.radians(uniform(rng, [-bc["yaw_deg"], bc["yaw_deg"]])) if rng.random() < bc["yaw_probability"] else 0.0
        )
        setback = uniform(rng, bc["setback"])
        c, s = abs(math.cos(yaw)), abs(math.sin(yaw))
        # Keep the footprint on the board: shrink the depth if needed.
        max_hz = (depth - setback - 0.02) / 2
        if 0.5 * (s * w + c * d) > max_hz:
            d = max((2 * max_hz - s * w) / max(c, 1e-6), 0.0)
        hx = 0.5 * (c * w + s * d)
        hz = 0.5 * (s * w + c * d)
        if cursor + 2 * hx > x_hi:
            break
        empty = rng.random() < preset["empty_probability"]
        count = 1
        while count < bc["max_stack"] and rng.random() < preset["stack_probability"]:
            count += 1
        if h > limit:
            h = limit
        count = max(1, min(count, int(limit // h))) if h > 0 else 0
        if not empty and d >= 0.05 and h >= 0.05:
            rgb = colour(rng, bc["colours"], bc["colour_jitter"])
            pattern = PATTERNS[choice(rng, bc["textures"])]
            refl = uniform(rng, bc["reflectance"])
            out.append(
                StackPlan(cursor + hx, z_front + setback + hz, (w, h, d), yaw, count, Material(rgb, pattern, refl, w))
            )
        cursor += 2 * hx + uniform(rng, preset["gap"])
    return out


def _add_stacks(
    b: _Builder, shelf: Shelf, stacks: list[StackPlan], level: float, semantic: int, record: bool, shared_instance: int
) -> None:
    """The boxes of a board's planned stacks (recorded on ``shelf`` for the mapped row)."""
    for n_stack, st in enumerate(stacks):
        w, h, d = st.size
        stack_id = f"{shelf.id}/stack_{n_stack:03d}"
        mat = b.material(st.material)
        for k in range(st.count):
            bid = f"{shelf.id}/box_{len(shelf.boxes):03d}"
            center = (st.x, -(level + (k + 0.5) * h), st.z)
            iid = b.instance(bid, semantic) if record else shared_instance
            b.cuboid(center, (w, h, d), semantic, iid, mat, st.yaw)
            if record:
                shelf.boxes.append(Box(bid, center, (w, h, d), st.yaw, stack_id, k, iid))


def sample_rack_stacks(
    rng: np.random.Generator,
    cfg: dict[str, Any],
    preset: dict[str, Any],
    x_min: float,
    x_max: float,
    z_front: float,
    depth: float,
    levels: list[float],
    thickness: float,
    top: float,
    uw: float,
    shared: tuple[bool, bool] = (False, False),
) -> list[list[StackPlan]]:
    """The stacks of every board of one rack, lowest first (``shared``: `RackPlan.shared`)."""
    lo, hi = board_span(x_min, x_max, uw, shared)
    clears = clear_heights(levels, thickness, top)
    return [sample_stacks(rng, cfg, preset, ch, lo, hi, z_front, depth) for ch in clears]


def _build_rack_parts(
    b: _Builder,
    rack: Rack,
    levels: list[float],
    thickness: float,
    top: float,
    uw: float,
    rack_mat: int,
    board_mat: int,
    semantics: tuple[int, int, int],
    record: bool,
    stacks: list[list[StackPlan]],
    shared_instance: int = 0,
    shared: tuple[bool, bool] = (False, False),
    frames: tuple[bool, bool] = (True, True),
) -> None:
    """Uprights (``frames``: which of its two; ``shared``: `RackPlan.shared`), top beams, boards and boxes of a rack."""
    rack_sem, shelf_sem, box_sem = semantics
    x0, x1, zf, dp = rack.x_min, rack.x_max, rack.z_front, rack.depth
    beam = 0.08
    height = top + beam
    rid = rack.instance_id if record else shared_instance
    proud = 0.003  # uprights 3 mm proud of boards, beams slimmer: no coplanar faces (their ids would be arbitrary)
    xs = upright_centres(x0, x1, uw, shared)
    for x in (x for x, own in zip(xs, frames) if own):  # a frame shared with the rack before is built there
        for z in (zf + uw / 2, zf + dp - uw / 2):
            b.cuboid((x, -height / 2, z), (uw + 2 * proud, height, uw + 2 * proud), rack_sem, rid, rack_mat)
    for z in (zf + uw / 2, zf + dp - uw / 2):
        bx, bw = ((xs[0] + xs[1]) / 2, xs[1] - xs[0] - uw) if any(shared) else ((x0 + x1) / 2, x1 - x0 - 2 * uw)
        b.cuboid((bx, -(top + beam / 2), z), (bw, beam, uw * 0.8), rack_sem, rid, rack_mat)
    clears = clear_heights(levels, thickness, top)
    for k, (lv, ch) in enumerate(zip(levels, clears)):
        sid = f"{rack.id}/shelf_{k:02d}"
        iid = b.instance(sid, shelf_sem) if record else shared_instance
        shelf = Shelf(sid, k, -lv, thickness, ch, iid)
        b.cuboid(
            ((x0 + x1) / 2, -(lv - thickness / 2), zf + dp / 2), (x1 - x0, thickness, dp), shelf_sem, iid, board_mat
        )
        _add_stacks(b, shelf, stacks[k], lv, box_sem, record, shared_instance)
        if record:
            rack.shelves.append(shelf)


@dataclass
class _Row:
    """The mapped row as sampled: shared shelf heights, the racks along X and what the background reuses."""

    levels: list[float]
    thickness: float
    top: float
    depth: float
    upright_width: float = 0.0
    preset: dict[str, Any] = field(default_factory=dict)  #: the box-density preset drawn for the scene
    density: str = ""
    board_mat: int = -1
    racks: list[Rack] = field(default_factory=list)
    gaps: list[tuple[float, float]] = field(default_factory=list)  #: X ranges between neighbouring racks


def _sample_row_camera(
    rng: np.random.Generator, cfg: dict[str, Any], intrinsics: Intrinsics, frames: int, x_extent: float | None
) -> tuple[_Row, Camera, list[int]]:
    """Row heights (shared by every rack of the row), a camera that sees 1..R of them, and its path; with
    ``x_extent``, one of those inside the canonical view too (a shelf slot: `waresynth.groundtruth.slot_levels`)."""
    cc, rc = cfg["camera"], cfg["rack"]
    for _ in range(200):
        levels, thickness, top = sample_levels(rng, cfg)
        clears = clear_heights(levels, thickness, top)
        distance = uniform(rng, cc["distance"])
        cam_h = uniform(rng, cc["height"])
        visible = [k for k in range(len(levels)) if level_visible(intrinsics, cam_h, distance, levels[k], clears[k])]
        half = None if x_extent is None else slot_half_height(intrinsics, x_extent)
        if any(half is None or level_in_window(cam_h, levels[k], clears[k], half) for k in visible):
            break
    else:
        raise InputError(
            "config: camera.height/distance and rack levels never make a shelf visible inside the canonical view; "
            "widen the ranges"
        )
    depth = uniform(rng, rc["depth"])
    step = uniform(rng, cc["step"]) * (-1.0 if rng.random() < cc["reverse_probability"] else 1.0)
    cam_z = Z_FRONT - distance
    xs = np.arange(frames, dtype=np.float64) * step + 0.0  # no -0.0
    positions = np.stack([xs, np.full(frames, -cam_h), np.full(frames, cam_z)], axis=1)
    return _Row(levels, thickness, top, depth), Camera(intrinsics, cam_h, distance, step, positions), visible


def sample_row_look(
    rng: np.random.Generator, cfg: dict[str, Any]
) -> tuple[str, dict[str, Any], Material, Material, float]:
    """A row's box-density preset (name and keys), rack and board materials and upright width."""
    rc = cfg["rack"]
    names = sorted(cfg["boxes"]["density"])
    weights = np.array([cfg["boxes"]["density"][k]["weight"] for k in names], np.float64)
    density = names[int(rng.choice(len(weights), p=weights / weights.sum()))]
    rack_material = Material(
        colour(rng, rc["colours"], rc["colour_jitter"]), PATTERNS[choice(rng, rc["textures"])], 0.3, 0.05
    )
    board_material = Material(
        colour(rng, rc["board_colours"], rc["colour_jitter"]), PATTERNS[choice(rng, rc["board_textures"])], 0.05, 1.0
    )
    return density, cfg["boxes"]["density"][density], rack_material, board_material, uniform(rng, rc["upright_width"])


def _sample_row_plan(rng: np.random.Generator, cfg: dict[str, Any], row: _Row, camera: Camera) -> RowPlan:
    """Racks along X covering the view of every frame (the row end may show at either end)."""
    rc = cfg["rack"]
    xs, intrinsics = camera.positions[:, 0], camera.intrinsics
    half_view = (camera.distance + row.depth) * intrinsics.width / (2 * intrinsics.fx)
    x_start = float(xs.min()) - half_view - uniform(rng, [-0.8, 2.0])
    x_end = float(xs.max()) + half_view + uniform(rng, [-0.8, 2.0])
    density, preset, rack_material, board_material, upright_width = sample_row_look(rng, cfg)
    plan = RowPlan(
        row.levels, row.thickness, row.top, row.depth, upright_width, density, preset, rack_material, board_material
    )
    x = x_start
    while x < x_end:
        width = uniform(rng, rc["width"])
        stacks = sample_rack_stacks(
            rng, cfg, preset, x, x + width, Z_FRONT, row.depth, row.levels, row.thickness, row.top, plan.upright_width
        )
        plan.racks.append(RackPlan(f"rack_{len(plan.racks):02d}", x, x + width, stacks))
        gap = uniform(rng, rc["wide_gap"]) if rng.random() < rc["wide_gap_probability"] else uniform(rng, rc["gap"])
        plan.gaps.append((x + width, x + width + gap))
        x += width + gap
    plan.gaps.pop()
    return plan


def _build_row(b: _Builder, plan: RowPlan) -> _Row:
    """The row's racks, boards and boxes as planned (no random draws: a plan builds the same row every time)."""
    row = _Row(plan.levels, plan.thickness, plan.top, plan.depth, plan.upright_width, plan.preset, plan.density)
    rack_mat = b.material(plan.rack_material)
    row.board_mat = b.material(plan.board_material)
    for k, rp in enumerate(plan.racks):
        rack = Rack(rp.id, rp.x_min, rp.x_max, Z_FRONT, plan.depth, b.instance(rp.id, sem.RACK))
        lead = not rp.shared[0] or k == 0 or not plan.racks[k - 1].shared[1]  # a shared frame is built once
        _build_rack_parts(
            b, rack, plan.levels, plan.thickness, plan.top, plan.upright_width, rack_mat, row.board_mat,
            (sem.RACK, sem.SHELF, sem.BOX), True, rp.stacks, shared=rp.shared, frames=(lead, True),
        )  # fmt: skip
        row.racks.append(rack)
    row.gaps = list(plan.gaps)
    return row


def _build_background(
    rng: np.random.Generator, b: _Builder, cfg: dict[str, Any], row: _Row
) -> tuple[bool, list[dict[str, Any]], float]:
    """A bare wall close behind, or a busy warehouse (background racks, props, far wall); props beside the
    row ends either way. Returns (busy, the clutter records, the wall's Z before it makes room)."""
    rc, bgc = cfg["rack"], cfg["background"]
    row_x0, row_x1 = row.racks[0].x_min, row.racks[-1].x_max
    busy = rng.random() < bgc["busy_probability"]
    clutter: list[dict[str, Any]] = []
    back = Z_FRONT + row.depth
    wall_z = back + uniform(rng, bgc["busy_wall_distance"] if busy else bgc["wall_distance"])

    def prop(kind: str, center, size, yaw: float = 0.0) -> None:
        cid = f"clutter_{len(clutter):03d}"
        iid = b.instance(cid, sem.CLUTTER)
        col = colour(rng, cfg["boxes"]["colours"] + rc["board_colours"], 0.15)
        mat = b.material(Material(col, PATTERNS["noise"], 0.05, 0.3))
        b.cuboid(center, size, sem.CLUTTER, iid, mat, yaw)
        clutter.append(
            {"id": cid, "kind": kind, "center": [float(v) for v in center], "size": [float(v) for v in size],
             "yaw": float(yaw), "instance_id": iid}
        )  # fmt: skip

    if busy:
        bz = back + uniform(rng, bgc["background_rack_distance"])
        bdepth = min(uniform(rng, rc["depth"]), max(wall_z - bz - 0.2, 0.3))
        blevels, bthick, btop = sample_levels(rng, cfg)
        bmat = b.material(Material(colour(rng, rc["colours"], rc["colour_jitter"]), PATTERNS["plain"], 0.3, 0.05))
        bx = row_x0 - uniform(rng, [0.0, 2.0])
        while bx < row_x1 + 2.0:
            width = uniform(rng, rc["width"])
            cid = f"clutter_{len(clutter):03d}"
            iid = b.instance(cid, sem.CLUTTER)
            brack = Rack(cid, bx, bx + width, bz, bdepth, iid)
            bstacks = sample_rack_stacks(
                rng, cfg, row.preset, bx, bx + width, bz, bdepth, blevels, bthick, btop, row.upright_width
            )
            _build_rack_parts(
                b, brack, blevels, bthick, btop, row.upright_width, bmat, row.board_mat,
                (sem.CLUTTER, sem.CLUTTER, sem.CLUTTER), False, bstacks, iid,
            )  # fmt: skip
            clutter.append(
                {"id": cid, "kind": "background_rack", "center": [bx + width / 2, -(btop + 0.08) / 2, bz + bdepth / 2],
                 "size": [width, btop + 0.08, bdepth], "yaw": 0.0, "instance_id": iid}
            )  # fmt: skip
            bx += width + uniform(rng, rc["gap"])
        for g0, g1 in row.gaps:
            for _ in range(integer(rng, bgc["props_per_gap"])):
                w, h, d = uniform(rng, [0.3, 1.0]), uniform(rng, [0.2, 1.2]), uniform(rng, [0.3, 0.8])
                zc = back + 0.2 + d / 2 + uniform(rng, [0.0, max(bz - back - 0.4 - d, 0.0)])
                prop(
                    "prop",
                    ((g0 + g1) / 2 + uniform(rng, [-0.5, 0.5]), -h / 2, zc),
                    (w, h, d),
                    uniform(rng, [-0.5, 0.5]),
                )
    for end, sign in ((row_x0, -1.0), (row_x1, 1.0)):
        for _ in range(integer(rng, bgc["end_props"])):
            w, h, d = uniform(rng, [0.4, 1.2]), uniform(rng, [0.15, 1.5]), uniform(rng, [0.4, 1.2])
            xc = end + sign * (0.3 + w / 2 + uniform(rng, [0.0, 2.5]))
            zc = Z_FRONT + 0.2 + d / 2 + uniform(rng, [0.0, max(wall_z - Z_FRONT - 0.5 - d, 0.0)])
            prop("end_prop", (xc, -h / 2, zc), (w, h, d), uniform(rng, [-0.6, 0.6]))
    return busy, clutter, wall_z


def _build_floor_wall(
    rng: np.random.Generator, b: _Builder, cfg: dict[str, Any], row: _Row, camera: Camera, wall_z: float
) -> list[dict[str, Any]]:
    """Floor and back wall: large thin cuboids with procedural textures. Nothing may stand behind
    the wall (the renderer treats it as the farthest surface), so it moves back if needed."""
    far = max(
        p.center[2] + 0.5 * (abs(math.sin(p.yaw)) * p.size[0] + abs(math.cos(p.yaw)) * p.size[2]) for p in b.parts
    )
    wall_z = max(wall_z, far + 0.05)
    fc, wc = cfg["floor"], cfg["wall"]
    xs = camera.positions[:, 0]
    row_x0, row_x1 = row.racks[0].x_min, row.racks[-1].x_max
    span0, span1 = min(row_x0, float(xs.min())) - 40.0, max(row_x1, float(xs.max())) + 40.0
    walls: list[dict[str, Any]] = []
    fid = b.instance("floor", sem.FLOOR)
    fmat = b.material(
        Material(
            colour(rng, fc["colours"], fc["colour_jitter"]),
            PATTERNS[choice(rng, fc["textures"])],
            0.1,
            uniform(rng, [0.5, 1.2]),
        )
    )
    fz0 = (Z_FRONT - camera.distance) - 5.0
    fcenter, fsize = ((span0 + span1) / 2, 0.05, (fz0 + wall_z) / 2), (span1 - span0, 0.1, wall_z - fz0)
    b.cuboid(fcenter, fsize, sem.FLOOR, fid, fmat)
    wid = b.instance("wall_00", sem.WALL)
    wmat = b.material(
        Material(
            colour(rng, wc["colours"], wc["colour_jitter"]),
            PATTERNS[choice(rng, wc["textures"])],
            0.02,
            uniform(rng, [0.8, 1.5]),
        )
    )
    wall_h = 14.0
    wcenter, wsize = ((span0 + span1) / 2, -wall_h / 2, wall_z + 0.05), (span1 - span0, wall_h, 0.1)
    b.cuboid(wcenter, wsize, sem.WALL, wid, wmat)
    for name, iid, c, s in (("floor", fid, fcenter, fsize), ("wall_00", wid, wcenter, wsize)):
        walls.append({"id": name, "kind": name.split("_")[0], "center": list(c), "size": list(s), "instance_id": iid})
    return walls


def _planned_camera(intr: Intrinsics, plan: RowPlan, cam: CameraPlan, frames: int) -> tuple[_Row, Camera, list[int]]:
    visible = visible_levels(intr, cam.height, cam.distance, plan.levels, plan.thickness, plan.top)
    xs = cam.x0 + np.arange(frames, dtype=np.float64) * cam.step + 0.0  # no -0.0
    positions = np.stack([xs, np.full(frames, -cam.height), np.full(frames, Z_FRONT - cam.distance)], axis=1)
    return (
        _Row(plan.levels, plan.thickness, plan.top, plan.depth),
        Camera(intr, cam.height, cam.distance, cam.step, positions),
        visible,
    )


def build_scene(
    rng: np.random.Generator,
    cfg: dict[str, Any],
    intrinsics: Intrinsics,
    frames: int,
    planned: tuple[RowPlan, CameraPlan] | None = None,
    x_extent: float | None = None,
) -> Scene:
    """Sample a whole scene and camera path for one sequence from ``rng`` and the effective config.

    ``planned``: the row and the camera's path given (a pass along a planned rack face); the rest of the
    scene (background, floor, wall, light, sensor, look) is drawn from ``rng`` as for a sampled row.
    ``x_extent``: the layout's width (`LayoutSpec.x_extent`); a sampled camera is then drawn again until a
    level it sees lies inside the canonical view, so that every frame has a shelf slot.
    """
    cc = cfg["camera"]
    b = _Builder()
    if planned is None:
        row, camera, visible = _sample_row_camera(rng, cfg, intrinsics, frames, x_extent)
        plan = _sample_row_plan(rng, cfg, row, camera)
    else:
        plan = planned[0]
        row, camera, visible = _planned_camera(intrinsics, plan, planned[1], frames)
        if not visible:
            raise InputError("a planned pass's camera sees no shelf level; widen camera.height/distance")
    row = _build_row(b, plan)
    busy, clutter, wall_z = _build_background(rng, b, cfg, row)
    walls = _build_floor_wall(rng, b, cfg, row, camera, wall_z)

    xs = camera.positions[:, 0]
    lc, sc = cfg["lighting"], cfg["sensor"]
    light = {
        "position": [
            (float(xs.min()) + float(xs.max())) / 2 + uniform(rng, [-2.0, 2.0]),
            -uniform(rng, lc["light_height"]),
            Z_FRONT - uniform(rng, lc["light_offset_z"]),
        ],
        "ambient": uniform(rng, lc["ambient"]),
        "intensity": uniform(rng, lc["intensity"]),
        "shadow_strength": uniform(rng, lc["shadow_strength"]),
    }
    sensor = {"noise_sigma": uniform(rng, sc["noise_sigma"]), "gain": uniform(rng, sc["gain"])}
    # The camera's rotation is drawn last and only from a range that is not one value (`_u`), so a
    # level config draws nothing and a rotated one keeps the scene the same seed gives a level camera.
    camera.roll_deg, camera.pitch_deg, camera.yaw_deg = (uniform(rng, cc[k]) for k in CAMERA_ANGLE_KEYS)
    # The same for the motion blur: a sharp config draws nothing (nor does a probability of 1).
    sensor["motion_blur"] = draw_motion_blur(rng, sc)
    # And the look (light level, white balance, noise, lens, codec): a neutral config draws nothing.
    look = draw_look(rng, cfg, intrinsics, xs)
    row_record = {
        "z_front": Z_FRONT,
        "depth": row.depth,
        "levels": row.levels,
        "top_height": row.top,
        "board_thickness": row.thickness,
    }
    return Scene(
        row=row_record,
        racks=row.racks,
        camera=camera,
        visible_levels=visible,
        light=light,
        sensor=sensor,
        background="busy" if busy else "wall",
        density=row.density,
        parts=b.parts,
        materials=b.materials,
        clutter=clutter,
        walls=walls,
        instances=b.instances,
        look=look,
    )
