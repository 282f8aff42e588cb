"""A building's ground truth: every rack, shelf and box in the building frame with its location code
(``building.json``), and one inventory row per location (``inventory.csv``).

A location is one position of one level of one bay of one face: its code is the building config's ``code``
format (default ``{aisle:02d}-{side}-{bay:02d}-{level:02d}``, e.g. ``01-L-03-02``), levels counted from 1 at
the floor, positions from 1 along +X (a level's usable length cut in ``positions`` equal parts; a box belongs
to the position holding its stack's centre). Codes come from the rack positions alone, never from what a pass
saw, so they are the same in every scan. Each rack records its span (its location column: its own uprights
whole, half of a frame it shares, `waresynth.building.rack_build`) and its two upright frames' X ranges (``uprights``);
``racking`` lists each face's build and every upright frame along it once, lowest X first.
"""

from __future__ import annotations

import math
from typing import Any

from layouts.locations import covered_length, location_code
from waresynth.building.plan import Building, Face
from waresynth.row_plan import RackPlan, clear_heights


def board_positions(face: Face, rack: RackPlan, n: int) -> tuple[float, float]:
    """(building X where the rack's usable board starts, one position's length) for ``n`` positions."""
    lo, hi = rack.board_span(face.row.upright_width)
    b0, b1 = sorted((face.sign * lo, face.sign * hi))
    return b0, (b1 - b0) / n


