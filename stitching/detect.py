"""Detect: one frame's top and front layouts -> metric 2D detections per shelf slot.

* Top view, boxes: connected components of the box mask (4-connectivity), labelled once per
  frame for all slots together (``scipy.ndimage.label`` with a structure that never joins two
  slots; it is the same labelling as ``skimage.measure.label`` and about 3x faster here).
  Components smaller than ``min_box_area`` are dropped (noise). A component that holds several
  touching boxes is split where its per-column far edge, near edge or front-view height steps
  by more than ``split_step``. Each piece gets an axis-aligned X/Z extent (pixel edges) and,
  when it fills its bounding box poorly (a yawed box), a minimum-area oriented rectangle.
* Top view, shelf: a column is shelf when at least ``shelf_fraction`` of its rows are shelf or
  box; runs of shelf columns are shelf segments (racks are separated by background columns).
  The shelf's depth range is the rows that are shelf/box in most shelf columns.
* Front view: per-column profiles (vectorised): box height = box pixels in the column,
  clear height = non-background pixels, both times the metres per row (robust to isolated flips
  because they count pixels rather than look for the top-most one). Front detections are runs
  of box columns, split where the height steps.

Columns outside ``visible`` are ignored (they are guesses); a detection touching the edge of
the visible range is flagged ``cut`` on that side.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage

from layouts.classes import BOX
from layouts.codecs import FrameLayouts
from layouts.errors import LayoutError
from layouts.spec import LayoutSpec
from layouts.steps import MIN_BOX_WIDTH, SPLIT_STEP, profile_steps, score_pieces
from stitching.geometry import min_area_rect

# Label structure: 4-connectivity inside a slot, nothing across slots.
_STRUCT = np.zeros((3, 3, 3), bool)
_STRUCT[1] = ndimage.generate_binary_structure(2, 1)


@dataclass(frozen=True)
class DetectConfig:
    """Clean-up and splitting settings (defaults suit ground truth and mildly noisy layouts)."""

    min_box_area: float = 0.012  #: m^2; smaller box components are noise
    opening: int = 0  #: iterations of a 3x3 binary opening of the box masks (0 = off; 1 for noisy output)
    shelf_fraction: float = 0.3  #: a top-view column is shelf when this fraction of rows is shelf/box
    split_step: float = SPLIT_STEP  #: m; a step this large in a component's depth edges or height splits it
    min_box_width: float = MIN_BOX_WIDTH  #: m; no split leaves a piece narrower than this
    min_box_height: float = 0.08  #: m; front-view columns with less box than this hold none (noise)
    cut_margin: float = 0.04  #: m; a box ending this close to the visible range's edge counts as cut there
    fit_yaw: bool = True  #: fit an oriented rectangle to components that fill their bounds poorly
    yaw_fill: float = 0.93  #: fill ratio (area / bounding-box area) below which yaw is fitted

    def __post_init__(self) -> None:
        for name in (
            "min_box_area",
            "shelf_fraction",
            "split_step",
            "min_box_width",
            "min_box_height",
            "cut_margin",
            "yaw_fill",
        ):
            v = getattr(self, name)
            if not isinstance(v, (int, float)) or not np.isfinite(v) or v < 0:
                raise LayoutError(f"DetectConfig.{name} must be a finite number >= 0, got {v!r}")
        if not isinstance(self.opening, int) or self.opening < 0:
            raise LayoutError(f"DetectConfig.opening must be an integer >= 0, got {self.opening!r}")


@dataclass
class TopBox:
    """A box footprint seen in the top view of one slot, in the frame's shelf-centric metres."""

    c0: int  #: first column (inclusive)
    c1: int  #: last column + 1
    x0: float
    x1: float
    z0: float
    z1: float
    cx: float
    cz: float
    w: float
    d: float
    yaw: float
    cut_left: bool
    cut_right: bool


@dataclass
class FrontRun:
    """A run of front-view box columns with one height (a front detection)."""

    c0: int
    c1: int
    x0: float
    x1: float
    height: float


