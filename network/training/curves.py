"""Learning curves as a PNG (validation mIoU against training minutes), drawn with Pillow alone.

`plot_curves` reads runs' ``metrics.jsonl`` (warm-started runs shifted by their source's minutes) and draws one panel per view x class (top/front x
rack/box), one line per run. The recipe stage ``curves`` (`mvracklay.training.small_stages`) draws them from
the shell: ``python -m mvracklay.training.stages curves [--from X] [--x {cpu-minutes,wall-minutes,steps}] OUT.png
LABEL=RUN_DIR ...`` (``--from`` keeps the points from that x on).
"""

from __future__ import annotations

import io
import json
import math
from pathlib import Path

from PIL import Image, ImageDraw

from layouts.errors import InputError
from layouts.fileio import atomic_write_bytes

PANELS = [("top", "rack"), ("top", "box"), ("front", "rack"), ("front", "box")]
COLOURS = [(31, 119, 180), (214, 39, 40), (44, 160, 44), (148, 103, 189), (255, 127, 14), (23, 190, 207)]


def read_metrics(path: str | Path) -> list[dict]:
    path = Path(path)
    if path.is_dir():
        path = path / "metrics.jsonl"
    if not path.is_file():
        raise InputError(f"{path}: metrics file not found")
    try:
        return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]
    except json.JSONDecodeError as e:
        raise InputError(f"{path}: not JSON lines ({e.msg})") from None


def start_offset(run: str | Path, x_key: str = "train_cpu_minutes") -> float:
    """Minutes a warm-started run had before its first step (its source's, from ``RUN/last.json``)."""
    rec = Path(run) / "last.json"
    if not rec.is_file():
        return 0.0
    try:
        src = json.loads(rec.read_text()).get("init_from") or {}
    except (json.JSONDecodeError, AttributeError):
        return 0.0
    v = src.get(x_key) if isinstance(src, dict) else None
    return float(v) if isinstance(v, (int, float)) else 0.0


def _round_up(x: float) -> float:
    """The smallest of 5 x (1, 2, 4, 5, 8) x 10^k that covers ``x``: five round x ticks."""
    step = 10 ** math.floor(math.log10(x / 5))
    for m in (1, 2, 4, 5, 8, 10):
        if 5 * m * step >= x - 1e-9:
            return 5 * m * step
    return 50 * step


LEGEND_PER_ROW = 4


def _y_axis(data: dict, view: str, cls: str, ylo_all: float, zoom: bool) -> tuple[float, float, list[float]]:
    """(low, high, ticks) of a panel's mIoU axis: whole tenths shared by all panels from ``ylo_all``
    to 1, or (``zoom``) this panel's own data range in steps of 0.02 (0.05 when wide)."""
    if not zoom:
        return ylo_all, 1.0, [t / 10 for t in range(round(ylo_all * 10), 11)]
    vals = [e["val_visible"][view][cls]["miou"] for es in data.values() for e in es]
    vals = [x for x in vals if x is not None] or [0.0, 1.0]
    step = 0.02 if max(vals) - min(vals) <= 0.12 else 0.05
    lo = max(0.0, math.floor(min(vals) / step - 1e-9) * step)
    hi = min(1.0, math.ceil(max(vals) / step + 1e-9) * step)
    hi = hi if hi > lo else lo + step
    return lo, hi, [lo + step * t for t in range(round((hi - lo) / step) + 1)]


