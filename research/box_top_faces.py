#!/usr/bin/env python3
"""What reading each box's depth from its own top face could buy the top view, and what any face could.

    .venv/bin/python research/box_top_faces.py mvracklay/models/mvracklay-disc-4-256.pt data/heldout256 [--every 2]

A box whose top lies below the camera shows its top face in the canonical view (`layouts.canonical`)
between two horizontal edges: the front edge, at its front, and the back edge, at its back ``Z``
behind the rack front. On the front plane a point ``h`` metres above the board, ``Z`` behind the
front, appears at height ``c - (c - h) * d / (d + Z)`` (``c``: the camera's height above the board,
``d``: its distance to the rack front), so the two edges' rows give the box's depth, as the boards'
back edges give the rack's (`network.heads.backedge`). The rows are few: a box top 0.5 m below the camera
shows a face 4-10 cm tall on the front plane for boxes 0.25-0.7 m deep.

Runs the model (streaming, its own rack-depth reading and row-head anchors) over every sequence and
scores the top view (Table I mIoU, columns in view) of:

* **prediction** as it is;
* **true depth where the top face shows**: every predicted box (connected box cells) whose top the
  front view puts at least ``--min-below`` under the camera and whose top face the board above does
  not hide gets the true depth (its back row moved to the truth's; X and front kept): the ceiling
  of any single-frame top-face reader on these predictions;
* **read from the true edges**: the same boxes' depth decoded from the true top-face edges
  (drawn as the targets a detector would be fitted to, from scene.json and the camera), by the
  geometry above: per column, the box top height (within +-8 cm of the front view's) and back
  depth that best explain both edges, median-filtered over 5 columns: what the geometry gives with a
  perfect edge detector, with the anchors, box tops and fronts as predicted;
* **true depth where this frame shows it (any face)** and **where this or an earlier frame showed
  it**: the predicted boxes whose stack's depth the frame shows (`waresynth.visibility`: its visible
  pixels reach 90 % of its depth, through a top face, a side face in a gap or the back edge), or any
  frame so far did, get the true depth: the ceilings of a single-frame reader of every face and of a
  sequence reader, on these predictions (`research/layout_ceilings.py` gives them on the truth's
  layouts).
"""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch
from scipy.ndimage import map_coordinates, median_filter
from tqdm import tqdm

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


from layouts import BOX, LayoutSpec  # noqa: E402
from layouts.boxdepth import box_parts, cell_z, redraw  # noqa: E402
from layouts.canonical import CanonicalView  # noqa: E402
from layouts.metrics import FrameScorer  # noqa: E402
from network.checkpoint import load_model  # noqa: E402
from network.inference.predictor import Predictor, sequence_camera  # noqa: E402
from waresynth.dataset import open_dataset  # noqa: E402
from waresynth.visibility import SeenTracker  # noqa: E402

SAMPLES = 24  #: points per side sampled on each top face
H_SEARCH = np.arange(-0.08, 0.0801, 0.01)  #: box top heights tried around the front view's, metres
Z_STEP = 0.01  #: back depths tried, metres
MIN_DEPTH = 0.12  #: shallowest box depth tried, metres
MEDIAN = 5  #: columns of the median filter over a box's per-column depths
PROB_FLOOR = 1e-3


def top_face_edges(
    scene: dict, frame: dict, anchors: np.ndarray, view: CanonicalView, spec: LayoutSpec
) -> tuple[np.ndarray, np.ndarray]:
    """Per slot and front-window column: the rows (continuous, front-view row axis) of the visible top
    faces' back and front edges, NaN where no box top face shows; relative to the given anchors."""
    cx, cy, cz = frame["camera_position"]
    d, m, h2 = -cz, view.metres_per_pixel, view.height / 2
    r_n, n = len(anchors), spec.size
    back, front = np.full((r_n, n), np.nan), np.full((r_n, n), np.nan)
    levels: dict[int, list[dict]] = {}
    for rack in scene["racks"]:
        for sh in rack["shelves"]:
            levels.setdefault(sh["level"], []).append(sh)
    u, v = np.meshgrid(np.linspace(-0.5, 0.5, SAMPLES), np.linspace(-0.5, 0.5, SAMPLES))
    for r, a in enumerate(anchors):
        if not np.isfinite(a):
            continue
        match = [(abs(view.row_of(shs[0]["board_top_y"] - cy) - a), shs) for shs in levels.values()]
        match = [t for t in match if t[0] < 3]
        if not match:
            continue
        shelves = min(match, key=lambda t: t[0])[1]
        true_row = float(view.row_of(shelves[0]["board_top_y"] - cy))
        for sh in shelves:
            tops: dict[str, list] = {}
            for b in sh["boxes"]:
                t = tops.setdefault(b["stack_id"], [b, math.inf])
                t[1] = min(t[1], b["center"][1] - b["size"][1] / 2)  # Y down: the stack's top
            for b, y_top in tops.values():
                if y_top - cy <= 0 or abs(b["center"][0] - cx) > spec.x_extent:
                    continue  # at or above the camera: no top face
                x, _, z = b["center"]
                w, dz, yaw = b["size"][0], b["size"][2], b["yaw"]
                px = x + math.cos(yaw) * u * w - math.sin(yaw) * v * dz
                pz = z + math.sin(yaw) * u * w + math.cos(yaw) * v * dz
                rho = (d / (d + pz)).ravel()
                row = h2 + (y_top - cy) * rho / m  # canonical rows of the face's points
                h_used, h_true = (a - row) * m, (true_row - row) * m
                col = np.floor(spec.x_to_col((px.ravel() - cx) * rho)).astype(int)
                ok = (col >= 0) & (col < n)
                hb, hf, ht = np.full(n, -np.inf), np.full(n, np.inf), np.full(n, -np.inf)
                np.maximum.at(hb, col[ok], h_used[ok])
                np.minimum.at(hf, col[ok], h_used[ok])
                np.maximum.at(ht, col[ok], h_true[ok])
                seen = np.isfinite(hb) & (ht < sh["clear_height"] - 0.01) & (hb < spec.h_extent)
                kb, kf = spec.a_to_row("front", hb), spec.a_to_row("front", hf)
                new = seen & (np.isnan(back[r]) | (kb < back[r]))
                back[r][new], front[r][new] = kb[new], kf[new]
    return back, front


