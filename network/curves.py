"""Learning curves as a PNG (validation mIoU against training minutes), drawn with Pillow alone.

`plot_curves` reads runs' ``metrics.jsonl`` (warm-started runs shifted by their source's minutes) and draws one panel per view x class (top/front x
rack/box), one line per run. ``python -m network.curves OUT.png LABEL=RUN_DIR ...`` does it
from the shell.
"""

from __future__ import annotations

import io
import json
import math
import sys
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


def plot_curves(runs: dict[str, str | Path], out: str | Path, x_key: str = "train_cpu_minutes") -> None:
    """Draw validation (visible-column) mIoU per panel against ``x_key`` for each run; write ``out``.

    A warm-started run's curve starts where its source's training ended (`start_offset`), so
    every x is the total training the weights have had.
    """
    data = {}
    for label, p in runs.items():
        off = start_offset(p, x_key) if Path(p).is_dir() else 0.0
        data[label] = [{**e, x_key: e[x_key] + off} for e in read_metrics(p) if "val_visible" in e]
    pw, ph, m = 420, 260, 50
    img = Image.new("RGB", (2 * pw, 2 * ph + 40), "white")
    d = ImageDraw.Draw(img)
    xmax = _round_up(max([e[x_key] for es in data.values() for e in es] + [1e-6]))
    vals = [e["val_visible"][v][c]["miou"] for es in data.values() for e in es for v, c in PANELS]
    vals = [x for x in vals if x is not None]
    # Zoom the y axis to the data (whole tenths), so a few points' difference shows.
    ylo = max(0.0, math.floor(min(vals, default=0.0) * 10 - 1e-9) / 10)
    for k, (view, cls) in enumerate(PANELS):
        ox, oy = (k % 2) * pw, (k // 2) * ph
        x0, y0, x1, y1 = ox + m, oy + 20, ox + pw - 15, oy + ph - 35
        d.rectangle([x0, y0, x1, y1], outline="black")
        d.text((x0, oy + 4), f"{view} {cls} mIoU (validation scenes, columns in view)", fill="black")
        for t in range(round(ylo * 10), 11):
            y = y1 - (y1 - y0) * (t / 10 - ylo) / (1.0 - ylo)
            d.line([x0 - 4, y, x0, y], fill="black")
            d.text((x0 - 30, y - 6), f"{t / 10:.1f}", fill="black")
            d.line([x0, y, x1, y], fill=(230, 230, 230))
        for t in range(6):
            x = x0 + (x1 - x0) * t / 5
            d.line([x, y1, x, y1 + 4], fill="black")
            d.text((x - 10, y1 + 6), f"{xmax * t / 5:.0f}" if xmax >= 20 else f"{xmax * t / 5:.1f}", fill="black")
        d.text((x1 - 120, y1 + 18), x_key.replace("_", " "), fill="black")
        for i, es in enumerate(data.values()):
            pts = []
            for e in es:
                v = e["val_visible"][view][cls]["miou"]
                if v is None:
                    continue
                pts.append((x0 + (x1 - x0) * e[x_key] / xmax, y1 - (y1 - y0) * (v - ylo) / (1.0 - ylo)))
            col = COLOURS[i % len(COLOURS)]
            if len(pts) > 1:
                d.line(pts, fill=col, width=2)
            for x, y in pts:
                d.ellipse([x - 2, y - 2, x + 2, y + 2], fill=col)
    for i, label in enumerate(data):
        col = COLOURS[i % len(COLOURS)]
        x = 20 + i * 200
        d.rectangle([x, 2 * ph + 15, x + 14, 2 * ph + 27], fill=col)
        d.text((x + 20, 2 * ph + 15), label, fill="black")
    buf = io.BytesIO()
    img.save(buf, format="PNG")
    atomic_write_bytes(out, buf.getvalue())


def main(argv: list[str]) -> int:
    if len(argv) < 2 or any("=" not in a for a in argv[1:]):
        print("usage: python -m network.curves OUT.png LABEL=RUN_DIR [LABEL=RUN_DIR ...]", file=sys.stderr)
        return 2
    runs = dict(a.split("=", 1) for a in argv[1:])
    try:
        plot_curves(runs, argv[0])
    except InputError as e:
        print(f"network.curves: error: {e}", file=sys.stderr)
        return 2
    print(f"wrote {argv[0]}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