@dataclass
class SlotDetections:
    """Everything detected in one shelf slot of one frame."""

    slot: int
    present: bool  #: the slot shows any shelf
    shelf_cols: np.ndarray  #: (D,) bool, shelf columns (within the visible range)
    segments: list[tuple[float, float, bool, bool]]  #: shelf runs (x0, x1, cut_left, cut_right)
    z_range: tuple[float, float]  #: shelf depth range (Z about mid-depth)
    clear_height: float  #: median clear height over shelf columns (0 if none)
    box_height: np.ndarray  #: (D,) front-view box height per column (metres, 0 = none)
    boxes: list[TopBox] = field(default_factory=list)
    front: list[FrontRun] = field(default_factory=list)


@dataclass
class FrameDetections:
    slots: list[SlotDetections]
    vis_lo: int  #: first visible column
    vis_hi: int  #: last visible column + 1
    cut_cols: int = 0  #: columns from the visible edges within which a detection counts as cut


def visible_range(visible: np.ndarray | None, size: int) -> tuple[int, int]:
    """First and last+1 visible column (the whole width when unknown or none visible)."""
    if visible is None:
        return 0, size
    idx = np.flatnonzero(visible)
    if idx.size == 0:
        return 0, 0
    return int(idx[0]), int(idx[-1]) + 1


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """Half-open runs ``[a, b)`` of True in a 1D bool array."""
    if not mask.any():
        return []
    d = np.diff(np.concatenate([[0], mask.view(np.int8), [0]]))
    starts, ends = np.flatnonzero(d == 1), np.flatnonzero(d == -1)
    return list(zip(starts.tolist(), ends.tolist()))


def _piece(
    spec: LayoutSpec,
    sub: np.ndarray,
    r_off: int,
    c_off: int,
    vis: tuple[int, int],
    cfg: DetectConfig,
    trim: tuple[int, int] = (0, 0),
) -> TopBox | None:
    """Metric footprint of one component piece ``sub`` (bool, rows x cols) placed at (r_off, c_off).

    ``trim`` = columns next to a split on the (left, right) side: the split position is uncertain
    by a few columns, so those columns are left out of the depth range (they may hold the
    neighbour's rows), and a split piece gets no oriented fit.
    """
    cols = np.flatnonzero(sub.any(axis=0))
    if cols.size == 0:
        return None
    a, b = int(cols[0]), int(cols[-1]) + 1
    core = sub
    if trim != (0, 0) and sub.shape[1] - trim[0] - trim[1] >= 3:
        core = sub[:, trim[0] : sub.shape[1] - trim[1]]
    rows = np.flatnonzero(core.any(axis=1))
    if rows.size == 0:
        return None
    ra, rb = int(rows[0]), int(rows[-1]) + 1
    c0, c1 = c_off + a, c_off + b
    x0, x1 = float(spec.col_to_x(c0)), float(spec.col_to_x(c1))
    z1, z0 = float(spec.row_to_a("top", r_off + ra)), float(spec.row_to_a("top", r_off + rb))
    cx, cz, w, d, yaw = (x0 + x1) / 2, (z0 + z1) / 2, x1 - x0, z1 - z0, 0.0
    area = int(sub.sum())
    if cfg.fit_yaw and trim == (0, 0) and area >= 30 and area < cfg.yaw_fill * (b - a) * (rb - ra):
        # A convex shape's hull vertices are all column extremes: the top and bottom pixel of each column.
        s = sub[ra:rb, a:b]
        has_c = s.any(axis=0)
        cc = np.flatnonzero(has_c)
        top_r = s.argmax(axis=0)[has_c]
        bot_r = s.shape[0] - 1 - s[::-1].argmax(axis=0)[has_c]
        pu = np.concatenate([cc, cc]) + (c_off + a) + 0.5
        pv = np.concatenate([top_r, bot_r]) + (r_off + ra) + 0.5
        px, pz = spec.to_metres("top", pu, pv)
        rcx, rcz, rw, rd, ryaw = min_area_rect(np.column_stack([px, pz]))
        # Outermost pixel centres lie up to a pixel inside a true edge. Along a slanted side the
        # centres take many sub-pixel phases, so the extreme one is nearly on the edge; only when a
        # side crosses under one pixel step does the half-pixel gap of an axis-aligned edge remain.
        dx, dz = spec.pixel_size("top")
        steps = min(rw, rd) * abs(np.sin(ryaw)) / min(dx, dz)
        grow = 0.5 * float(np.clip(1.0 - steps, 0.0, 1.0))
        cy, sy = abs(np.cos(ryaw)), abs(np.sin(ryaw))
        rw += 2 * grow * (dx * cy + dz * sy)
        rd += 2 * grow * (dx * sy + dz * cy)
        if rw * rd < w * d:  # only keep the oriented fit when it is the tighter description
            cx, cz, w, d, yaw = rcx, rcz, rw, rd, ryaw
    m = int(round(cfg.cut_margin / (spec.x_extent / spec.size)))
    return TopBox(c0, c1, x0, x1, z0, z1, cx, cz, w, d, yaw, c0 <= vis[0] + m, c1 >= vis[1] - m)


