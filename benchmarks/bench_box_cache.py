"""Speed of the box-depth head's cache pass: frames/s streamed and slots kept per second.

The `fit-box-depth` stage of a training recipe spends most of its minutes streaming the frozen network over the training
scenes (`network.training.box_cache.cache_inputs`); the scenes a fixed number of minutes holds is what the
head's quality follows (docs/training.md, *The budget (budget-256)*). This times that pass
alone on the first ``--sequences`` scenes of ``--data``, streaming their first ``--frames`` frames and
keeping the slots from ``--from-frame`` on, as the fit does; the best of ``--repeats`` passes is the
figure least disturbed by other processes. ``--workers N`` splits the pass over N processes of one
thread each (`network.training.box_cache.cache_part`, `fit-box-depth --cache-workers N`); ``--threads`` is then
the parent's and unused by the pass.

    .venv/bin/python benchmarks/bench_box_cache.py runs/budget256b/mvracklay-disc-4/calibrated.pt \\
        data/train256b --sequences 20 --frames 6 --from-frame 3 --parallax --threads 1
    #   ... --threads 2 (one process on both cores), --workers 2 (two processes of one thread),
    #   --precision bf16 (the trunk's graph in bf16, as fit-box-depth --precision bf16 streams it),
    #   --cold-start (the frames before --from-frame skip the network, as fit-box-depth --cold-start)
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from layouts.errors import InputError  # noqa: E402
from layouts.fileio import atomic_write_json  # noqa: E402
from mvracklay.models import checkpoint_arg  # noqa: E402
from mvracklay.settings import ComputeSettings, add_options  # noqa: E402
from network.checkpoint import load_checkpoint, model_from  # noqa: E402
from network.model.frozen import trunk_precision, use_precision  # noqa: E402
from network.training.box_cache import FrameChoice, StreamedPass, cache_part  # noqa: E402
from network.training.fit_box_depth import with_box_head  # noqa: E402
from network.training.train_data import open_data  # noqa: E402
from waresynth.visibility import SeenTracker  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument(
        "checkpoint", type=checkpoint_arg, help="a trained checkpoint or a shipped model's name (its trunk is streamed)"
    )
    ap.add_argument("data", type=Path, help="a generated dataset folder (scenes with depth and instances)")
    ap.add_argument("--sequences", type=int, default=20, help="scenes streamed (the first ones)")
    ap.add_argument("--frames", type=int, help="stream only each scene's first N frames (default: all)")
    ap.add_argument("--from-frame", type=int, default=0, help="keep the slots of frames K on")
    ap.add_argument("--cold-start", action="store_true", help="the frames before --from-frame skip the network")
    ap.add_argument("--parallax", action="store_true", help="a head that reads the plane-sweep maps")
    ap.add_argument("--threads", type=int, default=1, help="torch threads of a one-process pass")
    ap.add_argument("--workers", type=int, default=1, help="processes of one thread each sharing the pass")
    ap.add_argument("--repeats", type=int, default=2, help="passes; the best is shown")
    add_options(ap, ComputeSettings, only=("precision",))
    ap.add_argument("--json", type=Path, help="also write the figures here")
    args = ap.parse_args(argv)
    try:
        if args.sequences < 1 or args.threads < 1 or args.repeats < 1 or args.workers < 1:
            raise InputError("--sequences, --threads, --workers and --repeats must be >= 1")
        choice = FrameChoice(args.frames, args.from_frame, args.cold_start)
        choice.validate()
        torch.set_num_threads(args.threads)
        payload, record = load_checkpoint(args.checkpoint)
        model = with_box_head(model_from(payload, record, args.checkpoint), parallax=args.parallax)
        use_precision(model, args.precision)
        seqs = open_data(args.data).sequences(None)[: args.sequences]
        if not seqs:
            raise InputError(f"{args.data}: no sequences")
        frames = sum(choice.streamed(s) for s in seqs)
        rates = []
        for _ in range(args.repeats):
            with tempfile.TemporaryDirectory(prefix="bench-box-cache-") as tmp:
                t = time.perf_counter()
                caches = cache_part(StreamedPass(model, SeenTracker, choice, False, args.workers), seqs, Path(tmp))[0]
                dt = time.perf_counter() - t
                slots = sum(len(c) for c in caches)
                del caches  # the memory maps closed before the folder goes
            rates.append(frames / dt)
    except InputError as e:
        print(f"bench_box_cache.py: {e}", file=sys.stderr)
        return 2
    best = max(rates)
    out = {"sequences": len(seqs), "frames": frames, "cold_start": args.cold_start, "slots": slots, "threads": args.threads, "workers": args.workers,
           "precision": trunk_precision(model),
           "frames_per_s": rates, "best_frames_per_s": best, "best_ms_per_frame": 1000 / best}  # fmt: skip
    how = f"{args.workers} processes of 1 thread" if args.workers > 1 else f"{args.threads} thread(s)"
    how += ", the frames before K skipping the network" if args.cold_start else ""
    print(f"{len(seqs)} scenes, {frames} frames streamed, {slots} slots kept, {how}, the trunk in {trunk_precision(model)}: "
          f"{best:.2f} frames/s best ({1000 / best:.0f} ms a frame; passes: "
          + ", ".join(f"{r:.2f}" for r in rates) + ")")  # fmt: skip
    if args.json:
        atomic_write_json(args.json, out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
