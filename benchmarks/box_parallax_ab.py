"""Does the box-depth head read box depths better with the plane-sweep parallax among its inputs?

One cache of the head's inputs with the parallax maps (`network.heads.boxdepth.ParallaxHistory`) over the
first N training sequences, then two heads fitted on it with the same seed and schedule: one on the
window without the parallax channels (the shipped head's inputs), one with them. Writes both as
checkpoints (``OUT/without.pt``, ``OUT/with.pt``) for `mvracklay evaluate` / `eval-reconstruction`.

    python benchmarks/box_parallax_ab.py weights/mvracklay-disc-4.pt --data data/train128b \
        --sequences 1500 --out runs/boxpar --cache-dir runs
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

from network.checkpoint import load_checkpoint, model_from, save_with_head
from network.heads.boxdepth import PARALLAX_CHANNELS, BoxDepthHead
from network.training.fit_boxdepth import Cache, FitConfig, box_head_config, cache_inputs, train_head, with_box_head
from network.training.trainer import open_data
from waresynth.visibility import SeenTracker


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("checkpoint", type=Path)
    ap.add_argument("--data", type=Path, nargs="+", required=True)
    ap.add_argument("--sequences", type=int, default=1500)
    ap.add_argument("--epochs", type=int, default=3)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--cache-dir", type=Path)
    ap.add_argument("--seed", type=int, default=0, help="both heads' initial weights and batch order")
    ap.add_argument("--threads", type=int, default=2)
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    args.out.mkdir(parents=True, exist_ok=True)
    payload, record = load_checkpoint(args.checkpoint)
    model = with_box_head(model_from(payload, record, args.checkpoint), parallax=True)
    train = [s for root in args.data for s in open_data(root).sequences(None)][: args.sequences]
    cfg = FitConfig(epochs=args.epochs, seed=args.seed)
    results = {}
    with tempfile.TemporaryDirectory(prefix="box-parallax-", dir=args.cache_dir) as tmp:
        t0 = time.perf_counter()
        data = cache_inputs(model, train, SeenTracker, Path(tmp))
        print(f"cached {len(data)} slots in {(time.perf_counter() - t0) / 60:.1f} min", flush=True)
        c_all = data.win.shape[1]
        for name, channels in (("without", c_all - PARALLAX_CHANNELS), ("with", c_all)):
            t1 = time.perf_counter()
            part = Cache(data.win[:, :channels], data.extra, data.back, data.shown)
            torch.manual_seed(cfg.seed)
            head = BoxDepthHead(channels, data.extra.shape[1])
            losses = train_head(head, part, cfg)
            minutes = (time.perf_counter() - t1) / 60
            info = {
                "data": [str(d) for d in args.data], "train_sequences": len(train), "train_slots": len(data),
                "shown_fraction": float(np.mean(data.shown[np.isfinite(data.back)])), "epochs": cfg.epochs,
                "seed": cfg.seed, "losses": losses, "fit_minutes": minutes, "parallax": name == "with",
            }  # fmt: skip
            mcfg = box_head_config(model.cfg, parallax=name == "with")
            save_with_head(args.out / f"{name}.pt", payload, record, mcfg, "box_depth", head, "box_depth", info)
            results[name] = {"losses": losses, "fit_minutes": minutes}
            print(f"{name}: losses {', '.join(f'{v:.3f}' for v in losses)} ({minutes:.1f} min)", flush=True)
        del data, part
    (args.out / "fit.json").write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