def _front_runs(
    spec: LayoutSpec, box_h: np.ndarray, h_steps: np.ndarray, lo: int, hi: int, cfg: DetectConfig
) -> list[FrontRun]:
    out = []
    dx = spec.x_extent / spec.size
    min_cols = max(1, int(round(cfg.min_box_width / dx)))
    for a, b in _runs(box_h[lo:hi] > 0):
        a, b = a + lo, b + lo
        if (b - a) * dx < 0.05:
            continue
        for p, q in score_pieces(h_steps[a : b + 1], cfg.split_step, min_cols):
            out.append(
                FrontRun(
                    a + p,
                    a + q,
                    float(spec.col_to_x(a + p)),
                    float(spec.col_to_x(a + q)),
                    float(np.median(box_h[a + p : a + q])),
                )
            )
    return out


def check_frame(top: np.ndarray, front: np.ndarray, spec: LayoutSpec, visible: np.ndarray | None, name: str) -> None:
    """Validate one frame's arrays against ``spec`` with a one-line error naming ``name``."""
    if visible is not None and not isinstance(visible, np.ndarray):
        raise LayoutError(f"{name}: visible must be a numpy bool array, got {type(visible).__name__}")
    FrameLayouts(top, front, visible).validate(spec, name)


def _slot_shelf(
    spec: LayoutSpec,
    cfg: DetectConfig,
    r: int,
    shelf_frac: np.ndarray,
    nonbg_rows: np.ndarray,
    clear: np.ndarray,
    box_h: np.ndarray,
    vis: tuple[int, int],
    cut_cols: int,
) -> SlotDetections:
    """Slot ``r``'s shelf from its top-view column fractions and front-view clear heights (no boxes yet)."""
    D = spec.size
    lo, hi = vis
    dx = spec.pixel_size("top")[0]
    cols = np.zeros(D, bool)
    cols[lo:hi] = shelf_frac >= cfg.shelf_fraction
    present = bool(cols.any())
    segs = [
        (float(spec.col_to_x(a)), float(spec.col_to_x(b)), a <= lo + cut_cols, b >= hi - cut_cols)
        for a, b in _runs(cols)
        if (b - a) * dx >= 0.1
    ]
    z_range = (0.0, 0.0)
    ch = 0.0
    if present:
        # Rows that are shelf/box in at least half of the shelf columns (gaps are background).
        rows = nonbg_rows >= 0.5 * np.count_nonzero(cols)
        idx = np.flatnonzero(rows)
        if idx.size:
            z_range = (float(spec.row_to_a("top", idx[-1] + 1)), float(spec.row_to_a("top", idx[0])))
        c = clear[cols]
        c = c[c > 0]
        ch = float(np.median(c)) if c.size else 0.0
    return SlotDetections(r, present, cols, segs, z_range, ch, box_h)


