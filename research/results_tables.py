#!/usr/bin/env python3
"""Print the README's results tables (Markdown) from the JSON files the default-128 recipe writes.

    .venv/bin/python research/results_tables.py runs

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


def _label(run: Path) -> str:
    """The run's variant (from its record; the folder name without one), with " (unaligned memory)"
    for a sequence run trained before the slot memory followed the camera."""
    record = run / "best.json"
    if not record.is_file():
        return run.name
    model = json.loads(record.read_text()).get("model_config", {})
    variant = model.get("variant", run.name)
    unaligned = variant != "racklay" and not model.get("align_memory", False)
    return variant + (" (unaligned memory)" if unaligned else "")


def table1(runs: Path) -> list[str]:
    dirs = {
        v: runs / v for v in ("mvracklay-disc-4", "mvracklay-4", "mvracklay-disc-8", "_unaligned-disc-4", "racklay")
    }
    d4, mv4, d8, old, rl = ((_label(p), p) for p in dirs.values())
    out = [
        "| model | top rack | top box | front rack | front box | slot count right |",
        "|---|---|---|---|---|---|",
    ]
    for name, path in [
        (f"{d4[0]}, calibrated (windowed)", d4[1] / "table1_calibrated.json"),
        (f"{d4[0]}, calibrated (streaming)", d4[1] / "table1_calibrated_stream.json"),
        (f"{d4[0]}, calibrated, flip-averaged (windowed)", d4[1] / "table1_calibrated_flip.json"),
        (f"{d4[0]}, calibrated, flip-averaged (streaming)", d4[1] / "table1_calibrated_flip_stream.json"),
        (f"{mv4[0]}, calibrated", mv4[1] / "table1_calibrated.json"),
        (f"{d8[0]}, calibrated", d8[1] / "table1_calibrated.json"),
        (f"{old[0]}, calibrated", old[1] / "table1_calibrated.json"),
        (f"{rl[0]}, calibrated", rl[1] / "table1_calibrated.json"),
        (f"{d4[0]}, raw argmax (windowed)", d4[1] / "table1_window.json"),
        (f"{d4[0]}, raw argmax (streaming)", d4[1] / "table1_stream.json"),
        (f"{mv4[0]}, raw argmax", mv4[1] / "table1_window.json"),
        (f"{d8[0]}, raw argmax", d8[1] / "table1_window.json"),
        (f"{old[0]}, raw argmax", old[1] / "table1_window.json"),
        (f"{rl[0]}, raw argmax", rl[1] / "table1_window.json"),
        ("depth projection (ground-truth depth + masks)", runs / "baseline_depth.json"),
        (f"{d4[0]}, true shelf boards (analysis)", d4[1] / "table1_true_anchors.json"),
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
