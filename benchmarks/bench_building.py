"""Building-map benchmark: `mvracklay map --layouts gt` on buildings of 1, 5 and 10 aisles (2 faces of about
50 m each), time and peak memory against the number of passes, and local processes against a local Ray.

    .venv/bin/python benchmarks/bench_building.py                         # 1, 5, 10 aisles, 2 workers, + Ray
    .venv/bin/python benchmarks/bench_building.py --aisles 1 2 --no-ray   # quicker

Each building is generated once into the work folder (32x32 images, 128 px layouts, steps of 20-25 cm: the map reads
only the layouts): by default a fresh folder under the system's temporary folder, removed at the end unless
``--keep``; a ``--work`` folder given is kept, and a re-run with it reuses the buildings. Per size: the wall time of mapping every pass as a row and of placing,
registering and fusing them, the peak resident memory of the command and of a worker mapping a pass, and seconds per pass
(flat when the cost grows linearly with the passes). With Ray (``--ray-aisles``): the same map through a local
Ray of ``--workers`` CPUs against ``--workers`` local processes, as a ratio (Ray's start-up included once).
"""

from __future__ import annotations

import argparse
import resource
import shutil
import sys
import tempfile
import time
from pathlib import Path

_ROOT = Path(__file__).resolve().parents[1]
if str(_ROOT) not in sys.path:
    sys.path.insert(0, str(_ROOT))

from layouts.spec import LayoutSpec  # noqa: E402
from mvracklay.building_job import MapSettings, map_building  # noqa: E402
from mvracklay.settings import ComputeSettings, OutputSettings  # noqa: E402
from waresynth.building.generate import generate_building  # noqa: E402

FACE = {"bays": [19, 19], "bay_width": [2.3, 2.7], "bay_gap": [0.1, 0.2], "pass_length": 12.0}
CONFIG = {"camera": {"step": [0.2, 0.25]}}


def building(work: Path, aisles: int) -> Path:
    root = work / f"building_{aisles}"
    generate_building(root, building={**FACE, "aisles": aisles}, config=CONFIG, image_size=(32, 32),
                      spec=LayoutSpec(size=128), seed=aisles, workers=2, progress=False)  # fmt: skip
    return root


def peak_mb() -> float:
    """Peak resident memory (MB) of this process (the command: placing, registering, fusing, writing)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def time_map(root: Path, out: Path, workers: int, ray: str | None = None) -> dict:
    shutil.rmtree(out, ignore_errors=True)
    t0 = time.perf_counter()
    res = map_building(
        root,
        out,
        MapSettings(layouts="gt"),
        ComputeSettings(workers=workers, ray=ray),
        OutputSettings(rrd=False, quiet=True),
    )
    total = time.perf_counter() - t0
    passes = len(res.map.passes)
    return {"passes": passes, "seconds": total, "per_pass": total / passes, "boxes": res.map.box_count(),
            "worker_mb": res.worker_peak_mb}  # fmt: skip


def parser() -> argparse.ArgumentParser:
    """The benchmark's options, each described."""
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--aisles", type=int, nargs="+", default=[1, 5, 10], metavar="N",
                   help="the building sizes to map, in aisles of 2 faces (default: 1 5 10)")  # fmt: skip
    p.add_argument("--workers", type=int, default=2, metavar="W",
                   help="local processes mapping the passes, and the CPUs of the local Ray (default: 2)")  # fmt: skip
    p.add_argument("--work", type=Path, metavar="DIR",
                   help="where the buildings and maps go, kept for a re-run to reuse (default: a fresh folder under "
                   "the system's temporary folder, removed at the end)")  # fmt: skip
    p.add_argument("--keep", action="store_true", help="keep the default work folder (its path is printed)")
    p.add_argument(
        "--ray-aisles",
        type=int,
        default=5,
        metavar="N",
        help="the building size mapped through a local Ray too, against local processes (default: 5)",
    )
    p.add_argument("--no-ray", action="store_true", help="skip the local Ray comparison (no Ray needed)")
    return p


def main(argv: list[str] | None = None) -> int:
    args = parser().parse_args(argv)
    if args.work is not None:
        args.work.mkdir(parents=True, exist_ok=True)
        return run(args)
    args.work = Path(tempfile.mkdtemp(prefix="bench_building-"))
    try:
        return run(args)
    finally:
        if args.keep:
            print(f"work folder kept: {args.work}")
        else:
            shutil.rmtree(args.work, ignore_errors=True)


def run(args: argparse.Namespace) -> int:
    """The benchmark's table (and the Ray line) for ``args`` (`main`), in ``args.work``."""
    print(f"{'aisles':>6} {'passes':>6} {'boxes':>6} {'map_s':>7} {'s/pass':>7} {'peak_MB':>8} {'worker_MB':>10}")
    for a in args.aisles:
        root = building(args.work, a)
        r = time_map(root, args.work / f"map_{a}", args.workers)
        print(
            f"{a:>6} {r['passes']:>6} {r['boxes']:>6} {r['seconds']:>7.1f} {r['per_pass']:>7.2f} {peak_mb():>8.0f} "
            f"{r['worker_mb']:>10.0f}"
        )
    if not args.no_ray:
        root = building(args.work, args.ray_aisles)
        local = time_map(root, args.work / "map_local", args.workers)
        ray = time_map(root, args.work / "map_ray", args.workers, ray="local")
        print(
            f"{args.ray_aisles} aisles, {local['passes']} passes: local processes {local['seconds']:.1f} s, "
            f"local Ray {ray['seconds']:.1f} s (Ray / local = {ray['seconds'] / local['seconds']:.2f})"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