def _add_top_boxes(
    slots: list[SlotDetections],
    spec: LayoutSpec,
    cfg: DetectConfig,
    labels: np.ndarray,
    h_steps: np.ndarray,
    r_lo: int,
    vis: tuple[int, int],
    min_px: float,
) -> None:
    """Top-view box components (``labels`` over rows from ``r_lo``, columns from the visible ``lo``) into their
    slots' boxes, each split where the top or front outline steps."""
    lo, hi = vis
    dx, dz = spec.pixel_size("top")
    objs = ndimage.find_objects(labels)
    min_cols = max(1, int(round(cfg.min_box_width / dx)))
    for k, sl in enumerate(objs, start=1):
        if sl is None or (sl[1].stop - sl[1].start) * (sl[2].stop - sl[2].start) < min_px:
            continue
        r = sl[0].start
        rs, cs = sl[1], sl[2]
        sub = labels[r, rs, cs] == k
        if np.count_nonzero(sub) < min_px:
            continue
        rs = slice(rs.start + r_lo, rs.stop + r_lo)
        c_off = cs.start + lo
        ncol = sub.shape[1]
        pieces = [(0, ncol)]
        if ncol >= 2 * min_cols:
            has = sub.any(axis=0)
            top_r = np.where(has, sub.argmax(axis=0), 0) * dz
            bot_r = np.where(has, sub.shape[0] - sub[::-1].argmax(axis=0), 0) * dz
            score = np.maximum(profile_steps(np.stack([top_r, bot_r])), h_steps[r, c_off : c_off + ncol + 1])
            pieces = score_pieces(score, cfg.split_step, min_cols)
        trim = max(2, int(np.ceil(0.04 / dx)))
        for a, b in pieces:
            piece = sub[:, a:b]
            if piece.sum() < min_px:
                continue
            t = (trim if a > 0 else 0, trim if b < ncol else 0)
            tb = _piece(spec, piece, rs.start, c_off + a, (lo, hi), cfg, t)
            if tb is not None:
                slots[r].boxes.append(tb)


def detect_frame(
    top: np.ndarray,
    front: np.ndarray,
    spec: LayoutSpec,
    visible: np.ndarray | None = None,
    config: DetectConfig | None = None,
    validate: bool = True,
    name: str = "frame",
) -> FrameDetections:
    """Detect shelves and boxes in every slot of one frame (arrays ``(R, D, D)`` uint8)."""
    cfg = config or DetectConfig()
    if validate:
        check_frame(top, front, spec, visible, name)
    R, D = spec.num_slots, spec.size
    lo, hi = visible_range(visible, D)
    dx, dz = spec.pixel_size("top")
    _, dh = spec.pixel_size("front")

    # Front profiles for all slots at once.
    fvis = front[:, :, lo:hi]
    box_h = np.zeros((R, D))
    clear = np.zeros((R, D))
    box_h[:, lo:hi] = (fvis == BOX).sum(axis=1, dtype=np.int32) * dh
    box_h[box_h < cfg.min_box_height] = 0.0
    clear[:, lo:hi] = np.count_nonzero(fvis, axis=1) * dh  # class ids: nonzero = not background

    # Height steps along the whole front profile of each slot (split positions 0..D).
    h_steps = np.stack([profile_steps(box_h[r]) for r in range(R)])
    tvis = top[:, :, lo:hi]
    shelf_frac = np.count_nonzero(tvis, axis=1) / D  # nonzero = not background
    nonbg_rows = np.count_nonzero(tvis, axis=2)
    box_mask = tvis == BOX
    # Label only the rows that hold any box (the rack depth is narrower than the layout).
    rows_any = box_mask.any(axis=(0, 2))
    ridx = np.flatnonzero(rows_any)
    r_lo, r_hi = (int(ridx[0]), int(ridx[-1]) + 1) if ridx.size else (0, 0)
    box_mask = box_mask[:, r_lo:r_hi]
    if cfg.opening:
        box_mask = ndimage.binary_opening(box_mask, structure=_STRUCT, iterations=cfg.opening)
    labels, n = ndimage.label(box_mask, structure=_STRUCT)
    min_px = cfg.min_box_area / (dx * dz)
    cut_cols = int(round(cfg.cut_margin / dx))
    slots = [
        _slot_shelf(spec, cfg, r, shelf_frac[r], nonbg_rows[r], clear[r], box_h[r], (lo, hi), cut_cols)
        for r in range(R)
    ]
    if n:
        _add_top_boxes(slots, spec, cfg, labels, h_steps, r_lo, (lo, hi), min_px)
    for s in slots:
        s.boxes.sort(key=lambda b: b.x0)
        s.front = _front_runs(spec, s.box_height, h_steps[s.slot], lo, hi, cfg)
    return FrameDetections(slots, lo, hi, cut_cols)
