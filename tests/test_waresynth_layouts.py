"""Ground-truth layouts agree with the rendered images and with the scene's geometry."""

from __future__ import annotations

import math

import numpy as np

from layouts.classes import BOX
from layouts.raster import fill_rect
from waresynth import semantics
from waresynth.dataset import open_dataset


def _front_z(box: dict, x: np.ndarray) -> np.ndarray:
    """Z of the yawed footprint's near (camera-facing) side at world X (NaN outside it)."""
    cx, _, cz = box["center"]
    w, _, d = box["size"]
    c, s = math.cos(box["yaw"]), math.sin(box["yaw"])
    corners = [
        (cx + c * u - s * v, cz + s * u + c * v)
        for u, v in ((-w / 2, -d / 2), (w / 2, -d / 2), (w / 2, d / 2), (-w / 2, d / 2))
    ]
    z = np.full(x.shape, np.inf)
    for (x0, z0), (x1, z1) in zip(corners, corners[1:] + corners[:1]):
        lo, hi = min(x0, x1), max(x0, x1)
        if hi - lo < 1e-12:
            continue
        inside = (x >= lo) & (x <= hi)
        zz = z0 + (x - x0) * (z1 - z0) / (x1 - x0)
        z = np.where(inside, np.minimum(z, zz), z)
    return np.where(np.isfinite(z), z, np.nan)


def box_projection_agreement(seq) -> tuple[int, int]:
    """(hits, total): front-view box pixels in visible columns, projected onto the box front, landing on BOX."""
    spec, intr = seq.spec, seq.intrinsics
    scene = seq.scene()
    xs_cell, hs_cell = spec.cell_centres("front")
    hits = total = 0
    for i in range(seq.num_frames):
        rec, lay, sem = seq.frame(i), seq.layouts(i), seq.semantic(i)
        cam = np.array(rec["camera_position"])
        for r, slot in enumerate(rec["slots"]):
            rows, cols = np.nonzero((lay.front[r] == BOX) & lay.visible[None, :])
            if not len(rows):
                continue
            x = xs_cell[cols] + cam[0]
            y = slot["board_top_y"] - hs_cell[rows]
            z = np.full(x.shape, np.nan)
            for rack in scene["racks"]:
                for box in rack["shelves"][slot["level"]]["boxes"]:
                    top = box["center"][1] - box["size"][1] / 2
                    zb = _front_z(box, x)
                    zb = np.where((y >= top - 1e-6) & (y <= slot["board_top_y"] + 1e-6), zb, np.nan)
                    z = np.where(np.isnan(z), zb, np.fmin(z, zb))
            assert not np.isnan(z).any(), "a front-view box pixel has no box behind it in scene.json"
            uv = intr.project(np.stack([x - cam[0], y - cam[1], z - cam[2]], 1))
            u, v = np.floor(uv[:, 0]).astype(int), np.floor(uv[:, 1]).astype(int)
            inside = (u >= 0) & (u < intr.width) & (v >= 0) & (v < intr.height)
            hits += int((sem[v[inside], u[inside]] == semantics.BOX).sum())
            total += int(inside.sum())
    return hits, total


def test_front_box_pixels_land_on_box_pixels(tiny_dataset):
    ds = open_dataset(tiny_dataset)
    hits = total = 0
    for seq in ds.sequences():
        h, t = box_projection_agreement(seq)
        hits, total = hits + h, total + t
    assert total > 200, "the tiny dataset should show boxes"
    assert hits / total >= 0.95, f"only {hits}/{total} front-view box pixels land on box pixels"