def edge_maps(back: np.ndarray, front: np.ndarray, size: int) -> np.ndarray:
    """``(R, 2, D, D)`` edge probabilities: a bump (one row sigma) at each column's back and front edge row."""
    c = np.arange(size) + 0.5
    maps = [np.exp(-0.5 * (c[None, :, None] - e[:, None, :]) ** 2) for e in (back, front)]
    return np.nan_to_num(np.stack(maps, 1), nan=0.0)


def read_depths(
    prob: np.ndarray, cols: np.ndarray, c: float, h_top: float, d: float, z_front: float, z_max: float, spec: LayoutSpec
) -> np.ndarray | None:
    """Per-column back depth (metres behind the rack front) best explaining both edges; NaN where weak."""
    zs = np.arange(z_front + MIN_DEPTH, z_max + 1e-9, Z_STEP)
    if not len(zs):
        return None
    hs = h_top + H_SEARCH
    x = spec.col_to_x(cols + 0.5)
    lb, lf = (np.log(np.clip(p, PROB_FLOOR, 1.0)) for p in prob)
    rho_b, rho_f = d / (d + zs), d / (d + z_front)
    ub = np.broadcast_to(spec.x_to_col(x[None, :] * rho_b[:, None])[None] - 0.5, (len(hs), len(zs), len(x)))
    vb = np.broadcast_to((spec.a_to_row("front", c - (c - hs)[:, None] * rho_b[None, :]) - 0.5)[..., None], ub.shape)
    sb = map_coordinates(lb, [vb.ravel(), ub.ravel()], order=1, mode="nearest").reshape(ub.shape)
    uf = np.broadcast_to(spec.x_to_col(x * rho_f)[None] - 0.5, (len(hs), len(x)))
    vf = np.broadcast_to((spec.a_to_row("front", c - (c - hs) * rho_f) - 0.5)[:, None], uf.shape)
    sf = map_coordinates(lf, [vf.ravel(), uf.ravel()], order=1, mode="nearest").reshape(uf.shape)
    score = (sb + sf[:, None, :]).reshape(-1, len(x))
    best = score.argmax(0)
    z = zs[np.unravel_index(best, (len(hs), len(zs)))[1]]
    strong = np.exp(sb.reshape(-1, len(x))[best, np.arange(len(x))]) >= 0.2
    if not strong.any():
        return None
    return np.where(strong, median_filter(z, size=MEDIAN, mode="nearest"), np.nan)


def true_backs(truth_top: np.ndarray, cols: np.ndarray, spec: LayoutSpec, depth: float):
    """Per column of a predicted box: the truth's box back (metres behind the rack front, far cell's far
    boundary; the median where the truth has no box in the column) and which columns have one; None if none."""
    g = truth_top[:, cols] == BOX
    has = g.any(0)
    if not has.any():
        return None
    zc = cell_z(spec, depth) + spec.z_extent / spec.size / 2
    back = np.array([zc[np.nonzero(g[:, i])[0].min()] if has[i] else np.nan for i in range(len(cols))])
    back[~has] = np.median(back[has])
    return back, has


def score(frames: list[dict], view: CanonicalView, choose: Callable[..., np.ndarray | None]) -> tuple[dict, int, float]:
    """Top view scored with every predicted box's back replaced by ``choose(frame, r, cols, ...)`` (per-column
    Z, NaN keeps a column; None keeps the box); returns Table I's visible top view, boxes changed, mean error."""
    scorer, errs = FrameScorer(), []
    for f in frames:
        pred, truth, anchors, depth, spec = f["pred"], f["truth"], f["anchors"], f["depth"], f["spec"]
        top = pred["top"].copy()
        for r, a in enumerate(anchors):
            if not np.isfinite(a):
                continue
            c = (a - view.height / 2) * view.metres_per_pixel  # camera height above the board
            for cols, zf, _, h_top in box_parts(pred["top"][r], pred["front"][r], spec, depth):
                tb = true_backs(truth.top[r], cols, spec, depth)
                if tb is None:
                    continue  # no box there in the truth
                new = choose(f, r, cols, zf, h_top, c, *tb)
                if new is None:
                    continue
                err = np.abs(new - tb[0])[tb[1]]
                if np.isfinite(err).any():
                    errs.append(np.nanmedian(err))
                redraw(top[r], cols, zf, new, spec, depth)
        scorer.update({"top": top, "front": pred["front"]}, truth)
    return scorer.result()["visible"]["top"], len(errs), 100 * float(np.mean(errs)) if errs else float("nan")


