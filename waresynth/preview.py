"""Dataset summary and a one-frame preview sheet, so a person can check a WareSynth dataset at a glance.

`summarise` gathers the figures ``mvracklay inspect`` prints (sequences per split, image size,
layout spec, semantic class pixel fractions, boxes per shelf); `render_sheet` draws one frame's
RGB, depth, semantic and instance images beside the top and front layouts of every shelf slot.
"""

from __future__ import annotations

import io
import os
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image, ImageDraw, ImageFont
from tqdm import tqdm

from layouts.camera_record import CAMERA_ANGLE_KEYS
from layouts.classes import BOX, CLASS_COLOURS, CLASS_NAMES, SHELF, colourise
from layouts.errors import InputError
from layouts.fileio import atomic_write_bytes
from waresynth.semantics import NUM_SEMANTIC, SEMANTIC_COLOURS, SEMANTIC_NAMES, colourise_semantic

# ----------------------------------------------------------------------------- geometry
MARGIN = 10  #: outer margin, pixels
GAP = 10  #: space between panels
TITLE = 18  #: height of a panel's title strip
HEADER = 24  #: height of the sheet's header line
PANEL_W = 256  #: width of each image panel (RGB, depth, semantic, instances)
LAYOUT_PX = 176  #: side of each layout panel (top / front)
LABEL_W = 150  #: width of the slot description column
LEGEND_ROW = 16  #: height of one legend line
_LEGEND_LINES = NUM_SEMANTIC + len(CLASS_NAMES) + 7  # headings, swatches, depth bar, notes

_DIM = 0.35  #: brightness kept by layout columns that are out of view
_BG = (250, 250, 250)
_INK = (20, 20, 20)
_MUTED = (110, 110, 110)


@dataclass(frozen=True)
class SheetGeometry:
    """Pixel layout of a preview sheet; depends only on the image size and the slot count."""

    panel_h: int
    width: int
    height: int
    layouts_top: int  #: y of the first slot row

    @property
    def size(self) -> tuple[int, int]:
        return self.width, self.height


def sheet_geometry(image_size: tuple[int, int], num_slots: int) -> SheetGeometry:
    """Where everything goes on the sheet for ``image_size = (w, h)`` images and R slots."""
    w, h = image_size
    panel_h = max(1, round(PANEL_W * h / w))
    width = 2 * MARGIN + 4 * PANEL_W + 3 * GAP
    layouts_top = MARGIN + HEADER + TITLE + panel_h + 2 * GAP
    slots_h = num_slots * (TITLE + LAYOUT_PX + GAP)
    legend_h = TITLE + _LEGEND_LINES * LEGEND_ROW
    height = layouts_top + max(slots_h, legend_h) + MARGIN
    return SheetGeometry(panel_h, width, height, layouts_top)


def sheet_size(image_size: tuple[int, int], num_slots: int) -> tuple[int, int]:
    """``(width, height)`` in pixels of the sheet `render_sheet` draws."""
    return sheet_geometry(image_size, num_slots).size


# ----------------------------------------------------------------------------- colouring
#: Anchor colours of the depth colour map (near = yellow, far = dark blue), viridis-like.
_DEPTH_ANCHORS = np.array(
    [[253, 231, 37], [122, 209, 81], [34, 168, 132], [42, 120, 142], [65, 68, 135], [68, 1, 84]], np.float64
)


def depth_colour(
    depth: np.ndarray, limits: tuple[float, float] | None = None
) -> tuple[np.ndarray, tuple[float, float]]:
    """Colour-map metric depth, near = yellow to far = purple (0 = no hit, drawn black).

    Colours are linear in inverse depth, so the rack row in front keeps its contrast when the
    background is far away. ``limits`` (near, far) in metres default to the 1st and 99th
    percentiles of the valid depths; returns the RGB image and the limits used.
    """
    d = np.asarray(depth, dtype=np.float64)
    valid = np.isfinite(d) & (d > 0)
    if limits is None:
        if valid.any():
            lo, hi = (float(v) for v in np.percentile(d[valid], [1, 99]))
        else:
            lo, hi = 0.0, 1.0
        if hi - lo < 0.1:
            lo, hi = max(0.01, lo - 0.05), hi + 0.05
        limits = (lo, hi)
    lo, hi = limits
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (1 / lo - 1 / np.where(valid, d, hi)) / max(1 / lo - 1 / hi, 1e-12)
    t = np.clip(t, 0, 1) * (len(_DEPTH_ANCHORS) - 1)
    k = np.minimum(np.floor(t).astype(int), len(_DEPTH_ANCHORS) - 2)
    f = (t - k)[..., None]
    rgb = _DEPTH_ANCHORS[k] * (1 - f) + _DEPTH_ANCHORS[k + 1] * f
    rgb[~valid] = 0
    return rgb.round().astype(np.uint8), (lo, hi)