def test_top_view_boxes_inside_shelf_region(tiny_dataset):
    ds = open_dataset(tiny_dataset)
    n_box = 0
    for seq in ds.sequences():
        spec, scene = seq.spec, seq.scene()
        for rack in scene["racks"]:
            x0, x1, zf, dp = rack["x_min"], rack["x_max"], rack["z_front"], rack["depth"]
            for shelf in rack["shelves"]:
                for box in shelf["boxes"]:
                    cx, _, cz = box["center"]
                    w, _, d = box["size"]
                    c, s = math.cos(box["yaw"]), math.sin(box["yaw"])
                    for u, v in ((-w / 2, -d / 2), (w / 2, -d / 2), (w / 2, d / 2), (-w / 2, d / 2)):
                        assert x0 <= cx + c * u - s * v <= x1 and zf <= cz + s * u + c * v <= zf + dp, box["id"]
        for i in range(seq.num_frames):
            rec, lay = seq.frame(i), seq.layouts(i)
            cam_x = rec["camera_position"][0]
            region = np.zeros((spec.size, spec.size), np.uint8)
            for rack in scene["racks"]:
                centre = (
                    (rack["x_min"] + rack["x_max"]) / 2 - cam_x,
                    rack["z_front"] + rack["depth"] / 2 - rec["rack_mid_z"],
                )
                fill_rect(region, spec, "top", centre, (rack["x_max"] - rack["x_min"], rack["depth"]), 1)
            for r in range(len(rec["slots"])):
                boxes = lay.top[r] == BOX
                n_box += int(boxes.sum())
                assert region[boxes].all(), f"{seq.name} frame {i} slot {r}: box pixels outside the shelf region"
                assert np.array_equal(lay.top[r] != 0, region == 1)
            assert not lay.top[len(rec["slots"]) :].any() and not lay.front[len(rec["slots"]) :].any()
    assert n_box > 0


def test_frame_records_match_layouts(tiny_dataset):
    ds = open_dataset(tiny_dataset)
    for seq in ds.sequences():
        spec = seq.spec
        for i in range(seq.num_frames):
            rec, lay = seq.frame(i), seq.layouts(i)
            assert 1 <= len(rec["slots"]) <= spec.num_slots
            levels = [s["level"] for s in rec["slots"]]
            assert levels == sorted(levels)
            assert math.isclose(rec["visible_fraction"], float(lay.visible.mean()))
            assert np.array_equal(lay.visible, seq.intrinsics.visible_columns(spec, rec["distance"]))
            for r, slot in enumerate(rec["slots"]):
                # Shelf window height in the front view follows the clear height (clipped at h_extent).
                col = (lay.front[r] != 0).sum(0)
                expect = min(slot["clear_height"], spec.h_extent) / spec.pixel_size("front")[1]
                assert abs(col.max() - expect) <= 1.0


def test_box_pixels_lie_on_their_scene_cuboid(tiny_dataset):
    """Depth + instance images back-project onto the cuboid scene.json gives each box (yaw convention)."""
    ds = open_dataset(tiny_dataset)
    checked = yawed = 0
    for seq in ds.sequences():
        intr = seq.intrinsics
        boxes = {b["instance_id"]: b for r in seq.scene()["racks"] for s in r["shelves"] for b in s["boxes"]}
        for i in range(0, seq.num_frames, 3):
            cam = np.array(seq.frame(i)["camera_position"])
            depth, inst = seq.depth(i), seq.instance(i)
            v, u = np.nonzero(np.isin(inst, list(boxes)))
            z = depth[v, u].astype(np.float64)
            pts = np.stack([(u + 0.5 - intr.cx) / intr.fx * z, (v + 0.5 - intr.cy) / intr.fy * z, z], 1) + cam
            for iid in np.unique(inst[v, u]):
                b = boxes[int(iid)]
                q = pts[inst[v, u] == iid] - np.array(b["center"])
                c, s = math.cos(b["yaw"]), math.sin(b["yaw"])
                local = np.stack([c * q[:, 0] + s * q[:, 2], q[:, 1], -s * q[:, 0] + c * q[:, 2]], 1)
                half = np.array(b["size"]) / 2
                inside = (np.abs(local) <= half + 0.006).all(1)
                on_face = (np.abs(np.abs(local) - half) <= 0.006).any(1)
                assert (inside & on_face).mean() >= 0.97, b["id"]
                checked += 1
                yawed += abs(b["yaw"]) > 0.05
    assert checked > 20 and yawed > 0
