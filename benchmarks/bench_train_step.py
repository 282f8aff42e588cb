#!/usr/bin/env python3
"""Seconds per training step (forward, backward, Adam) of model configurations, on random data.

    .venv/bin/python benchmarks/bench_train_step.py --threads 2
    .venv/bin/python benchmarks/bench_train_step.py --threads 2 --widths 16 32 64 --sizes 128 256
    .venv/bin/python benchmarks/bench_train_step.py --threads 1 --precisions fp32 bf16

One step = ``--frames`` frames (4 windows of 4 for the sequence variants, 16 single frames for
racklay), supervised + row-head losses, without data loading or discriminators. Prints the
median of ``--repeats`` steps after two warm-up steps, the parameter count and the fp16 size.
``bf16`` runs the forward passes under bf16 autocast, as ``mvracklay train --precision bf16`` does.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from layouts import VIEWS, LayoutSpec  # noqa: E402
from network.model.config import VARIANTS, ModelConfig  # noqa: E402
from network.model.net import MVRackLay  # noqa: E402
from network.precision import PRECISIONS, forward_autocast  # noqa: E402
from network.training.losses import row_loss, supervised_loss  # noqa: E402


def step_seconds(cfg: ModelConfig, frames: int, repeats: int, precision: str = "fp32") -> float:
    torch.manual_seed(0)
    model = MVRackLay(cfg).train()
    opt = torch.optim.Adam(model.parameters(), lr=1e-4)
    t = cfg.seq_len
    b = max(1, frames // t)
    d, r = cfg.spec.size, cfg.spec.num_slots
    x = torch.rand(b, t, 3, cfg.input_height, cfg.input_width)
    rows = torch.linspace(0.8, 0.2, r) * cfg.input_height
    anchors = rows.expand(b, t, r).clone()
    target = {v: torch.randint(0, 3, (b, t, r, d, d)) for v in VIEWS}
    row_t = torch.zeros(b, t, cfg.input_height)
    times = []
    for i in range(repeats + 2):
        t0 = time.perf_counter()
        with forward_autocast("cpu", precision):
            out = model(x, anchors)
        out = {k: v.float() for k, v in out.items()}
        loss = sum(supervised_loss(out[v], target[v]) for v in VIEWS) + row_loss(out["rows"], row_t)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        if i >= 2:
            times.append(time.perf_counter() - t0)
    return statistics.median(times)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--variants", nargs="+", default=["racklay", "mvracklay-disc-4"], choices=sorted(VARIANTS))
    ap.add_argument("--widths", type=int, nargs="+", default=[32], help="encoder widths")
    ap.add_argument("--sizes", type=int, nargs="+", default=[128], help="square canonical input sizes")
    ap.add_argument("--precisions", nargs="+", default=["fp32"], choices=list(PRECISIONS))
    ap.add_argument("--frames", type=int, default=16)
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    print(f"torch {torch.__version__}, {args.threads} threads, {args.frames} frames per step")
    for variant in args.variants:
        for size in args.sizes:
            for width in args.widths:
                cfg = ModelConfig(
                    variant=variant, input_width=size, input_height=size, encoder_width=width, spec=LayoutSpec(size=64)
                )
                params = sum(p.numel() for p in MVRackLay(cfg).parameters())
                for precision in args.precisions:
                    s = step_seconds(cfg, args.frames, args.repeats, precision)
                    print(
                        f"{variant:<17} input {size}x{size}  width {width:>3}  {params / 1e6:5.2f} M params "
                        f"({2 * params / 2**20:5.1f} MiB fp16)  {precision}  "
                        f"{s:6.3f} s/step  {args.frames / s:6.1f} frames/s"
                    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
