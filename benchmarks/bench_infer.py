"""Inference speed: frames/s of streaming vs windowed prediction on CPU threads.

Streaming: one encoder pass and one ConvLSTM step per frame (what ``mvracklay predict`` does).
Windowed (cached): the paper's window of seq_len frames from a fresh state per frame, reusing
cached encoder features. Windowed (recompute): the naive form that re-encodes the whole window.
Stream-flip (asked for with --modes): streaming with the test-time flip average (two passes per frame).
Speed does not depend on the weights, so the model is built from its config (random weights)
unless --checkpoint is given. Images are fed at the model's input size (no resize). On a shared machine the best of several
passes is the figure least disturbed by other processes; the median is printed beside it.
--compete N measures each case again beside N busy processes (one core each, started for that
measurement and stopped after it) and prints the idle and competing frames/s and their ratio; the
process sets OpenMP's wait policy as the command line does (`mvracklay.threads.quiet_openmp`) unless
--openmp inherit leaves the environment as it is (libgomp's default: idle threads spin a while).

    .venv/bin/python benchmarks/bench_infer.py --threads 2 --sizes 128 256 --frames 40
    .venv/bin/python benchmarks/bench_infer.py --checkpoint mvracklay-disc-4 --sizes 128 --modes stream \
        --threads 2 --frames 30 --repeats 3 --compete 2
    .venv/bin/python benchmarks/bench_infer.py --threads 2 --sizes 256 --modes stream --precision bf16
    .venv/bin/python benchmarks/bench_infer.py --threads 2 --sizes 256 --modes stream --runtime torch  # TorchScript
    .venv/bin/python benchmarks/bench_infer.py --threads 2 --checkpoint mvracklay-disc-4-256 --sizes 256 --modes stream \
        --sequence data/s256/seq_00000 --frames 40   # a generated sequence's frames
    python benchmarks/bench_infer.py --device cuda --checkpoint mvracklay-disc-4   # on a GPU
"""

from __future__ import annotations

import argparse
import atexit
import contextlib
import os
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
_GIVEN = dict(os.environ)  # before `mvracklay` sets OpenMP's wait policy on import

from mvracklay.threads import OPENMP_ENV, quiet_openmp, resolve_threads  # noqa: E402

_pre = argparse.ArgumentParser(add_help=False)
_pre.add_argument("--openmp", default="passive")
if _pre.parse_known_args()[0].openmp == "inherit":  # the environment as given, torch not loaded yet
    for _key in OPENMP_ENV:
        if _key not in _GIVEN:
            os.environ.pop(_key, None)
else:
    quiet_openmp()  # before torch loads libgomp, as `mvracklay` does

import numpy as np  # noqa: E402
import torch  # noqa: E402

from layouts.fileio import atomic_write_json  # noqa: E402
from mvracklay.models import checkpoint_arg  # noqa: E402
from mvracklay.settings import ComputeSettings, InferenceSettings, add_options  # noqa: E402
from network.checkpoint import load_model  # noqa: E402
from network.inference.predictor import Predictor  # noqa: E402
from network.model import frozen  # noqa: E402
from network.model.config import VARIANTS, ModelConfig  # noqa: E402
from network.model.net import MVRackLay  # noqa: E402
from network.model.ortgraph import RUNTIMES, default_runtime  # noqa: E402


def sync(device: torch.device) -> None:
    """Wait for the device's queued work (GPU kernels run asynchronously; a pass ends when they finish)."""
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def bench(pred: Predictor, frames: list[np.ndarray], mode: str, repeats: int, warmup: int = 4) -> list[float]:
    """frames/s of each of ``repeats`` passes over ``frames`` (after a warm-up)."""
    run = {
        "stream": lambda f: pred.stream(f),
        "window": lambda f: pred.window(f),
        "window-recompute": lambda f: pred.window(f, recompute=True),
        "stream-flip": lambda f: Predictor(
            pred.model, pred.camera, flip=True, fuse_tau=pred.fuse_tau, roll=pred.roll, pitch=pred.pitch, yaw=pred.yaw
        ).stream(f),
    }[mode]
    for _ in run(frames[:warmup]):
        pass
    sync(pred.device)
    out = []
    for _ in range(repeats):
        t = time.perf_counter()
        n = sum(1 for _ in run(frames))
        sync(pred.device)
        out.append(n / (time.perf_counter() - t))
    return out


#: what a competing process runs: one core kept busy
BUSY = "while True: pass"


