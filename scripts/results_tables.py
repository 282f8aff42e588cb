#!/usr/bin/env python3
"""Print the README's results tables (Markdown) from the JSON files `scripts/train_default.sh` writes.

    .venv/bin/python scripts/results_tables.py runs

Table I: mIoU / "mAP" (mean pixel precision) in percent, per-(frame, slot) averages over the
columns in view, for every trained variant, the depth-projection baseline, and the paper's figures
(their data). Reconstruction: stitched maps against the generator's cuboids. Sequence runs trained
before the slot memory followed the camera are labelled "unaligned memory"; the earlier default
model's run, if kept as RUNS/_unaligned-disc-4, is listed beside the current one.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

CELLS = [("top", "rack"), ("top", "box"), ("front", "rack"), ("front", "box")]
#: the paper's Table I (MVRackLay paper, their dataset and GPU): (mIoU, mAP) per cell
PAPER = {
    "MVRackLay-Disc-4 (paper, their data)": [(96.44, 98.01), (86.89, 92.70), (94.98, 97.14), (88.02, 93.49)],
    "RackLay (paper, their data)": [(93.44, 94.98), (82.80, 85.47), (91.75, 93.10), (83.28, 85.49)],
}


def _cells(table: dict) -> list[tuple[float, float]]:
    return [(100 * table[v][c]["miou"], 100 * table[v][c]["map"]) for v, c in CELLS]


def _row(name: str, cells: list[tuple[float, float]], extra: str = "") -> str:
    return f"| {name} | " + " | ".join(f"{m:.1f} / {p:.1f}" for m, p in cells) + f" |{extra}"


def _memory_note(run: Path) -> str:
    """' (unaligned memory)' for a sequence run trained before the slot memory followed the camera."""
    record = run / "best.json"
    if not record.is_file():
        return ""
    model = json.loads(record.read_text()).get("model_config", {})
    if model.get("variant", "racklay") != "racklay" and not model.get("align_memory", False):
        return " (unaligned memory)"
    return ""


def table1(runs: Path) -> list[str]:
    mv4, disc8 = (_memory_note(runs / v) for v in ("mvracklay-4", "mvracklay-disc-8"))
    old = runs / "_unaligned-disc-4"
    out = [
        "| model | top rack | top box | front rack | front box | slot count right |",
        "|---|---|---|---|---|---|",
    ]
    for name, path in [
        ("mvracklay-disc-4, calibrated (windowed)", runs / "mvracklay-disc-4" / "table1_calibrated.json"),
        ("mvracklay-disc-4, calibrated (streaming)", runs / "mvracklay-disc-4" / "table1_calibrated_stream.json"),
        (f"mvracklay-4{mv4}, calibrated", runs / "mvracklay-4" / "table1_calibrated.json"),
        (f"mvracklay-disc-8{disc8}, calibrated", runs / "mvracklay-disc-8" / "table1_calibrated.json"),
        ("mvracklay-disc-4 (unaligned memory), calibrated", old / "table1_calibrated.json"),
        ("racklay, calibrated", runs / "racklay" / "table1_calibrated.json"),
        ("mvracklay-disc-4, raw argmax (windowed)", runs / "mvracklay-disc-4" / "table1_window.json"),
        ("mvracklay-disc-4, raw argmax (streaming)", runs / "mvracklay-disc-4" / "table1_stream.json"),
        (f"mvracklay-4{mv4}, raw argmax", runs / "mvracklay-4" / "table1_window.json"),
        (f"mvracklay-disc-8{disc8}, raw argmax", runs / "mvracklay-disc-8" / "table1_window.json"),
        ("mvracklay-disc-4 (unaligned memory), raw argmax", old / "table1_window.json"),
        ("racklay, raw argmax", runs / "racklay" / "table1_window.json"),
        ("depth projection (ground-truth depth + masks)", runs / "baseline_depth.json"),
        ("mvracklay-disc-4, true shelf boards (analysis)", runs / "mvracklay-disc-4" / "table1_true_anchors.json"),
    ]:
        if path.is_file():
            d = json.loads(path.read_text())
            acc = d.get("slot_count_accuracy")
            out.append(_row(name, _cells(d["visible"]), f" {100 * acc:.1f} % |" if acc is not None else " – |"))
    for name, cells in PAPER.items():
        out.append(_row(name, cells, " – |"))
    return out


def reconstruction(runs: Path) -> list[str]:
    out = [
        "| layouts | stacks | recall | precision | mean 3D IoU | count exact | free-length error | drift mean / max |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for name, path in [
        ("ground truth", runs / "reconstruction_gt.json"),
        ("mvracklay-disc-4, calibrated (streaming)", runs / "reconstruction_mvracklay-disc-4.json"),
        ("racklay, calibrated", runs / "reconstruction_racklay.json"),
        ("mvracklay-disc-4 (unaligned memory), calibrated", runs / "_unaligned_reconstruction_mvracklay-disc-4.json"),
        ("mvracklay-disc-4, raw argmax (streaming)", runs / "reconstruction_mvracklay-disc-4_raw.json"),
        ("racklay, raw argmax", runs / "reconstruction_racklay_raw.json"),
    ]:
        if path.is_file():
            s = json.loads(path.read_text())["summary"]
            out.append(
                f"| {name} | {s['tp'] + s['fn']} | {s['recall']:.3f} | {s['precision']:.3f} | {s['mean_iou']:.3f} | "
                f"{100 * s['count_accuracy']:.1f} % | {100 * s['free_length_mae']:.1f} cm | "
                f"{100 * s['drift_end_mean']:.1f} / {100 * s['drift_end_max']:.1f} cm |"
            )
    return out


def main(argv: list[str]) -> int:
    if len(argv) != 1 or not Path(argv[0]).is_dir():
        print("usage: results_tables.py RUNS_DIR", file=sys.stderr)
        return 2
    runs = Path(argv[0])
    print("\n".join(table1(runs)))
    print()
    print("\n".join(reconstruction(runs)))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