def plot_curves(
    runs: dict[str, str | Path], out: str | Path, x_key: str = "train_cpu_minutes", x_from: float = 0.0
) -> None:
    """Draw validation (visible-column) mIoU per panel against ``x_key`` for each run; write ``out``.

    A warm-started run's curve starts where its source's training ended (`start_offset`), so
    every x is the total training the weights have had. ``x_from`` > 0 draws only the points from
    that x on (to compare runs that branch late), with the y axis zoomed to them.
    """
    if not math.isfinite(x_from) or x_from < 0:
        raise InputError(f"x_from: must be a finite number >= 0, got {x_from}")
    data = {}
    for label, p in runs.items():
        off = start_offset(p, x_key) if Path(p).is_dir() else 0.0
        entries = [e for e in read_metrics(p) if "val_visible" in e]
        if any(not isinstance(e.get(x_key), (int, float)) for e in entries):
            raise InputError(f"{p}: a validation entry has no number under {x_key!r}")
        data[label] = [{**e, x_key: e[x_key] + off} for e in entries if e[x_key] + off >= x_from]
    pw, ph, m = 420, 260, 50
    legend_rows = max(1, math.ceil(len(data) / LEGEND_PER_ROW))
    img = Image.new("RGB", (2 * pw, 2 * ph + 20 + 20 * legend_rows), "white")
    d = ImageDraw.Draw(img)
    xmax = _round_up(max([e[x_key] for es in data.values() for e in es] + [x_from + 1e-6]))
    xmin = x_from if x_from < xmax else 0.0
    all_vals = [e["val_visible"][v][c]["miou"] for es in data.values() for e in es for v, c in PANELS]
    ylo_all = max(0.0, math.floor(min([x for x in all_vals if x is not None], default=0.0) * 10 - 1e-9) / 10)
    for k, (view, cls) in enumerate(PANELS):
        ox, oy = (k % 2) * pw, (k // 2) * ph
        ylo, yhi, ticks = _y_axis(data, view, cls, ylo_all, zoom=x_from > 0)
        x0, y0, x1, y1 = ox + m, oy + 20, ox + pw - 15, oy + ph - 35
        d.rectangle([x0, y0, x1, y1], outline="black")
        d.text((x0, oy + 4), f"{view} {cls} mIoU (validation scenes, columns in view)", fill="black")
        for t in ticks:
            y = y1 - (y1 - y0) * (t - ylo) / (yhi - ylo)
            d.line([x0 - 4, y, x0, y], fill="black")
            d.text((x0 - 34, y - 6), f"{t:.2f}" if x_from > 0 else f"{t:.1f}", fill="black")
            d.line([x0, y, x1, y], fill=(230, 230, 230))
        for t in range(6):
            x = x0 + (x1 - x0) * t / 5
            xv = xmin + (xmax - xmin) * t / 5
            d.line([x, y1, x, y1 + 4], fill="black")
            d.text((x - 10, y1 + 6), f"{xv:.0f}" if xmax >= 20 else f"{xv:.1f}", fill="black")
        d.text((x1 - 120, y1 + 18), x_key.replace("_", " "), fill="black")
        for i, es in enumerate(data.values()):
            pts = []
            for e in es:
                v = e["val_visible"][view][cls]["miou"]
                if v is None:
                    continue
                pts.append(
                    (x0 + (x1 - x0) * (e[x_key] - xmin) / (xmax - xmin), y1 - (y1 - y0) * (v - ylo) / (yhi - ylo))
                )
            col = COLOURS[i % len(COLOURS)]
            if len(pts) > 1:
                d.line(pts, fill=col, width=2)
            for x, y in pts:
                d.ellipse([x - 2, y - 2, x + 2, y + 2], fill=col)
    for i, label in enumerate(data):
        col = COLOURS[i % len(COLOURS)]
        x, y = 20 + (i % LEGEND_PER_ROW) * 205, 2 * ph + 15 + 20 * (i // LEGEND_PER_ROW)
        d.rectangle([x, y, x + 14, y + 12], fill=col)
        d.text((x + 20, y), label, fill="black")
    buf = io.BytesIO()
    img.save(buf, format="PNG")
    atomic_write_bytes(out, buf.getvalue())


#: the x axes the curves are drawn against: name -> the metrics' key
X_AXES = {"cpu-minutes": "train_cpu_minutes", "wall-minutes": "train_wall_minutes", "steps": "step"}