@contextlib.contextmanager
def competing(n: int) -> Iterator[list[subprocess.Popen]]:
    """``n`` busy processes for the duration of the block, killed at its end (and at exit, whatever happens)."""
    procs: list[subprocess.Popen] = []

    def stop() -> None:
        for p in procs:
            if p.poll() is None:
                p.kill()
        for p in procs:
            with contextlib.suppress(Exception):
                p.wait(timeout=5)

    atexit.register(stop)
    try:
        for _ in range(n):
            procs.append(subprocess.Popen([sys.executable, "-c", BUSY], stdin=subprocess.DEVNULL))
        time.sleep(0.2 if n else 0.0)  # let them start spinning
        yield procs
    finally:
        stop()
        atexit.unregister(stop)


def _where(device: torch.device, threads: int) -> str:
    if device.type == "cuda":
        return f"{torch.cuda.get_device_name(device)} ({device})"
    return f"{threads} CPU threads"


def _compete(
    pred: Predictor, frames: list, mode: str, repeats: int, n: int, best: float, med: float, auto: bool
) -> dict:
    """The case measured again beside ``n`` busy processes; its figures and their ratios to the idle ones.
    ``auto``: ``--threads auto`` resolved again once they run, as a command started then would."""
    idle_threads = torch.get_num_threads()
    with competing(n) as procs:
        if auto:
            torch.set_num_threads(resolve_threads("auto"))
        used = torch.get_num_threads()
        try:
            fps = bench(pred, frames, mode, repeats)
        finally:
            torch.set_num_threads(idle_threads)
    cbest, cmed = max(fps), float(np.median(fps))
    print(
        f"{'':9}beside {n} busy{f' ({used} threads)' if auto else ''}   best {cbest:7.1f}  median {cmed:7.1f} frames/s  "
        f"(competing / idle: best {cbest / best:.2f}, median {cmed / med:.2f})"
    )
    return {
        "compete": n,
        "compete_pids": [p.pid for p in procs],  # stopped by now
        "compete_threads": used,
        "fps_compete_best": cbest,
        "fps_compete_median": cmed,
        "ratio_best": cbest / best,
        "ratio_median": cmed / med,
    }