def instance_colour(instance: np.ndarray) -> np.ndarray:
    """Distinct stable colours per instance id (0 = none, drawn dark grey)."""
    inst = np.asarray(instance, dtype=np.int64)
    ids, inv = np.unique(inst, return_inverse=True)
    h = (ids * 2654435761) & 0xFFFFFF
    lut = np.stack([(h >> 16) & 255, (h >> 8) & 255, h & 255], axis=1)
    lut = (64 + lut * 191 // 255).astype(np.uint8)
    lut[ids == 0] = (40, 40, 40)
    return lut[inv.reshape(inst.shape)]


def _font(size: int) -> ImageFont.FreeTypeFont | ImageFont.ImageFont:
    return ImageFont.load_default(size=size)


# ----------------------------------------------------------------------------- sheet
def _paste(sheet: Image.Image, arr: np.ndarray, xy: tuple[int, int], size: tuple[int, int]) -> None:
    """Paste an array scaled (nearest) to ``size`` at ``xy``, framed by a thin grey line."""
    im = Image.fromarray(np.ascontiguousarray(arr)).resize(size, Image.Resampling.NEAREST)
    sheet.paste(im, xy)
    x, y = xy
    ImageDraw.Draw(sheet).rectangle([x - 1, y - 1, x + size[0], y + size[1]], outline=(160, 160, 160))


def _dim_columns(rgb: np.ndarray, visible: np.ndarray | None) -> np.ndarray:
    if visible is None or visible.all():
        return rgb
    out = rgb.astype(np.float32)
    out[:, ~visible] *= _DIM
    return out.round().astype(np.uint8)


def _mark_slots(
    draw: ImageDraw.ImageDraw, seq: Any, record: dict[str, Any], xy: tuple[int, int], size: tuple[int, int], font: Any
) -> None:
    """Mark each slot's board edge (at the rack front plane) on the RGB panel with a labelled tick."""
    cam = record.get("camera_position")
    distance = record.get("distance")
    if not isinstance(cam, list) or len(cam) != 3 or not isinstance(distance, (int, float)) or distance <= 0:
        return
    intr = seq.intrinsics
    sy = size[1] / intr.height
    for r, info in enumerate(record.get("slots") or []):
        try:
            dy = float(info["board_top_y"]) - float(cam[1])
        except (KeyError, TypeError, ValueError):
            continue
        v = float(intr.project(np.array([[0.0, dy, float(distance)]]))[0, 1])
        if not 0 <= v < intr.height:
            continue
        y = xy[1] + v * sy
        x0, x1 = xy[0], xy[0] + size[0] - 1
        draw.line([(x0, y), (x0 + 12, y)], fill=(255, 255, 255), width=2)
        draw.line([(x1 - 12, y), (x1, y)], fill=(255, 255, 255), width=2)
        label = f"slot {r}"
        tw = draw.textlength(label, font=font)
        box = [x1 - 16 - tw - 4, y - 8, x1 - 14, y + 6]
        draw.rectangle(box, fill=(0, 0, 0))
        draw.text((box[0] + 2, y - 7), label, fill=(255, 255, 255), font=font)


def _fmt_m(v: Any) -> str:
    try:
        return f"{float(v):.2f} m"
    except (TypeError, ValueError):
        return "?"


def _draw_header(
    draw: ImageDraw.ImageDraw, seq: Any, index: int, record: dict, size: tuple[int, int], name: str
) -> None:
    """The title line: dataset, sequence, frame, image size, camera position and distance, turned angles."""
    w, h = size
    cam = record.get("camera_position") or []
    cam_txt = ", ".join(f"{float(c):.2f}" for c in cam) if len(cam) == 3 else "?"
    head = (
        f"{name + ' / ' if name else ''}{seq.name} ({seq.split})   frame {index} of {seq.num_frames}"
        f"   image {w}x{h}   camera ({cam_txt}) m   distance to rack front {_fmt_m(record.get('distance'))}"
    )
    angles = getattr(seq, "camera_angles", None)
    if angles and any(angles):
        head += "   turned (roll / pitch / yaw) " + " / ".join(f"{a:g}" for a in angles) + " deg"
    draw.text((MARGIN, MARGIN), head, fill=_INK, font=_font(15))


def _draw_slot_rows(
    sheet: Image.Image, draw: ImageDraw.ImageDraw, seq: Any, index: int, record: dict, geo: SheetGeometry
) -> int:
    """One row per shelf slot (top and front layouts, the slot's facts), highest slot first so the rows read
    like the image; returns the X of the legend column."""
    spec = seq.spec
    f_title, f_small = _font(13), _font(11)
    lay = seq.layouts(index)
    slot_list = list(record.get("slots") or [])
    x_top = MARGIN + LABEL_W
    x_front = x_top + LAYOUT_PX + GAP
    for row, r in enumerate(range(spec.num_slots - 1, -1, -1)):
        y = geo.layouts_top + row * (TITLE + LAYOUT_PX + GAP)
        top, front = lay.top[r], lay.front[r]
        empty = not top.any() and not front.any()
        draw.text((x_top, y), f"slot {r}: top view (up = far side)", fill=_INK, font=f_title)
        draw.text((x_front, y), f"slot {r}: front view (up = higher)", fill=_INK, font=f_title)
        _paste(sheet, _dim_columns(colourise(top), lay.visible), (x_top, y + TITLE), (LAYOUT_PX, LAYOUT_PX))
        _paste(sheet, _dim_columns(colourise(front), lay.visible), (x_front, y + TITLE), (LAYOUT_PX, LAYOUT_PX))
        lines = [f"shelf slot {r}"]
        if empty:
            lines.append("(no shelf visible)")
        else:
            info = slot_list[r] if r < len(slot_list) else None
            if info is not None:
                lines.append(f"level {info.get('level', '?')}")
                lines.append(f"board top y = {_fmt_m(info.get('board_top_y'))}")
                lines.append(f"clear height {_fmt_m(info.get('clear_height'))}")
            box_frac = float((top == BOX).sum()) / max(1, int((top > 0).sum()))
            lines.append(f"top view occupied {100 * box_frac:.0f} %")
        for k, line in enumerate(lines):
            draw.text(
                (MARGIN, y + TITLE + k * LEGEND_ROW),
                line,
                fill=_INK if k == 0 else _MUTED,
                font=f_title if k == 0 else f_small,
            )
    return x_front + LAYOUT_PX + 2 * GAP


def _draw_legend(
    sheet: Image.Image, draw: ImageDraw.ImageDraw, spec: Any, x_leg: int, y: int, depth_range: tuple[float, float]
) -> None:
    """The legend column: semantic and layout class colours, what the layouts span, the depth colour bar."""
    f_title, f_small = _font(13), _font(11)
    dmin, dmax = depth_range
    draw.text((x_leg, y), "legend", fill=_INK, font=f_title)
    y += TITLE

    def swatch(colour: tuple[int, int, int], text: str) -> None:
        nonlocal y
        draw.rectangle([x_leg, y + 2, x_leg + 22, y + LEGEND_ROW - 3], fill=colour, outline=(0, 0, 0))
        draw.text((x_leg + 30, y + 1), text, fill=_INK, font=f_small)
        y += LEGEND_ROW

    def note(text: str, colour: tuple[int, int, int] = _MUTED) -> None:
        nonlocal y
        draw.text((x_leg, y + 1), text, fill=colour, font=f_small)
        y += LEGEND_ROW

    note("semantic classes", _INK)
    for cid in range(NUM_SEMANTIC):
        swatch(SEMANTIC_COLOURS[cid], SEMANTIC_NAMES[cid])
    note("layout classes (top / front views)", _INK)
    for cid in sorted(CLASS_NAMES):
        desc = {0: "background (no shelf)", SHELF: "shelf (free)", BOX: "box (occupied)"}.get(cid, CLASS_NAMES[cid])
        swatch(CLASS_COLOURS[cid], desc)
    note("dimmed layout columns: out of the camera's view")
    note(f"layout {spec.size}x{spec.size} px: {spec.x_extent:.2f} m wide (X, left to right);")
    note(f"top rows {spec.z_extent:.2f} m deep, front rows {spec.h_extent:.2f} m high")
    note("depth colours, near to far (linear in 1/depth):", _INK)
    bar_w = 200
    inv = np.linspace(1 / dmin, 1 / dmax, bar_w)  # the bar is linear in inverse depth, like the panel
    ramp, _ = depth_colour((1 / inv)[None, :].repeat(4, 0), (dmin, dmax))
    _paste(sheet, ramp, (x_leg, y + 2), (bar_w, LEGEND_ROW - 4))
    y += LEGEND_ROW
    for frac in (0.0, 0.5, 1.0):
        label = f"{1 / (1 / dmin + frac * (1 / dmax - 1 / dmin)):.1f} m"
        tw = draw.textlength(label, font=f_small)
        x = x_leg + frac * bar_w - frac * tw
        draw.text((x, y + 1), label, fill=_MUTED, font=f_small)


def render_sheet(seq: Any, index: int, dataset_name: str = "") -> Image.Image:
    """Draw the preview sheet of frame ``index`` of sequence ``seq`` (a `waresynth.dataset.Sequence`)."""
    if isinstance(index, bool) or not isinstance(index, (int, np.integer)) or not 0 <= index < seq.num_frames:
        raise InputError(f"--frame must be in [0, {seq.num_frames}) for sequence {seq.name}, got {index!r}")
    index = int(index)
    spec = seq.spec
    rgb = np.asarray(seq.rgb(index))
    h, w = rgb.shape[:2]
    geo = sheet_geometry((w, h), spec.num_slots)
    sheet = Image.new("RGB", geo.size, _BG)
    draw = ImageDraw.Draw(sheet)
    record = seq.frame(index)
    _draw_header(draw, seq, index, record, (w, h), dataset_name)

    # Row of image panels.
    depth_rgb, (dmin, dmax) = depth_colour(seq.depth(index))
    panels = [
        ("RGB", rgb),
        (f"depth ({dmin:.1f} to {dmax:.1f} m, black = no hit)", depth_rgb),
        ("semantic classes", colourise_semantic(seq.semantic(index))),
        ("instances (one colour per id)", instance_colour(seq.instance(index))),
    ]
    y_title = MARGIN + HEADER
    f_title = _font(13)
    for k, (title, arr) in enumerate(panels):
        x = MARGIN + k * (PANEL_W + GAP)
        draw.text((x, y_title), title, fill=_INK, font=f_title)
        _paste(sheet, arr, (x, y_title + TITLE), (PANEL_W, geo.panel_h))
    _mark_slots(draw, seq, record, (MARGIN, y_title + TITLE), (PANEL_W, geo.panel_h), _font(11))

    x_leg = _draw_slot_rows(sheet, draw, seq, index, record, geo)
    _draw_legend(sheet, draw, spec, x_leg, geo.layouts_top, (dmin, dmax))
    return sheet


def write_sheet(seq: Any, index: int, out: str | os.PathLike, dataset_name: str = "") -> tuple[int, int]:
    """Render the sheet of one frame and write it atomically as PNG; returns its ``(width, height)``."""
    out = Path(out)
    if out.suffix.lower() != ".png":
        raise InputError(f"{out}: the preview sheet is written as PNG; give a path ending in .png")
    if out.is_dir():
        raise InputError(f"{out}: is a folder; give a .png file path")
    sheet = render_sheet(seq, index, dataset_name)
    buf = io.BytesIO()
    sheet.save(buf, format="PNG", optimize=False)
    atomic_write_bytes(out, buf.getvalue())
    return sheet.size


# ----------------------------------------------------------------------------- summary
def _sample_frames(seqs: list[Any], max_frames: int) -> list[tuple[Any, int]]:
    """Up to ``max_frames`` (sequence, frame) pairs spread evenly over the dataset, deterministic."""
    pairs = [(s, i) for s in seqs for i in range(s.num_frames)]
    if len(pairs) <= max_frames:
        return pairs
    pick = np.linspace(0, len(pairs) - 1, max_frames).round().astype(int)
    return [pairs[k] for k in np.unique(pick)]


def _iter_boxes_per_shelf(scene: Any) -> Iterable[int]:
    """Box counts of every shelf in a scene.json (racks -> shelves -> boxes)."""
    if not isinstance(scene, dict):
        return
    for rack in scene.get("racks") or []:
        if not isinstance(rack, dict):
            continue
        for shelf in rack.get("shelves") or []:
            if isinstance(shelf, dict) and isinstance(shelf.get("boxes"), list):
                yield len(shelf["boxes"])


def summarise(dataset: Any, max_frames: int = 200, progress: bool = True) -> dict[str, Any]:
    """Figures describing a dataset; pixel fractions are measured on up to ``max_frames`` frames."""
    if isinstance(max_frames, bool) or not isinstance(max_frames, int) or max_frames < 1:
        raise InputError(f"--max-frames must be a positive integer, got {max_frames!r}")
    seqs = dataset.sequences()
    order = {name: k for k, name in enumerate(("train", "val", "test"))}
    splits: dict[str, dict[str, int]] = {}
    for s in sorted(seqs, key=lambda q: (order.get(q.split, len(order)), q.split)):
        d = splits.setdefault(s.split, {"sequences": 0, "frames": 0})
        d["sequences"] += 1
        d["frames"] += s.num_frames
    sem_hist = np.zeros(256, np.int64)
    lay_hist = {"top": np.zeros(256, np.int64), "front": np.zeros(256, np.int64)}
    visible_shelves = []
    sample = _sample_frames(seqs, max_frames)
    for seq, i in tqdm(sample, desc="inspect", unit="frame", disable=not progress, leave=False):
        sem_hist += np.bincount(np.asarray(seq.semantic(i), np.uint8).ravel(), minlength=256)
        lay = seq.layouts(i)
        lay_hist["top"] += np.bincount(lay.top.ravel(), minlength=256)
        lay_hist["front"] += np.bincount(lay.front.ravel(), minlength=256)
        visible_shelves.append(int((lay.top > 0).any(axis=(1, 2)).sum()))
    scenes = [s.scene() for s in seqs]
    counts = [c for sc in scenes for c in _iter_boxes_per_shelf(sc)]
    w, h = dataset.image_size
    total = int(sem_hist.sum())
    return {
        "root": str(dataset.root),
        "seed": int(dataset.seed),
        "image_size": [int(w), int(h)],
        "spec": dataset.spec.to_dict(),
        "splits": splits,
        "sequences": len(seqs),
        "frames": sum(s.num_frames for s in seqs),
        "frames_measured": len(sample),
        "semantic_fractions": {
            SEMANTIC_NAMES.get(c, str(c)): float(sem_hist[c]) / max(1, total)
            for c in range(256)
            if sem_hist[c] or c < NUM_SEMANTIC
        },
        "layout_fractions": {
            v: {CLASS_NAMES[c]: float(hh[c]) / max(1, int(hh.sum())) for c in sorted(CLASS_NAMES)}
            for v, hh in lay_hist.items()
        },
        "visible_shelves_per_frame": _stats(visible_shelves),
        "boxes_per_shelf": _stats(counts),
        # rays per pixel side whose mean colour each pixel is (1: one ray at its centre)
        "supersample": int(dataset.config.get("sensor", {}).get("supersample", 1)),
        # the fraction of a step the shutter stays open, one per sequence (0: sharp)
        "motion_blur": _range([float(s.meta.get("camera", {}).get("motion_blur", 0.0)) for s in seqs]),
        # what the sequences' looks change (waresynth.look; scene.json "look"), {} when every one is neutral
        "look": _look_summary([sc.get("look", {}) for sc in scenes]),
        # the cameras' horizontal fields of view (degrees), one per sequence (camera.hfov_deg)
        "hfov_deg": _range([float(s.intrinsics.hfov_deg) for s in seqs]),
        # the cameras' rotations (degrees; each 0 for a level camera), one per sequence
        "camera_angles": {
            k.removesuffix("_deg"): _range([s.camera_angles[j] for s in seqs]) for j, k in enumerate(CAMERA_ANGLE_KEYS)
        },
    }


def _look_summary(looks: list[dict[str, Any]]) -> dict[str, Any]:
    """How many sequences have a look, the spans of its light level, noise and lens, and the codecs' counts."""
    if not any(looks):
        return {}
    out: dict[str, Any] = {"sequences": sum(bool(lk) for lk in looks), "of": len(looks)}
    for key, neutral in (("level", 1.0), ("shot_noise", 0.0), ("read_noise", 0.0), ("lens_k1", 0.0)):
        out[key] = _range([float(lk.get(key, neutral)) for lk in looks])
    codecs = [lk.get("compression", "none") for lk in looks]
    out["compression"] = {c: codecs.count(c) for c in sorted(set(codecs))}
    return out


def _range(values: list[float]) -> list[float]:
    return [min(values), max(values)] if values else [0.0, 0.0]


def _stats(values: list[int]) -> dict[str, float]:
    if not values:
        return {"count": 0}
    a = np.asarray(values, np.float64)
    return {
        "count": int(a.size),
        "mean": float(a.mean()),
        "min": float(a.min()),
        "median": float(np.median(a)),
        "max": float(a.max()),
    }


def format_summary(s: dict[str, Any]) -> str:
    """Human-readable text of a `summarise` result."""
    spec = s["spec"]
    lines = [
        f"dataset      {s['root']}  (seed {s['seed']})",
        f"sequences    {s['sequences']}, frames {s['frames']}, image {s['image_size'][0]}x{s['image_size'][1]}",
    ]
    for name, d in s["splits"].items():
        lines.append(f"  {name:<10} {d['sequences']:4d} sequences  {d['frames']:6d} frames")
    lines.append(
        f"layout spec  R={spec['num_slots']} slots, D={spec['size']} px, x {spec['x_extent']:.2f} m, "
        f"z {spec['z_extent']:.2f} m, h {spec['h_extent']:.2f} m"
    )
    if s.get("supersample", 1) > 1:
        k = s["supersample"]
        lines.append(f"pixels       area-sampled: each the mean colour of {k} x {k} rays (sensor.supersample)")
    blur = s.get("motion_blur", [0.0, 0.0])
    if any(blur):
        lines.append(
            f"pixels       motion-blurred: the shutter open {blur[0]:.2f}"
            + (f" to {blur[1]:.2f}" if blur[1] != blur[0] else "")
            + " of a step (sensor.motion_blur)"
        )
    look = s.get("look")
    if look:
        codecs = ", ".join(f"{c} {n}" for c, n in look["compression"].items())
        lines.append(
            f"look         {look['sequences']} of {look['of']} sequences (waresynth.look): light level "
            + ", ".join(f"{k} {r[0]:.2f} to {r[1]:.2f}" for k, r in look.items() if isinstance(r, list)).removeprefix(
                "level "
            )
            + f"; compression {codecs}"
        )
    fov = s.get("hfov_deg")
    if fov:
        span = f"{fov[0]:.1f}" + (f" to {fov[1]:.1f}" if fov[1] - fov[0] > 0.05 else "")
        lines.append(f"camera       {span} deg horizontal field of view (camera.hfov_deg)")
    turned = {k: r for k, r in s.get("camera_angles", {}).items() if any(r)}
    if turned:
        lines.append(
            "camera       turned: "
            + ", ".join(f"{k} {r[0]:g}" + (f" to {r[1]:g}" if r[1] != r[0] else "") + " deg" for k, r in turned.items())
        )
    lines.append(f"pixel fractions over {s['frames_measured']} frames (percent):")
    lines.append("  semantic   " + "  ".join(f"{k} {100 * v:.1f}" for k, v in s["semantic_fractions"].items()))
    for v, fr in s["layout_fractions"].items():
        lines.append(f"  {v + ' view':<10} " + "  ".join(f"{k} {100 * x:.1f}" for k, x in fr.items()))
    vs = s["visible_shelves_per_frame"]
    if vs["count"]:
        lines.append(
            f"shelf slots with a shelf per frame: mean {vs['mean']:.2f}, min {vs['min']:.0f}, max {vs['max']:.0f}"
        )
    b = s["boxes_per_shelf"]
    if b["count"]:
        lines.append(
            f"boxes per shelf (scene.json, {b['count']} shelves): mean {b['mean']:.2f}, min {b['min']:.0f}, "
            f"median {b['median']:.1f}, max {b['max']:.0f}"
        )
    else:
        lines.append("boxes per shelf: no shelves found in scene.json")
    return "\n".join(lines)
