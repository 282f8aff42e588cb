"""Long-aisle benchmark: stitching time and memory against the number of frames.

    .venv/bin/python benchmarks/bench_long_aisle.py                       # 1k, 5k and 10k frames, D=128
    .venv/bin/python benchmarks/bench_long_aisle.py --frames 1000 2000 --no-memory

For each frame count N, a synthetic row of racks long enough for N camera steps of ``--step``
metres is generated (`stitching.synthetic.long_aisle`, every density of box placement and yaw
the synthetic generator draws), and its ground-truth layouts are rasterised one frame at a time
(`stitching.synthetic.stream_frames`; rendering is not timed). Two passes per N:

* time: `Stitcher.push` per frame (detect + lift + shift + merge), wall clock and process CPU time
  (the machine may be shared, so CPU time is the steadier figure); per-frame CPU time over the
  first and the last tenth of the frames (equal when the cost per frame does not grow with
  the map), and the time of building the final `WarehouseMap`;
* memory (``tracemalloc``, slower, so timed separately): what the stitcher holds after N frames,
  split into the per-frame step records (the camera path; `MergeConfig.keep_steps` bounds it)
  and the map itself, and the peak over the run (transient per-frame arrays included).

The map size is printed alongside: fused map boxes (before the end-of-run clean-up), rack ends,
shelf-strip bins, and the boxes/racks of the final map.
"""

from __future__ import annotations

import argparse
import gc
import sys
import time
import tracemalloc
from pathlib import Path

_ROOT = Path(__file__).resolve().parents[1]
if str(_ROOT) not in sys.path:
    sys.path.insert(0, str(_ROOT))

from layouts.spec import LayoutSpec  # noqa: E402
from stitching.merge import MergeConfig  # noqa: E402
from stitching.pipeline import StitchConfig, Stitcher  # noqa: E402
from stitching.synthetic import long_aisle, stream_frames  # noqa: E402


def map_size(st: Stitcher) -> dict:
    b = st.builder
    return {
        "map_boxes": sum(len(s) for s in b.boxes),
        "rack_ends": len(b.ends),
        "strip_bins": int(b.votes.size),
        "steps_kept": len(b.steps),
    }


def time_pass(scene, xs, spec: LayoutSpec, config: StitchConfig) -> dict:
    st = Stitcher(spec, config)
    per, cpu = [], []
    for i, fl in enumerate(stream_frames(scene, spec, xs)):
        t0, c0 = time.perf_counter(), time.process_time()
        st.push(fl, i)
        per.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    t0 = time.perf_counter()
    wmap = st.map()
    t_map = time.perf_counter() - t0
    n = len(per)
    k = max(1, n // 10)
    return {
        "frames": n,
        "push_s": sum(per),
        "push_cpu_s": sum(cpu),
        "ms_first": 1e3 * sum(cpu[:k]) / k,
        "ms_last": 1e3 * sum(cpu[-k:]) / k,
        "map_s": t_map,
        "boxes": len(wmap.boxes()),
        "racks": len(wmap.racks),
        "row_m": wmap.meta["step_summary"]["offset_range"][1],
        **map_size(st),
    }


def memory_pass(scene, xs, spec: LayoutSpec, config: StitchConfig) -> dict:
    gc.collect()
    tracemalloc.start()
    base = tracemalloc.get_traced_memory()[0]
    st = Stitcher(spec, config)
    for i, fl in enumerate(stream_frames(scene, spec, xs)):
        st.push(fl, i)
    del fl
    st.map()
    gc.collect()
    held, peak = tracemalloc.get_traced_memory()
    st.builder.steps.clear()
    gc.collect()
    without_steps = tracemalloc.get_traced_memory()[0]
    tracemalloc.stop()
    return {
        "held_mb": (held - base) / 2**20,
        "steps_mb": (held - without_steps) / 2**20,
        "map_mb": (without_steps - base) / 2**20,
        "peak_mb": (peak - base) / 2**20,
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", type=int, nargs="+", default=[1000, 5000, 10000], help="frame counts to run")
    ap.add_argument("--size", type=int, default=128, help="layout resolution D")
    ap.add_argument("--step", type=float, default=0.1, help="camera step per frame, metres")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--keep-steps", type=int, default=None, help="bound the step records kept (default: all)")
    ap.add_argument("--no-memory", action="store_true", help="skip the tracemalloc pass")
    args = ap.parse_args()
    if any(n < 10 for n in args.frames) or args.step <= 0 or args.size < 16:
        ap.error("--frames must be >= 10, --step > 0, --size >= 16")

    spec = LayoutSpec(size=args.size)
    config = StitchConfig(merge=MergeConfig(keep_steps=args.keep_steps))
    kept = "all" if args.keep_steps is None else args.keep_steps
    print(f"long aisle: D={spec.size}, {args.step} m per frame, seed {args.seed}, step records kept: {kept}")
    rows = []
    for n in args.frames:
        scene, xs = long_aisle(args.seed, n, spec, args.step)
        r = time_pass(scene, xs, spec, config)
        if not args.no_memory:
            r.update(memory_pass(scene, xs, spec, config))
        rows.append(r)
        line = (
            f"{n:>6d} frames ({r['row_m']:.0f} m, {r['racks']} racks, {r['boxes']} boxes): "
            f"push {r['push_s']:.1f} s wall, {r['push_cpu_s']:.1f} s CPU = {1e3 * r['push_cpu_s'] / n:.2f} ms/frame CPU "
            f"(first 10% {r['ms_first']:.2f}, last 10% {r['ms_last']:.2f}); map build {r['map_s']:.2f} s; "
            f"map: {r['map_boxes']} fused boxes, {r['rack_ends']} rack ends, {r['strip_bins']} strip bins"
        )
        if not args.no_memory:
            line += (
                f"; memory held {r['held_mb']:.2f} MiB (map {r['map_mb']:.2f}, step records {r['steps_mb']:.2f}), "
                f"peak {r['peak_mb']:.2f} MiB"
            )
        print(line, flush=True)
    if len(rows) > 1:
        a, b = rows[0], rows[-1]
        print(
            f"scaling {a['frames']} -> {b['frames']} frames (x{b['frames'] / a['frames']:.1f}): "
            f"push CPU time x{b['push_cpu_s'] / a['push_cpu_s']:.2f}, map boxes x{b['map_boxes'] / max(a['map_boxes'], 1):.2f}"
            + ("" if args.no_memory else f", map memory x{b['map_mb'] / max(a['map_mb'], 1e-9):.2f}")
        )
        if not args.no_memory:
            kb = [1024 * r["map_mb"] / max(r["map_boxes"], 1) for r in rows]
            print("map memory per fused box: " + ", ".join(f"{k:.2f} KiB" for k in kb))
    return 0


if __name__ == "__main__":
    sys.exit(main())
