"""Scene model: a rack row with shelves and boxes, background, lighting and a camera path.

Everything is built from one ``numpy.random.Generator`` and the effective config, so a
sequence seed fully determines its scene. World frame (docs/conventions.md): X along the row,
Y down (floor at Y = 0), Z into the racks; the row's front plane is ``Z = 0``. Every renderable
thing is a cuboid `Part` (12 triangles); the racks/shelves/boxes hierarchy is kept beside the
parts for ground truth and ``scene.json``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from layouts.camera import Intrinsics
from layouts.camera_record import CAMERA_ANGLE_KEYS
from layouts.canonical import camera_rotation
from layouts.errors import InputError
from waresynth import semantics as sem

#: Renderer texture patterns by name.
PATTERNS: dict[str, int] = {
    "plain": 0,
    "noise": 1,
    "tape": 2,
    "label": 3,
    "perforated": 4,
    "tiles": 5,
    "bricks": 6,
    "panels": 7,
    "wood": 8,
}

Z_FRONT = 0.0


@dataclass
class Material:
    colour: tuple[float, float, float]  #: linear-ish RGB in [0, 1]
    pattern: int
    reflectance: float = 0.05
    scale: float = 1.0  #: pattern scale in metres (tile size, brick length ...)


@dataclass
class Part:
    """One rendered cuboid: centre, size (width along its own axis, height, depth) and yaw about Y."""

    center: tuple[float, float, float]
    size: tuple[float, float, float]
    yaw: float
    semantic: int
    instance: int
    material: int


@dataclass
class Box:
    id: str
    center: tuple[float, float, float]
    size: tuple[float, float, float]
    yaw: float
    stack_id: str
    stack_level: int
    instance_id: int

    def to_dict(self) -> dict[str, Any]:
        return {
            "id": self.id,
            "center": [float(v) for v in self.center],
            "size": [float(v) for v in self.size],
            "yaw": float(self.yaw),
            "stack_id": self.stack_id,
            "stack_level": self.stack_level,
            "instance_id": self.instance_id,
        }


@dataclass
class Shelf:
    id: str
    level: int
    board_top_y: float
    thickness: float
    clear_height: float
    instance_id: int
    boxes: list[Box] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        return {
            "id": self.id,
            "level": self.level,
            "board_top_y": float(self.board_top_y),
            "thickness": float(self.thickness),
            "clear_height": float(self.clear_height),
            "instance_id": self.instance_id,
            "boxes": [b.to_dict() for b in self.boxes],
        }


@dataclass
class Rack:
    id: str
    x_min: float
    x_max: float
    z_front: float
    depth: float
    instance_id: int
    shelves: list[Shelf] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        return {
            "id": self.id,
            "x_min": float(self.x_min),
            "x_max": float(self.x_max),
            "z_front": float(self.z_front),
            "depth": float(self.depth),
            "instance_id": self.instance_id,
            "shelves": [s.to_dict() for s in self.shelves],
        }


@dataclass
class Camera:
    """A translation along X at fixed height and distance; positions are world (x, y, z).

    The camera keeps one rotation for the whole sequence: ``roll_deg`` about its optical axis,
    ``pitch_deg`` (optical axis up > 0) and ``yaw_deg`` (turned right > 0), the convention of
    `layouts.canonical.camera_rotation`; all 0 (the default) faces the racks square (+Z).
    """

    intrinsics: Intrinsics
    height: float
    distance: float
    step: float
    positions: np.ndarray  #: (N, 3) float64
    roll_deg: float = 0.0
    pitch_deg: float = 0.0
    yaw_deg: float = 0.0

    @property
    def angles(self) -> tuple[float, float, float]:
        """(roll, pitch, yaw) in degrees."""
        return (self.roll_deg, self.pitch_deg, self.yaw_deg)

    @property
    def rotation(self) -> np.ndarray:
        """3x3: the camera's frame in the world's (a camera ray ``d`` is the world ray ``R d``)."""
        return camera_rotation(*self.angles)


@dataclass
class Scene:
    row: dict[str, Any]
    racks: list[Rack]
    camera: Camera
    visible_levels: list[int]
    light: dict[str, float]
    sensor: dict[str, float]
    background: str
    density: str
    parts: list[Part] = field(default_factory=list)
    materials: list[Material] = field(default_factory=list)
    clutter: list[dict[str, Any]] = field(default_factory=list)
    walls: list[dict[str, Any]] = field(default_factory=list)
    instances: list[dict[str, Any]] = field(default_factory=list)

    @property
    def rack_mid_z(self) -> float:
        return self.row["z_front"] + self.row["depth"] / 2

    def to_dict(self) -> dict[str, Any]:
        """The ``scene.json`` content (world frame, Y down, floor Y = 0)."""
        return {
            "row": self.row,
            "racks": [r.to_dict() for r in self.racks],
            "clutter": self.clutter,
            "walls": self.walls,
            "instances": self.instances,
            "light": self.light,
            "background": self.background,
            "density": self.density,
        }


# ----------------------------------------------------------------------------- sampling
def _u(rng: np.random.Generator, r: list[float]) -> float:
    return float(rng.uniform(r[0], r[1])) if r[1] > r[0] else float(r[0])


def _i(rng: np.random.Generator, r: list[int]) -> int:
    return int(rng.integers(int(r[0]), int(r[1]) + 1))


def _colour(rng: np.random.Generator, palette: list[list[float]], jitter: float) -> tuple[float, float, float]:
    base = np.asarray(palette[int(rng.integers(len(palette)))], np.float64) / 255.0
    c = np.clip(base * (1.0 + rng.uniform(-jitter, jitter, 3)), 0.0, 1.0)
    return (float(c[0]), float(c[1]), float(c[2]))


def _choice(rng: np.random.Generator, items: list[str]) -> str:
    return items[int(rng.integers(len(items)))]


def level_visible(intr: Intrinsics, cam_height: float, distance: float, level: float, clear: float) -> bool:
    """Generator rule: the board edge (h = 0) and half the clear height project inside the image rows."""
    for h in (0.0, clear / 2):
        v = intr.cy + intr.fy * (cam_height - level - h) / distance
        if not 0.0 <= v < intr.height:
            return False
    return True


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
def _sample_levels(rng: np.random.Generator, cfg: dict[str, Any]) -> tuple[list[float], float, float]:
    rc = cfg["rack"]
    n = _i(rng, rc["levels"])
    thickness = _u(rng, rc["board_thickness"])
    levels = [_u(rng, rc["first_level"])]
    for _ in range(n - 1):
        levels.append(levels[-1] + _u(rng, rc["spacing"]))
    top = levels[-1] + _u(rng, rc["top_clearance"])
    return levels, thickness, top


def _clear_heights(levels: list[float], thickness: float, top: float) -> list[float]:
    out = []
    for k, lv in enumerate(levels):
        nxt = levels[k + 1] - thickness if k + 1 < len(levels) else top
        out.append(nxt - lv)
    return out


def _place_boxes(
    rng: np.random.Generator,
    b: _Builder,
    cfg: dict[str, Any],
    preset: dict[str, Any],
    shelf: Shelf,
    x_lo: float,
    x_hi: float,
    z_front: float,
    depth: float,
    level: float,
    semantic: int,
    record: bool,
    shared_instance: int,
) -> None:
    """Fill one board left to right with stacks whose yawed footprints stay on the board."""
    bc = cfg["boxes"]
    cursor = x_lo + _u(rng, preset["gap"])
    n_stack = 0
    limit = shelf.clear_height - bc["head_room"]
    while True:
        w, d, h = _u(rng, bc["width"]), _u(rng, bc["depth"]), _u(rng, bc["height"])
        yaw = math.radians(_u(rng, [-bc["yaw_deg"], bc["yaw_deg"]])) if rng.random() < bc["yaw_probability"] else 0.0
        setback = _u(rng, bc["setback"])
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
            cx, cz = cursor + hx, z_front + setback + hz
            stack_id = f"{shelf.id}/stack_{n_stack:03d}"
            colour = _colour(rng, bc["colours"], bc["colour_jitter"])
            pattern = PATTERNS[_choice(rng, bc["textures"])]
            refl = _u(rng, bc["reflectance"])
            mat = b.material(Material(colour, pattern, refl, w))
            for k in range(count):
                bid = f"{shelf.id}/box_{len(shelf.boxes):03d}"
                center = (cx, -(level + (k + 0.5) * h), cz)
                iid = b.instance(bid, semantic) if record else shared_instance
                b.cuboid(center, (w, h, d), semantic, iid, mat, yaw)
                if record:
                    shelf.boxes.append(Box(bid, center, (w, h, d), yaw, stack_id, k, iid))
            n_stack += 1
        cursor += 2 * hx + _u(rng, preset["gap"])


def _build_rack_parts(
    rng: np.random.Generator,
    b: _Builder,
    cfg: dict[str, Any],
    preset: dict[str, Any],
    rack: Rack,
    levels: list[float],
    thickness: float,
    top: float,
    uw: float,
    rack_mat: int,
    board_mat: int,
    semantics: tuple[int, int, int],
    record: bool,
    shared_instance: int = 0,
) -> None:
    """Uprights, top beams, boards and boxes of one rack (the mapped row or a background rack)."""
    rack_sem, shelf_sem, box_sem = semantics
    x0, x1, zf, dp = rack.x_min, rack.x_max, rack.z_front, rack.depth
    beam = 0.08
    height = top + beam
    rid = rack.instance_id if record else shared_instance
    # Uprights stand 3 mm proud of the boards and beams are slimmer, so no two faces are coplanar
    # (coplanar faces would make the semantic/instance ids at their overlap arbitrary).
    proud = 0.003
    for x in (x0 + uw / 2, x1 - uw / 2):
        for z in (zf + uw / 2, zf + dp - uw / 2):
            b.cuboid((x, -height / 2, z), (uw + 2 * proud, height, uw + 2 * proud), rack_sem, rid, rack_mat)
    for z in (zf + uw / 2, zf + dp - uw / 2):
        b.cuboid(((x0 + x1) / 2, -(top + beam / 2), z), (x1 - x0 - 2 * uw, beam, uw * 0.8), rack_sem, rid, rack_mat)
    clears = _clear_heights(levels, thickness, top)
    for k, (lv, ch) in enumerate(zip(levels, clears)):
        sid = f"{rack.id}/shelf_{k:02d}"
        iid = b.instance(sid, shelf_sem) if record else shared_instance
        shelf = Shelf(sid, k, -lv, thickness, ch, iid)
        b.cuboid(
            ((x0 + x1) / 2, -(lv - thickness / 2), zf + dp / 2), (x1 - x0, thickness, dp), shelf_sem, iid, board_mat
        )
        _place_boxes(
            rng, b, cfg, preset, shelf, x0 + uw + 0.03, x1 - uw - 0.03, zf, dp, lv, box_sem,
            record, shared_instance,
        )  # fmt: skip
        if record:
            rack.shelves.append(shelf)


def build_scene(rng: np.random.Generator, cfg: dict[str, Any], intrinsics: Intrinsics, frames: int) -> Scene:
    """Sample a whole scene and camera path for one sequence from ``rng`` and the effective config."""
    cc, rc, bgc = cfg["camera"], cfg["rack"], cfg["background"]
    b = _Builder()

    # Row heights (shared by every rack of the row) and a camera that sees 1..R of them.
    for _ in range(200):
        levels, thickness, top = _sample_levels(rng, cfg)
        clears = _clear_heights(levels, thickness, top)
        distance = _u(rng, cc["distance"])
        cam_h = _u(rng, cc["height"])
        visible = [k for k in range(len(levels)) if level_visible(intrinsics, cam_h, distance, levels[k], clears[k])]
        if visible:
            break
    else:
        raise InputError("config: camera.height/distance and rack levels never make a shelf visible; widen the ranges")
    depth = _u(rng, rc["depth"])
    step = _u(rng, cc["step"]) * (-1.0 if rng.random() < cc["reverse_probability"] else 1.0)
    cam_z = Z_FRONT - distance
    xs = np.arange(frames, dtype=np.float64) * step + 0.0  # no -0.0
    positions = np.stack([xs, np.full(frames, -cam_h), np.full(frames, cam_z)], axis=1)
    camera = Camera(intrinsics, cam_h, distance, step, positions)

    # Racks along X covering the view of every frame (the row end may show at either end).
    half_view = (distance + depth) * intrinsics.width / (2 * intrinsics.fx)
    x_start = float(xs.min()) - half_view - _u(rng, [-0.8, 2.0])
    x_end = float(xs.max()) + half_view + _u(rng, [-0.8, 2.0])
    weights = np.array([cfg["boxes"]["density"][k]["weight"] for k in sorted(cfg["boxes"]["density"])], np.float64)
    density = sorted(cfg["boxes"]["density"])[int(rng.choice(len(weights), p=weights / weights.sum()))]
    preset = cfg["boxes"]["density"][density]
    rack_colour = _colour(rng, rc["colours"], rc["colour_jitter"])
    rack_mat = b.material(Material(rack_colour, PATTERNS[_choice(rng, rc["textures"])], 0.3, 0.05))
    board_mat = b.material(
        Material(_colour(rng, rc["board_colours"], rc["colour_jitter"]), PATTERNS["wood"], 0.05, 1.0)
    )
    uw = _u(rng, rc["upright_width"])
    racks: list[Rack] = []
    gaps: list[tuple[float, float]] = []
    x = x_start
    while x < x_end:
        width = _u(rng, rc["width"])
        rid = f"rack_{len(racks):02d}"
        rack = Rack(rid, x, x + width, Z_FRONT, depth, b.instance(rid, sem.RACK))
        _build_rack_parts(
            rng, b, cfg, preset, rack, levels, thickness, top, uw, rack_mat, board_mat,
            (sem.RACK, sem.SHELF, sem.BOX), True,
        )  # fmt: skip
        racks.append(rack)
        gap = _u(rng, rc["wide_gap"]) if rng.random() < rc["wide_gap_probability"] else _u(rng, rc["gap"])
        gaps.append((x + width, x + width + gap))
        x += width + gap
    gaps.pop()
    row_x0, row_x1 = racks[0].x_min, racks[-1].x_max
    row = {"z_front": Z_FRONT, "depth": depth, "levels": levels, "top_height": top, "board_thickness": thickness}

    # Background: a bare wall close behind, or a busy warehouse (background racks, props, far wall).
    busy = rng.random() < bgc["busy_probability"]
    clutter: list[dict[str, Any]] = []
    back = Z_FRONT + depth
    wall_z = back + _u(rng, bgc["busy_wall_distance"] if busy else bgc["wall_distance"])

    def prop(kind: str, center, size, yaw: float = 0.0) -> None:
        cid = f"clutter_{len(clutter):03d}"
        iid = b.instance(cid, sem.CLUTTER)
        col = _colour(rng, cfg["boxes"]["colours"] + rc["board_colours"], 0.15)
        mat = b.material(Material(col, PATTERNS["noise"], 0.05, 0.3))
        b.cuboid(center, size, sem.CLUTTER, iid, mat, yaw)
        clutter.append(
            {"id": cid, "kind": kind, "center": [float(v) for v in center], "size": [float(v) for v in size],
             "yaw": float(yaw), "instance_id": iid}
        )  # fmt: skip

    if busy:
        bz = back + _u(rng, bgc["background_rack_distance"])
        bdepth = min(_u(rng, rc["depth"]), max(wall_z - bz - 0.2, 0.3))
        blevels, bthick, btop = _sample_levels(rng, cfg)
        bmat = b.material(Material(_colour(rng, rc["colours"], rc["colour_jitter"]), PATTERNS["plain"], 0.3, 0.05))
        bx = row_x0 - _u(rng, [0.0, 2.0])
        while bx < row_x1 + 2.0:
            width = _u(rng, rc["width"])
            cid = f"clutter_{len(clutter):03d}"
            iid = b.instance(cid, sem.CLUTTER)
            brack = Rack(cid, bx, bx + width, bz, bdepth, iid)
            _build_rack_parts(
                rng, b, cfg, preset, brack, blevels, bthick, btop, uw, bmat, board_mat,
                (sem.CLUTTER, sem.CLUTTER, sem.CLUTTER), False, iid,
            )  # fmt: skip
            clutter.append(
                {"id": cid, "kind": "background_rack", "center": [bx + width / 2, -(btop + 0.08) / 2, bz + bdepth / 2],
                 "size": [width, btop + 0.08, bdepth], "yaw": 0.0, "instance_id": iid}
            )  # fmt: skip
            bx += width + _u(rng, rc["gap"])
        for g0, g1 in gaps:
            for _ in range(_i(rng, bgc["props_per_gap"])):
                w, h, d = _u(rng, [0.3, 1.0]), _u(rng, [0.2, 1.2]), _u(rng, [0.3, 0.8])
                zc = back + 0.2 + d / 2 + _u(rng, [0.0, max(bz - back - 0.4 - d, 0.0)])
                prop("prop", ((g0 + g1) / 2 + _u(rng, [-0.5, 0.5]), -h / 2, zc), (w, h, d), _u(rng, [-0.5, 0.5]))
    for end, sign in ((row_x0, -1.0), (row_x1, 1.0)):
        for _ in range(_i(rng, bgc["end_props"])):
            w, h, d = _u(rng, [0.4, 1.2]), _u(rng, [0.15, 1.5]), _u(rng, [0.4, 1.2])
            xc = end + sign * (0.3 + w / 2 + _u(rng, [0.0, 2.5]))
            zc = Z_FRONT + 0.2 + d / 2 + _u(rng, [0.0, max(wall_z - Z_FRONT - 0.5 - d, 0.0)])
            prop("end_prop", (xc, -h / 2, zc), (w, h, d), _u(rng, [-0.6, 0.6]))

    # Floor and back wall: large thin cuboids with procedural textures. Nothing may stand behind
    # the wall (the renderer treats it as the farthest surface), so it moves back if needed.
    far = max(
        p.center[2] + 0.5 * (abs(math.sin(p.yaw)) * p.size[0] + abs(math.cos(p.yaw)) * p.size[2]) for p in b.parts
    )
    wall_z = max(wall_z, far + 0.05)
    fc, wc = cfg["floor"], cfg["wall"]
    span0, span1 = min(row_x0, float(xs.min())) - 40.0, max(row_x1, float(xs.max())) + 40.0
    walls: list[dict[str, Any]] = []
    fid = b.instance("floor", sem.FLOOR)
    fmat = b.material(
        Material(
            _colour(rng, fc["colours"], fc["colour_jitter"]),
            PATTERNS[_choice(rng, fc["textures"])],
            0.1,
            _u(rng, [0.5, 1.2]),
        )
    )
    fz0 = cam_z - 5.0
    fcenter, fsize = ((span0 + span1) / 2, 0.05, (fz0 + wall_z) / 2), (span1 - span0, 0.1, wall_z - fz0)
    b.cuboid(fcenter, fsize, sem.FLOOR, fid, fmat)
    wid = b.instance("wall_00", sem.WALL)
    wmat = b.material(
        Material(
            _colour(rng, wc["colours"], wc["colour_jitter"]),
            PATTERNS[_choice(rng, wc["textures"])],
            0.02,
            _u(rng, [0.8, 1.5]),
        )
    )
    wall_h = 14.0
    wcenter, wsize = ((span0 + span1) / 2, -wall_h / 2, wall_z + 0.05), (span1 - span0, wall_h, 0.1)
    b.cuboid(wcenter, wsize, sem.WALL, wid, wmat)
    for name, iid, c, s in (("floor", fid, fcenter, fsize), ("wall_00", wid, wcenter, wsize)):
        walls.append({"id": name, "kind": name.split("_")[0], "center": list(c), "size": list(s), "instance_id": iid})

    lc, sc = cfg["lighting"], cfg["sensor"]
    light = {
        "position": [
            (float(xs.min()) + float(xs.max())) / 2 + _u(rng, [-2.0, 2.0]),
            -_u(rng, lc["light_height"]),
            Z_FRONT - _u(rng, lc["light_offset_z"]),
        ],
        "ambient": _u(rng, lc["ambient"]),
        "intensity": _u(rng, lc["intensity"]),
        "shadow_strength": _u(rng, lc["shadow_strength"]),
    }
    sensor = {"noise_sigma": _u(rng, sc["noise_sigma"]), "gain": _u(rng, sc["gain"])}
    # The camera's rotation is drawn last and only from a range that is not one value (`_u`), so a
    # level config draws nothing and a rotated one keeps the scene the same seed gives a level camera.
    camera.roll_deg, camera.pitch_deg, camera.yaw_deg = (_u(rng, cc[k]) for k in CAMERA_ANGLE_KEYS)
    # The same for the motion blur: a sharp config draws nothing.
    sensor["motion_blur"] = _u(rng, sc["motion_blur"])
    return Scene(
        row=row,
        racks=racks,
        camera=camera,
        visible_levels=visible,
        light=light,
        sensor=sensor,
        background="busy" if busy else "wall",
        density=density,
        parts=b.parts,
        materials=b.materials,
        clutter=clutter,
        walls=walls,
        instances=b.instances,
    )