def sequence_frames(folder: Path, size: int, count: int) -> list[np.ndarray]:
    """``count`` RGB frames of a generated sequence (its ``rgb/*.png``, looped), each resized to ``size`` square."""
    from PIL import Image

    paths = sorted((folder / "rgb").glob("*.png"))
    if not paths:
        raise SystemExit(f"bench_infer.py: error: --sequence {folder}: no rgb/*.png frames (a generated sequence?)")
    out = []
    for i in range(count):
        with Image.open(paths[i % len(paths)]) as im:
            out.append(np.asarray(im.convert("RGB").resize((size, size), Image.BILINEAR)))
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument(
        "--checkpoint",
        type=checkpoint_arg,
        help="use this checkpoint's config (and weights): a path or a shipped model's name",
    )
    ap.add_argument("--variant", choices=sorted(VARIANTS), default="mvracklay-disc-4")
    ap.add_argument("--sizes", type=int, nargs="+", default=[128, 256], help="square input sizes")
    ap.add_argument("--threads", default="2", help="CPU threads for torch: a count or auto (the free cores)")
    ap.add_argument(
        "--compete",
        type=int,
        default=0,
        metavar="N",
        help="also measure beside N busy processes and print idle vs competing frames/s and their ratio",
    )
    ap.add_argument(
        "--openmp",
        choices=["passive", "inherit"],
        default="passive",
        help="passive (default): OMP_WAIT_POLICY=PASSIVE unless set, as mvracklay does; inherit: the environment "
        "as it is (libgomp's default spin-wait)",
    )
    ap.add_argument("--frames", type=int, default=40)
    ap.add_argument("--repeats", type=int, default=3, help="passes per case; the best and median are shown")
    ap.add_argument(
        "--modes",
        nargs="+",
        default=["stream", "window", "window-recompute"],
        choices=["stream", "window", "window-recompute", "stream-flip"],
        help="stream-flip: streaming with the test-time flip average (--flip-average)",
    )
    add_options(ap, InferenceSettings, only=("fuse_tau", "roll", "pitch", "yaw"))
    ap.add_argument("--device", default="cpu", help="torch device to run on: cpu (default), cuda, cuda:1, ...")
    ap.add_argument(
        "--no-graphs",
        action="store_true",
        help="run the network's modules, not its frozen graphs (network/model/frozen.py), to see what they buy",
    )
    add_options(ap, ComputeSettings, only=("precision",))
    ap.add_argument(
        "--runtime",
        choices=RUNTIMES,
        default=None,
        help="the graphs' runtime (network/model/ortgraph.py): auto (default, as commands load models: ONNX Runtime "
        "where installed, unless MVRACKLAY_RUNTIME says otherwise), torch (TorchScript) or onnx",
    )
    ap.add_argument(
        "--sequence",
        type=Path,
        help="stream this generated sequence's frames (resized to each size, looped to --frames) instead of random "
        "images: real frames show the shelves the readers work on (random ones show three slots every frame)",
    )
    ap.add_argument("--json", type=Path, help="also write the figures here")
    args = ap.parse_args()
    try:
        device = torch.device(args.device)
    except RuntimeError as e:
        ap.error(f"--device: {e}")
    if device.type == "cuda" and not torch.cuda.is_available():
        ap.error("--device: CUDA was asked for but torch sees no GPU")
    if args.compete < 0:
        ap.error(f"--compete must be >= 0, got {args.compete}")
    auto = str(args.threads).strip().lower() == "auto"
    runtime = args.runtime or default_runtime()
    try:
        args.threads = resolve_threads(args.threads)
    except ValueError as e:
        ap.error(str(e))
    torch.set_num_threads(args.threads)
    torch.manual_seed(0)
    if args.checkpoint:
        base, _ = load_model(args.checkpoint)
        cfg = base.cfg
    else:
        base, cfg = None, ModelConfig(variant=args.variant)
    rng = np.random.default_rng(0)
    rows = []
    camera = "".join(
        f", camera {w} {v}" for w, v in (("roll", args.roll), ("pitch", args.pitch), ("yaw", args.yaw)) if v
    )
    print(
        f"torch {torch.__version__}, {_where(device, args.threads)}, variant {cfg.variant}, encoder width {cfg.encoder_width}, "
        f"layouts {cfg.spec.shape}{f', neighbouring frames fused with tau {args.fuse_frames:g}' if args.fuse_frames else ''}"
        f"{camera}{', modules (no frozen graphs)' if args.no_graphs else ''}"
        f"{', the trunk in bf16' if args.precision == 'bf16' and not args.no_graphs and device.type == 'cpu' else ''}"
        f", runtime {runtime}, OMP_WAIT_POLICY {os.environ.get('OMP_WAIT_POLICY', 'unset')}"
    )
    line = frozen.precision_warning(args.precision)
    if line:
        print(f"warning: {line}", file=sys.stderr)
    for size in args.sizes:
        c = replace(cfg, input_width=size, input_height=size)
        model = base if base is not None and c == cfg else MVRackLay(c).eval()
        model.frozen_graphs = not args.no_graphs
        frozen.set_precision(model, args.precision)
        frozen.set_runtime(model, runtime)
        pred = Predictor(model.to(device), fuse_tau=args.fuse_frames, roll=args.roll, pitch=args.pitch, yaw=args.yaw)
        frames = (
            sequence_frames(args.sequence, size, args.frames)
            if args.sequence
            else [rng.integers(0, 256, (size, size, 3), dtype=np.uint8) for _ in range(args.frames)]
        )
        for mode in args.modes:
            fps = bench(pred, frames, mode, args.repeats)
            best, med = max(fps), float(np.median(fps))
            print(f"{size}x{size}  {mode:<17} best {best:7.1f}  median {med:7.1f} frames/s")
            row = {
                "size": size,
                "mode": mode,
                "fps_best": best,
                "fps_median": med,
                "threads": args.threads,
                "device": str(device),
                "graphs": not args.no_graphs,
                "precision": frozen.trunk_precision(model),  # what ran: bf16 on the CPU's graphs only
                # what ran the trunk: onnx or torch (its graph or, without graphs or on a GPU, the modules)
                "runtime": frozen.graph_runtime(model) if frozen.graphs_held(model) else "torch",
                "graphs_built": frozen.graphs_held(model),  # what ran: 0 for the modules alone
                "omp_wait_policy": os.environ.get("OMP_WAIT_POLICY"),
                "frames_from": str(args.sequence) if args.sequence else "random",
            }
            if args.compete:
                row.update(_compete(pred, frames, mode, args.repeats, args.compete, best, med, auto))
            rows.append(row)
    if args.json:
        atomic_write_json(args.json, rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())
