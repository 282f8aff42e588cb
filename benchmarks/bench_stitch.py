"""Stitching benchmark: frames/s of detect+lift+shift+merge, and reconstruction accuracy.

    .venv/bin/python benchmarks/bench_stitch.py                  # generates what it needs in a temp folder
    .venv/bin/python benchmarks/bench_stitch.py --sequences 8 --frames 50

Speed: a generated 50-frame sequence with D=512 layouts, all frames loaded into memory first
(file reading is not timed), then `Stitcher.push` per frame; the best of ``--repeats`` runs,
as wall-clock and as process CPU time (the machine is shared, so both are printed), plus a
per-stage split. Accuracy: `mvracklay eval-reconstruction`'s figures on ``--sequences``
generated sequences (D=128) with ground-truth layouts, then with degraded layouts.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

_ROOT = Path(__file__).resolve().parents[1]
if str(_ROOT) not in sys.path:
    sys.path.insert(0, str(_ROOT))

from layouts.spec import LayoutSpec  # noqa: E402
from mvracklay.reconstruction_eval import Degrade, evaluate_sequence, summarise  # noqa: E402
from stitching.detect import DetectConfig, detect_frame  # noqa: E402
from stitching.lift import lift_frame  # noqa: E402
from stitching.merge import MapBuilder  # noqa: E402
from stitching.pipeline import StitchConfig, Stitcher  # noqa: E402


def speed(seq, repeats: int) -> dict:
    frames = [seq.layouts(i) for i in range(seq.num_frames)]
    spec = seq.spec
    best_wall = best_cpu = float("inf")
    for _ in range(repeats):
        st = Stitcher(spec)
        w0, c0 = time.perf_counter(), time.process_time()
        for i, fl in enumerate(frames):
            st.push(fl, i)
        best_wall = min(best_wall, time.perf_counter() - w0)
        best_cpu = min(best_cpu, time.process_time() - c0)
    # Per-stage split (one run).
    cfg = StitchConfig()
    builder = MapBuilder(spec, cfg.merge, cfg.shift, cfg.lift.board_thickness)
    t = {"detect": 0.0, "lift": 0.0, "shift+merge": 0.0}
    for fl in frames:
        a = time.process_time()
        det = detect_frame(fl.top, fl.front, spec, fl.visible, cfg.detect)
        b = time.process_time()
        rec = lift_frame(det, cfg.lift)
        c = time.process_time()
        builder.add(rec, fl.top)
        t["detect"] += b - a
        t["lift"] += c - b
        t["shift+merge"] += time.process_time() - c
    n = len(frames)
    return {
        "frames": n,
        "size": spec.size,
        "fps_wall": n / best_wall,
        "fps_cpu": n / best_cpu,
        "ms_per_stage": {k: 1e3 * v / n for k, v in t.items()},
    }


def accuracy(ds, label: str, config: StitchConfig | None, deg: Degrade | None) -> dict:
    results = [(s.name, evaluate_sequence(s, config=config, deg=deg)[0]) for s in ds.sequences()]
    s = summarise(results)
    print(
        f"{label:<40} recall {s['recall']:.3f}  precision {s['precision']:.3f}  mIoU {s['mean_iou']:.3f}  "
        f"TP {s['tp']:>3d} FP {s['fp']:>3d} FN {s['fn']:>3d}  count exact {s['count_accuracy']:.1%} of {s['shelves']}  "
        f"free-length MAE {s['free_length_mae']:.3f} m  drift end mean {100 * s['drift_end_mean']:.2f} cm, "
        f"max {100 * s['drift_end_max']:.2f} cm"
    )
    return s


def main() -> int:
    from waresynth.dataset import open_dataset
    from waresynth.generate import DatasetSettings, generate_dataset

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sequences", type=int, default=8, help="sequences for the accuracy figures")
    ap.add_argument("--frames", type=int, default=50)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--work", help="folder for the generated data (default: a temporary one)")
    args = ap.parse_args()

    with tempfile.TemporaryDirectory() as tmp:
        work = Path(args.work or tmp)
        big = generate_dataset(
            work / "d512",
            DatasetSettings(
                num_sequences=1,
                frames=args.frames,
                image_size=(64, 64),
                spec=LayoutSpec(size=512),
                seed=args.seed,
                progress=False,
            ),
        )
        acc = generate_dataset(
            work / "d128",
            DatasetSettings(
                num_sequences=args.sequences,
                frames=args.frames,
                image_size=(64, 64),
                spec=LayoutSpec(size=128),
                seed=args.seed + 1,
                progress=False,
            ),
        )
        seq = open_dataset(big).sequences()[0]
        sp = speed(seq, args.repeats)
        print(
            f"speed: {sp['frames']} frames at D={sp['size']}: {sp['fps_wall']:.0f} frames/s wall, "
            f"{sp['fps_cpu']:.0f} frames/s CPU time (detect+lift+shift+merge, best of {args.repeats})"
        )
        print("  ms/frame by stage (CPU): " + ", ".join(f"{k} {v:.2f}" for k, v in sp["ms_per_stage"].items()))
        print(f"accuracy on {args.sequences} generated sequences x {args.frames} frames (D=128), IoU >= 0.5:")
        ds = open_dataset(acc)
        accuracy(ds, "ground-truth layouts", None, None)
        accuracy(ds, "ground truth, no yaw fit (axis-aligned)", StitchConfig(detect=DetectConfig(fit_yaw=False)), None)
        noisy = StitchConfig.noisy()
        accuracy(ds, "dilated 1 px, 3% flips, 1 dropped", noisy, Degrade(1, 0.03, args.frames // 2, 1))
        accuracy(ds, "dilated 2 px, 5% flips, 1 dropped", noisy, Degrade(2, 0.05, args.frames // 2, 2))
        accuracy(ds, "eroded 2 px, 5% flips, 1 dropped", noisy, Degrade(-2, 0.05, args.frames // 2, 3))
        big_ds = open_dataset(big)
        accuracy(big_ds, "D=512 sequence, ground truth", None, None)
    return 0


if __name__ == "__main__":
    sys.exit(main())
