"""Depth-projection baseline: what *seeing* alone gives, with perfect depth and masks.

In the spirit of the PseudoLidar / MaskRCNN-GTdepth rows of the paper, it turns a frame's
ground-truth depth and semantic masks into shelf-centric layouts without any amodal
reasoning: only surfaces the camera sees are placed. The shelf geometry it needs (board heights
and clear heights of the visible slots, the rack's mid-depth and front plane) comes from the
frame's ground-truth record, so the comparison isolates visibility.

Top view (per slot r, on the board plane)
    Back-project every pixel. Board-top points (semantic shelf, within 3 cm of the board
    top) mark *shelf*; box points whose height above the board lies in the slot's clear height
    mark *box* (box tops and front faces). A 3x3 closing per class fills sampling holes only.
Front view (per slot r, on the rack's front plane)
    Each cell centre ``(x, h)`` on the front plane is projected into the image. If the pixel
    sees a box face within the rack's depth at about the cell's height (5 cm) -> *box*; otherwise,
    if a shelf board exists at that X (the board's front edge just below ``h = 0`` is seen as
    shelf) and ``h`` is within the clear height -> *shelf*.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from layouts.camera import Intrinsics
from layouts.classes import BOX, SHELF
from layouts.codecs import FrameLayouts
from layouts.errors import InputError
from layouts.spec import LayoutSpec

SEM_SHELF = 4  # waresynth.semantics.SHELF (boards of the mapped row)
SEM_BOX = 5  # waresynth.semantics.BOX (boxes on the mapped row)
BOARD_TOL = 0.03  #: metres: points this close to a board top count as the board surface
FACE_TOL = 0.05  #: metres: a box hit counts for a front cell when at about the cell's height
EDGE_PROBE = 0.015  #: metres below the board top where the board's front edge is probed


def _check(depth: np.ndarray, semantic: np.ndarray, k: Intrinsics) -> None:
    if depth.shape != (k.height, k.width) or semantic.shape != depth.shape:
        raise InputError(
            f"depth {depth.shape} and semantic {semantic.shape} must both be (H, W) = ({k.height}, {k.width})"
        )
    if not np.isfinite(depth).all():
        raise InputError("depth contains NaN or infinity (use 0 for no hit)")


def depth_projection_layouts(
    depth: np.ndarray,
    semantic: np.ndarray,
    intrinsics: Intrinsics,
    frame: dict,
    z_front: float,
    spec: LayoutSpec,
) -> FrameLayouts:
    """Layouts of one frame from metric Z-depth (0 = no hit) and semantic ids.

    ``frame`` is the generator's per-frame record (camera_position, rack_mid_z, slots);
    ``z_front`` the world Z of the rack row's front plane.
    """
    depth = np.asarray(depth, np.float64)
    semantic = np.asarray(semantic)
    _check(depth, semantic, intrinsics)
    k = intrinsics
    cam = np.asarray(frame["camera_position"], np.float64)
    mid_z = float(frame["rack_mid_z"])
    top = np.zeros(spec.shape, np.uint8)
    front = np.zeros(spec.shape, np.uint8)
    d = spec.size

    # ---- back-projected points (top view)
    v, u = np.nonzero(depth > 0)
    zc = depth[v, u]
    xc = (u + 0.5 - k.cx) * zc / k.fx
    yc = (v + 0.5 - k.cy) * zc / k.fy
    wy = yc + cam[1]
    sz = zc + cam[2] - mid_z  # shelf-centric Z
    sem = semantic[v, u]
    col = np.floor(spec.x_to_col(xc)).astype(np.int64)
    row = np.floor(spec.a_to_row("top", sz)).astype(np.int64)
    inside = (col >= 0) & (col < d) & (row >= 0) & (row < d)
    for r, slot in enumerate(frame["slots"][: spec.num_slots]):
        h = float(slot["board_top_y"]) - wy
        clear = float(slot["clear_height"])
        board = inside & (sem == SEM_SHELF) & (np.abs(h) < BOARD_TOL)
        boxes = inside & (sem == SEM_BOX) & (h > 0) & (h < clear)
        shelf_mask = np.zeros((d, d), bool)
        box_mask = np.zeros((d, d), bool)
        shelf_mask[row[board], col[board]] = True
        box_mask[row[boxes], col[boxes]] = True
        shelf_mask = ndimage.binary_closing(shelf_mask, np.ones((3, 3), bool))
        box_mask = ndimage.binary_closing(box_mask, np.ones((3, 3), bool))
        top[r][shelf_mask] = SHELF
        top[r][box_mask] = BOX

    # ---- front-plane sampling (front view)
    xs, hs = spec.cell_centres("front")
    dz = z_front - cam[2]
    if dz <= 0:
        raise InputError(f"rack front z={z_front} is not in front of the camera (camera z={cam[2]})")
    pu = np.floor(k.fx * xs / dz + k.cx).astype(np.int64)
    colvis = (pu >= 0) & (pu < k.width)
    pu_c = np.clip(pu, 0, k.width - 1)
    depth_back = 2 * (mid_z - z_front)  # rack depth
    for r, slot in enumerate(frame["slots"][: spec.num_slots]):
        by = float(slot["board_top_y"])
        clear = float(slot["clear_height"])
        # Board present at X: its front edge, just below the top surface, is seen as shelf.
        ev = np.floor(k.fy * (by + EDGE_PROBE - cam[1]) / dz + k.cy).astype(np.int64)
        if not 0 <= ev < k.height:
            continue
        has_board = colvis & (semantic[ev, pu_c] == SEM_SHELF)
        wy_cells = by - hs  # world Y of each row's cell centre
        pv = np.floor(k.fy * (wy_cells - cam[1]) / dz + k.cy).astype(np.int64)
        rowvis = (pv >= 0) & (pv < k.height)
        pv_c = np.clip(pv, 0, k.height - 1)
        S = semantic[pv_c[:, None], pu_c[None, :]]
        Z = depth[pv_c[:, None], pu_c[None, :]]
        seen = rowvis[:, None] & colvis[None, :]
        hit_h = by - (pv_c[:, None] + 0.5 - k.cy) * Z / k.fy - cam[1]
        in_window = (hs > 0) & (hs <= clear)
        box = seen & (S == SEM_BOX) & (Z > 0) & (Z <= dz + depth_back) & (np.abs(hit_h - hs[:, None]) < FACE_TOL)
        shelf = seen & in_window[:, None] & has_board[None, :]
        front[r][shelf] = SHELF
        front[r][box & in_window[:, None]] = BOX
    vis = k.visible_columns(spec, dz)
    return FrameLayouts(top, front, vis)


def evaluate_depth_projection(sequences: list, max_frames: int | None = None, progress: bool = True) -> dict:
    """``{"all": table, "visible": table, "frames": n}`` of the baseline over ``sequences``."""
    from tqdm import tqdm

    from layouts.metrics import FrameScorer
    from waresynth.dataset import require_level_camera

    scorer = FrameScorer()
    total = sum(s.num_frames if not max_frames else min(s.num_frames, max_frames) for s in sequences)
    frames = 0
    with tqdm(total=total, desc="depth projection", unit="frame", disable=not progress, leave=False) as bar:
        for seq in sequences:
            require_level_camera(seq, "the depth-projection baseline")  # it back-projects a level camera's depth
            z_front = float(seq.scene()["row"]["z_front"])
            n = seq.num_frames if not max_frames else min(seq.num_frames, max_frames)
            for i in range(n):
                got = depth_projection_layouts(
                    seq.depth(i), seq.semantic(i), seq.intrinsics, seq.frame(i), z_front, seq.spec
                )
                scorer.update({"top": got.top, "front": got.front}, seq.layouts(i))
                frames += 1
                bar.update(1)
    return {**scorer.result(), "frames": frames}
