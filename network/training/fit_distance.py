"""Train the `DistanceReader` on generated frames (stage ``fit-distance`` of ``mvracklay train``).

Every sample is a frame resampled at a *wrong* assumed distance ``d0 = d * exp(-t)`` with ``t`` drawn per
sample (half from a narrow normal around 0, where the last reading round works, half uniform over
``±T_WIDE``, where the first works), so the target ``t = log(d / d0)`` is learned from how sizes look,
not from where the generator's distances lie. The floor target is ``camera height * d0 / d`` (canonical
metres) where the floor line is in view. Frames are mirrored at random, their colours jittered and about
half JPEG-compressed (footage is).

Validation: the held-back splits read from the default distance as `read_distance` reads footage; the
median and 90th-percentile absolute error (%) are printed and recorded with the weights.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from layouts.errors import InputError
from network.data import colour_jitter, jpeg_round_trip
from network.inference.distance import read_distances, save_reader
from network.model.distance import DistanceReader, DistanceReaderConfig
from network.preprocess import canonical_image, to_tensor

#: half of the samples' log-ratio targets: uniform over +-T_WIDE; the other half normal with sd T_NARROW
T_WIDE = 0.35
T_NARROW = 0.05


def load_frames(datasets: list[Path], splits: tuple[str, ...]) -> tuple[list[np.ndarray], np.ndarray, np.ndarray, list]:
    """Every frame of ``splits``: RGB, distance, camera height above the floor, and the intrinsics."""
    from network.training.train_data import open_generated

    rgb, dist, height, intr = [], [], [], []
    for data, split in ((d, sp) for d in datasets for sp in splits):
        for seq in open_generated(data).sequences(split):
            for i in range(len(seq)):
                rec = seq.frame(i)
                rgb.append(seq.rgb(i))
                dist.append(float(rec["distance"]))
                height.append(-float(rec["camera_position"][1]))
                intr.append(seq.intrinsics)
    if not rgb:
        raise InputError(f"{', '.join(map(str, datasets))}: no frames in splits {', '.join(splits)}")
    return rgb, np.array(dist), np.array(height), intr


def make_batch(frames, dist, height, intrs, idx, reader_cfg: DistanceReaderConfig, rng: np.random.Generator):
    """Images ``(B, 3, S, S)`` and targets ``(B, 3)``: log ratio, floor_y (canonical metres), floor in view."""
    view = reader_cfg.view
    half = reader_cfg.x_extent / 2
    imgs, targets = [], []
    for k in idx:
        t = rng.normal(0.0, T_NARROW) if rng.random() < 0.5 else rng.uniform(-T_WIDE, T_WIDE)
        d0 = dist[k] / np.exp(t)
        img = canonical_image(frames[k], view, intrs[k], d0)
        if rng.random() < 0.5:
            img = jpeg_round_trip(img, int(rng.integers(60, 96)))
        if rng.random() < 0.5:
            img = img[:, ::-1]
        floor_y = height[k] * d0 / dist[k]
        v = intrs[k].cy + intrs[k].fy * height[k] / dist[k]
        seen = float(v < intrs[k].height - 1 and floor_y < half - 0.02)
        imgs.append(img)
        targets.append((t, floor_y, seen))
    x = colour_jitter(np.stack(imgs).astype(np.float32), rng)
    return to_tensor(x.round().clip(0, 255).astype(np.uint8)), torch.tensor(targets, dtype=torch.float32)


def loss_of(reader: DistanceReader, out: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    """Smooth L1 on the log ratio; where the floor is in view, cross entropy of its row against a soft
    target (a Gaussian of one row around the true continuous row); BCE on "in view"."""
    seen = y[:, 2]
    scale = F.smooth_l1_loss(out[:, 0] * 10, y[:, 0] * 10)
    rows = out[:, 2:]
    true_row = y[:, 1] / reader.row_metres + rows.shape[1] / 2  # continuous, bins from the top
    centres = torch.arange(rows.shape[1], dtype=rows.dtype) + 0.5
    target = torch.exp(-0.5 * ((centres[None] - true_row[:, None]) / 0.7) ** 2)
    target = target / target.sum(1, keepdim=True).clamp(min=1e-9)
    ce = -(target * rows.log_softmax(dim=1)).sum(1)
    floor = (ce * seen).sum() / seen.sum().clamp(min=1)
    return scale + 0.5 * floor + 0.2 * F.binary_cross_entropy_with_logits(out[:, 1], seen)


def validate(reader: DistanceReader, frames, dist, intrs) -> dict[str, float]:
    """Reading errors (%) from the default start, frame by frame."""
    reader.eval()
    d = np.concatenate(
        [read_distances(reader, frames[i : i + 32], intrs[i], 2.6)[0] for i in range(0, len(frames), 32)]
    )
    err = np.abs(d / dist - 1) * 100
    reader.train()
    return {"median_error_pct": float(np.median(err)), "p90_error_pct": float(np.percentile(err, 90))}


def fit(
    data: list[Path], out: Path, steps: int = 2400, batch: int = 32, seed: int = 0, threads: int = 2
) -> dict[str, float]:
    """Train a reader on ``data``'s train splits, validate on their val and test splits, write it to ``out``."""
    if steps < 1 or batch < 2:
        raise InputError(f"steps must be >= 1 and batch >= 2, got {steps} and {batch}")
    torch.manual_seed(seed)
    torch.set_num_threads(threads)
    rng = np.random.default_rng(seed)
    frames, dist, height, intrs = load_frames(data, ("train",))
    vframes, vdist, _, vintrs = load_frames(data, ("val", "test"))
    cfg = DistanceReaderConfig()
    reader = DistanceReader(cfg)
    opt = torch.optim.AdamW(reader.parameters(), lr=2e-3, weight_decay=1e-4)
    sched = torch.optim.lr_scheduler.OneCycleLR(opt, max_lr=2e-3, total_steps=steps, pct_start=0.1)
    t0 = time.perf_counter()
    for step in range(1, steps + 1):
        x, y = make_batch(frames, dist, height, intrs, rng.integers(0, len(frames), batch), cfg, rng)
        loss = loss_of(reader, reader(x), y)
        opt.zero_grad()
        loss.backward()
        opt.step()
        sched.step()
        if step % 100 == 0 or step == steps:
            print(f"step {step}/{steps} loss {loss.item():.4f} {time.perf_counter() - t0:.0f} s", file=sys.stderr)
    figures = validate(reader, vframes, vdist, vintrs)
    save_reader(
        out,
        reader,
        {
            "data": [str(d) for d in data],
            "frames": len(frames),
            "steps": steps,
            "batch": batch,
            "seed": seed,
            "validation": figures,
        },
    )
    return figures