def seen_in(level: int) -> Callable[..., np.ndarray | None]:
    """A `score` choice: the true depth for boxes whose stack's depth is seen at ``level`` or above
    (`SeenTracker.labels`: 2 = this frame, 1 = this or an earlier one) in most of their columns."""

    def choose(f, r, cols, zf, h_top, c, back, has):
        lab = f["seen"][r, cols][has]
        return back if (lab >= level).mean() > 0.5 else None

    return choose


class Table:
    """Prints `score`'s rows: top rack / box mIoU, boxes changed and their mean back error."""

    def __init__(self, frames: list[dict], view: CanonicalView, width: int = 60) -> None:
        self.frames, self.view, self.width = frames, view, width
        print(f"{'':{width}s} {'top rack':>9s} {'top box':>8s} {'boxes':>6s} {'back err (cm)':>14s}")

    def line(self, name: str, choose: Callable[..., np.ndarray | None]) -> None:
        v, boxes, err = score(self.frames, self.view, choose)
        cells = f"{100 * v['rack']['miou']:9.1f} {100 * v['box']['miou']:8.1f}"
        print(f"{name:{self.width}s} {cells}" + (f" {boxes:6d} {err:14.1f}" if boxes else ""), flush=True)


def top_face_shows(f: dict, r: int, cols: np.ndarray, true_back: np.ndarray) -> bool:
    """Does the box's top face show a back edge in the frame (the true edge map, where perspective puts it)?"""
    spec, dist = f["spec"], f["distance"]
    shown = spec.x_to_col(spec.col_to_x(cols + 0.5) * dist / (dist + np.median(true_back)))
    return bool(f["edges"][r, 0][:, np.clip(shown.astype(int), 0, spec.size - 1)].max() >= 0.5)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("checkpoint", type=Path)
    ap.add_argument("data", type=Path, help="a generated dataset (e.g. the held-out set)")
    ap.add_argument("--every", type=int, default=2, help="score every N-th frame (all frames are run)")
    ap.add_argument("--min-below", type=float, nargs="+", default=[0.1, 0.3], help="box top under the camera, m")
    ap.add_argument("--sequences", type=int, default=None, help="only the first N sequences")
    ap.add_argument("--threads", type=int, default=2)
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    model, _ = load_model(args.checkpoint)
    view = model.cfg.view
    seqs = open_dataset(args.data).sequences()[: args.sequences]
    frames = []
    bar = tqdm(total=sum(s.num_frames for s in seqs), desc="predict", unit="frame", leave=False)
    for seq in seqs:
        scene, spec, camera = seq.scene(), seq.spec, sequence_camera(seq)
        true_depth = float(scene["row"]["depth"])
        seen = SeenTracker(seq)
        for i, out in enumerate(Predictor(model, camera).run((seq.rgb(i) for i in range(seq.num_frames)), "stream")):
            bar.update(1)
            seen.add(i)
            if i % args.every:
                continue
            read = out.rack_depth
            anchors = out.anchors.float().cpu().numpy()
            back, front = top_face_edges(scene, seq.frame(i), anchors, view, spec)
            frames.append(
                {"pred": out.layouts(spec), "truth": seq.layouts(i), "anchors": anchors, "spec": spec,
                 "edges": edge_maps(back, front, spec.size), "depth": read if np.isfinite(read) else true_depth,
                 "distance": camera(i)[1], "seen": seen.labels(i)}
            )  # fmt: skip
    bar.close()
    print(f"{args.checkpoint} on {args.data}: {len(frames)} frames of {len(seqs)} sequences; top view, mIoU")
    line = Table(frames, view).line
    line("prediction", lambda *a: None)
    for below in args.min_below:

        def true_top(f, r, cols, zf, h_top, c, back, has, below=below):
            return back if c - h_top >= below and top_face_shows(f, r, cols, back) else None

        def from_edges(f, r, cols, zf, h_top, c, back, has, below=below):
            if true_top(f, r, cols, zf, h_top, c, back, has) is None:
                return None
            depth, spec = f["depth"], f["spec"]
            z_max = min(depth, spec.z_extent)
            return read_depths(f["edges"][r], cols, c, h_top, f["distance"], float(np.median(zf)), z_max, spec)

        line(f"true depth where the top face shows (top >= {below:g} m under)", true_top)
        line(f"read from the true edges (top >= {below:g} m under)", from_edges)

    line("true depth where this frame shows it (any face)", seen_in(2))
    line("true depth where this or an earlier frame showed it", seen_in(1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
