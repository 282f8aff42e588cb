"""Benchmark WareSynth generation: images/s at 512x512 with every annotation written to disk.

Each image counts once, together with its depth, semantic and instance PNGs, its layout file
and its share of meta.json/scene.json. Prints images/s (wall clock, including process start-up
of the workers) and the peak resident memory of this process and of its largest worker. Without
``--config`` it runs twice, the default look and the shipped wide look (`waresynth/configs/wide_look.json`),
and prints both rates side by side.

    .venv/bin/python benchmarks/bench_generate.py --sequences 4 --frames 50 --workers 2
    .venv/bin/python benchmarks/bench_generate.py ... --config turned.json   # one run: a turned camera
    .venv/bin/python benchmarks/bench_generate.py ... --config shifted_look  # one run: a shipped config
"""

from __future__ import annotations

import argparse
import os
import resource
import shutil
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from layouts.spec import LayoutSpec  # noqa: E402
from waresynth.generate import DatasetSettings, generate_dataset  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sequences", type=int, default=4)
    ap.add_argument("--frames", type=int, default=50)
    ap.add_argument("--size", type=int, default=512, help="image width and height")
    ap.add_argument("--layout-size", type=int, default=128)
    ap.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, default=None, help="keep the dataset here (default: a temporary folder)")
    ap.add_argument(
        "--config", type=Path, default=None, help="one run with this generator config (a file or a shipped name)"
    )
    args = ap.parse_args()
    runs = [args.config] if args.config is not None else [None, Path("wide_look")]
    rates = {}
    for config in runs:
        label = "default" if config is None else str(config)
        print(f"--- {label}")
        rates[label] = _run(args, config)
    if len(rates) > 1:
        print("images/s: " + "   ".join(f"{k} {v:.1f}" for k, v in rates.items()))
    return 0


def _run(args: argparse.Namespace, config: Path | None) -> float:
    """One generation with ``config``; prints what it cost and returns images/s."""
    tmp = None
    out = args.out
    stats: list[dict] = []
    if out is None:
        tmp = tempfile.mkdtemp(prefix="bench_waresynth_")
        out = Path(tmp) / "data"
    try:
        t0 = time.perf_counter()
        generate_dataset(
            out,
            DatasetSettings(
                num_sequences=args.sequences,
                frames=args.frames,
                image_size=(args.size, args.size),
                spec=LayoutSpec(size=args.layout_size),
                seed=args.seed,
                config=config,
                workers=args.workers,
                overwrite=True,
                progress=False,
            ),
            stats=stats,
        )
        wall = time.perf_counter() - t0
        n = args.sequences * args.frames
        size = sum(p.stat().st_size for p in out.rglob("*") if p.is_file())
    finally:
        if tmp:
            shutil.rmtree(tmp, ignore_errors=True)
    # Workers fork from a forkserver, so they are not this process's children: each reports its
    # own CPU time and peak RSS (getrusage RUSAGE_SELF) with every sequence it writes.
    cpu = sum(s["cpu_seconds"] for s in stats)
    own = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    child = max([resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024] + [s["max_rss_mib"] for s in stats])
    load = os.getloadavg()[0]
    print(f"command: {' '.join([Path(sys.executable).name, *sys.argv])}")
    print(
        f"images: {n} at {args.size}x{args.size} (rgb + depth + semantic + instance PNG, layouts {args.layout_size}), "
        f"workers {args.workers}, cpus {os.cpu_count()}, load average before exit {load:.2f}"
    )
    print(f"wall: {wall:.2f} s  ->  {n / wall:.1f} images/s   ({size / n / 1e6:.2f} MB per frame on disk)")
    print(
        f"cpu: {cpu:.2f} s in the sequence writers = {cpu / n * 1000:.0f} ms per image "
        f"-> at most {os.cpu_count() * n / cpu:.1f} images/s on {os.cpu_count()} idle cores (start-up excluded)"
    )
    print(f"peak memory (max RSS): main process {own:.0f} MiB, largest worker process {child:.0f} MiB")
    return n / wall


if __name__ == "__main__":
    sys.exit(main())