def position_of(b0: float, cut: float, n: int, x: float) -> int:
    """The position (from 0) holding building X ``x`` (clamped to the board's ``n`` positions)."""
    return min(n - 1, max(0, int((x - b0) // cut)))


def box_id(location: str, stack: int, stack_level: int) -> str:
    """A box's ground-truth id: its location, its stack's index on the board and its level in the stack."""
    return f"{location}/stack_{stack:03d}/box_{stack_level}"


def _r(v: float) -> float:
    return round(float(v), 6) + 0.0


def upright_frames(face: Face, rack: RackPlan) -> list[list[float]]:
    """The building X ranges of a rack's two upright frames, lowest X first."""
    half, out = face.row.upright_width / 2, []
    for c in rack.upright_centres(face.row.upright_width):
        lo, hi = sorted((face.sign * (c - half), face.sign * (c + half)))
        out.append([_r(lo), _r(hi)])
    return sorted(out)


def face_racking(face: Face) -> dict[str, Any]:
    """A face's ``racking`` record: its aisle, side, build and every upright frame along it once (X ranges)."""
    frames = sorted({tuple(f) for rack in face.row.racks for f in upright_frames(face, rack)})
    return {"aisle": face.aisle, "side": face.side, "build": face.build, "uprights": [list(f) for f in frames]}


def _seen_by(building: Building, k: int) -> dict[tuple[int, int], list[str]]:
    """(bay, level from 0) of face ``k`` -> the passes whose layouts hold it, in route order."""
    seen: dict[tuple[int, int], list[str]] = {}
    for p in building.passes:
        if p.face == k:
            for b in p.bays:
                for lv in p.levels:
                    seen.setdefault((b, lv), []).append(p.name)
    return seen


def _shelf_locations(building: Building, face: Face, bay: int, rack: RackPlan, k: int, seen: dict) -> dict[str, Any]:
    """One level of one bay: its board, positions (each a location) and boxes, in the building frame."""
    cfg, row = building.config, face.row
    clear = clear_heights(row.levels, row.thickness, row.top)[k]
    n = cfg["positions"]
    b0, cut = board_positions(face, rack, n)
    passes = seen.get((bay, k), [])
    positions = []
    for j in range(n):
        code = location_code(cfg["code"], face.aisle, face.side, bay, k + 1, j + 1)
        positions.append({"location": code, "position": j + 1, "x_min": _r(b0 + j * cut), "x_max": _r(b0 + (j + 1) * cut),
                          "boxes": [], "_stacks": []})  # fmt: skip
    level_y = row.levels[k]
    for s, st in enumerate(rack.stacks[k]):
        x, _, z = face.to_building(st.x, 0.0, st.z)
        j = position_of(b0, cut, n, x)
        w, h, d = st.size
        c, sn = abs(math.cos(st.yaw)), abs(math.sin(st.yaw))
        positions[j]["_stacks"].append(
            (x - 0.5 * (c * w + sn * d), x + 0.5 * (c * w + sn * d), w * d, w * d * h * st.count)
        )
        for lvl in range(st.count):
            positions[j]["boxes"].append({
                "id": box_id(positions[j]["location"], s, lvl),
                "scene_id": f"{rack.id}/shelf_{k:02d}/box_{sum(t.count for t in rack.stacks[k][:s]) + lvl:03d}",
                "center": [_r(x), _r(-(level_y + (lvl + 0.5) * h)), _r(z)],
                "size": [_r(w), _r(h), _r(d)],
                "yaw": _r(st.yaw),
                "stack": s,
                "stack_level": lvl,
            })  # fmt: skip
    for pos in positions:
        pos["_row"] = {"length": pos["x_max"] - pos["x_min"], "depth": row.depth, "clear": clear, "passes": passes}
    return {"level": k + 1, "board_top_y": _r(-level_y), "clear_height": _r(clear), "positions": positions}


def ground_truth(building: Building) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    """(``building.json``'s content, the inventory rows): racks -> levels -> positions -> boxes."""
    racks, rows = [], []
    for k, face in enumerate(building.faces):
        seen = _seen_by(building, k)
        by_id = {r.id: r for r in face.row.racks}
        for bay, (x0, x1) in enumerate(face.bays, start=1):
            rack = by_id[f"rack_{bay:02d}"]
            z0, z1 = sorted((face.front_z, face.front_z + face.sign * face.row.depth))
            levels = [_shelf_locations(building, face, bay, rack, lv, seen) for lv in range(len(face.row.levels))]
            for level in levels:
                for pos in level["positions"]:
                    rows.append(_inventory_row(face, bay, level["level"], pos))
            racks.append({
                "id": f"{face.aisle:02d}-{face.side}-{bay:02d}",
                "aisle": face.aisle, "side": face.side, "bay": bay, "x_min": _r(x0), "x_max": _r(x1),
                "z_min": _r(z0), "z_max": _r(z1), "height": _r(face.row.top + 0.08), "scene_id": rack.id,
                "uprights": upright_frames(face, rack), "levels": levels,
            })  # fmt: skip
    doc = {
        "frame": "building: metres, X along the aisles, Y down (floor 0), Z across",
        "code": building.config["code"],
        "aisles": building.aisles,
        "racks": racks,
        "racking": [face_racking(f) for f in building.faces],
    }
    return doc, rows


def _inventory_row(face: Face, bay: int, level: int, pos: dict[str, Any]) -> dict[str, Any]:
    """One location's inventory row (ground truth: confidence 1, never partial); drops the working keys."""
    stacks, facts = pos.pop("_stacks"), pos.pop("_row")
    length, depth, clear = facts["length"], facts["depth"], facts["clear"]
    covered = covered_length([(a, b) for a, b, _, _ in stacks], pos["x_min"], pos["x_max"])
    passes = facts["passes"]
    return {
        "location": pos["location"], "aisle": face.aisle, "side": face.side, "bay": bay, "level": level,
        "position": pos["position"], "boxes": len(stacks),
        "occupancy": round(covered / length, 4) if length > 0 else 0.0,
        "free_length_m": round(max(length - covered, 0.0), 4),
        "free_area_m2": round(max(length * depth - sum(s[2] for s in stacks), 0.0), 4),
        "free_volume_m3": round(max(length * depth * clear - sum(s[3] for s in stacks), 0.0), 4),
        "partial": "false", "confidence": 1, "last_seen": passes[-1] if passes else "", "pass": ";".join(passes),
    }  # fmt: skip
