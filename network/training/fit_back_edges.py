"""Fitting the back-edge head (`network.heads.backedge`) to a trained model, the rest of the network frozen.

The head reads the row head's column-pooled pyramid features, so one pass of the frozen trunk per
frame gives everything it needs: `cache_features` runs it once over the training sequences (and
keeps the row head's logits, for the depth read on validation sequences), `train_head` fits the
head to Gaussian bumps at the true back-edge rows (as the row head is fitted to the front edges),
and `depth_errors` measures what matters, the rack depth `DepthReader` reads per frame and over a
sequence. The targets come from the generator's ground truth: each visible board's height, the
camera pose and distance, the rack depth and the board thickness (scene.json).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from torch import nn
from tqdm import tqdm

from layouts.errors import InputError
from network.data import board_rows, row_target
from network.heads.backedge import BackEdgeHead, DepthReader, back_edge_rows
from network.inference.predictor import Predictor, sequence_camera
from network.model.decoders import board_peaks
from network.model.net import MVRackLay


@dataclass(frozen=True)
class FitConfig:
    """How the head is fitted (defaults: what was measured, docs/network.md)."""

    epochs: int = 20
    batch: int = 128
    lr: float = 2e-3
    weight_decay: float = 1e-2
    pos_weight: float = 5.0  #: BCE weight of the rare back-edge rows
    every: int = 1  #: use every N-th frame of a sequence
    seed: int = 0

    def validate(self) -> None:
        for name in ("epochs", "batch", "every"):
            v = getattr(self, name)
            if not isinstance(v, int) or isinstance(v, bool) or v < 1:
                raise InputError(f"--{name} must be a positive integer, got {v!r}")
        for name in ("lr", "pos_weight"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise InputError(f"--{name.replace('_', '-')} must be a positive number, got {v!r}")


@dataclass
class Cached:
    """Per frame: pooled features ``(N, C, H/2)`` (fp16), back-edge targets ``(N, H)``, row-head logits
    ``(N, H)``, and the sequence index, camera distance and true rack depth."""

    pooled: torch.Tensor
    target: torch.Tensor
    rows: torch.Tensor
    seq: np.ndarray
    distance: np.ndarray
    depth: np.ndarray


def rack_row(seq: Any, what: str = "the back-edge head") -> tuple[float, float]:
    """(rack depth, board thickness) of a generated sequence's scene, or a one-line error (fitting ``what``)."""
    try:
        row = seq.scene()["row"]
        return float(row["depth"]), float(row["board_thickness"])
    except (AttributeError, KeyError, TypeError, ValueError, OSError):
        name = getattr(seq, "root", getattr(seq, "name", "sequence"))
        raise InputError(f"{name}: fitting {what} needs a generated dataset (scene.json with the rack row)") from None


def frames_to_fit(model: MVRackLay, sequences: list[Any], every: int, head: str) -> int:
    """How many frames a head's fit reads (every ``every``-th of each sequence), ``model`` put in eval mode; one
    line when there are none."""
    model.eval()
    total = sum(len(range(0, s.num_frames, every)) for s in sequences)
    if not total:
        raise InputError(f"no frames to fit {head} on")
    return total


@torch.no_grad()
def cache_features(model: MVRackLay, sequences: list[Any], every: int = 1, progress: bool = True) -> Cached:
    """Run the frozen trunk over ``sequences`` (every ``every``-th frame) and keep what the head needs."""
    view, total = model.cfg.view, frames_to_fit(model, sequences, every, "the back-edge head")
    # one block per array, filled in place: many small per-sequence pieces fragment the heap (several x the memory)
    pooled: torch.Tensor | None = None
    rows = torch.empty((total, view.height))
    target = np.zeros((total, view.height), np.float32)
    seq_ids, dists, depths = np.zeros(total, np.int64), np.zeros(total), np.zeros(total)
    bar = tqdm(total=total, desc="back edges: features", unit="frame", disable=not progress, leave=False)
    n = 0
    for k, seq in enumerate(sequences):
        depth, thickness = rack_row(seq)
        camera = sequence_camera(seq)
        ids = list(range(0, seq.num_frames, every))
        pred = Predictor(model, camera, fuse_tau=0)  # the canonical warp of inference, so the head sees what it will
        x = torch.cat([pred.preprocess(seq.rgb(i), i) for i in ids])
        p = model.pooled_rows(x)
        if pooled is None:
            pooled = torch.empty((total, *p.shape[1:]), dtype=torch.float16)
        pooled[n : n + len(ids)] = p.half().cpu()
        rows[n : n + len(ids)] = model.rows.from_pooled(p).float().cpu()
        for j, i in enumerate(ids):
            dist = camera(i)[1]
            fronts = board_rows(seq, i, view, model.cfg.spec.num_slots)[1]
            back = back_edge_rows(fronts, view, dist, depth, thickness)[0]
            target[n + j] = row_target([float(r) for r in back if np.isfinite(r)], view.height)
            seq_ids[n + j], dists[n + j], depths[n + j] = k, dist, depth
        n += len(ids)
        bar.update(len(ids))
    bar.close()
    if pooled is None:  # unreachable: total > 0 means one sequence ran
        raise InputError("no frames to fit the back-edge head on")
    return Cached(pooled, torch.from_numpy(target), rows, seq_ids, dists, depths)


def fit_epochs(
    head: nn.Module,
    n: int,
    batch_loss: Callable[[torch.Tensor], torch.Tensor],
    cfg: FitConfig,
    desc: str,
    progress: bool = True,
) -> list[float]:
    """Fit ``head`` over ``n`` cached frames, ``batch_loss(indices)`` the loss of one batch (AdamW, cosine
    decay, batches in a seeded order); returns the mean loss per epoch. Shared by the column heads."""
    cfg.validate()
    gen = torch.Generator().manual_seed(cfg.seed)
    opt = torch.optim.AdamW(head.parameters(), cfg.lr, weight_decay=cfg.weight_decay)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, cfg.epochs)
    losses = []
    bar = tqdm(range(cfg.epochs), desc=desc, unit="epoch", disable=not progress, leave=False)
    for _ in bar:
        head.train()
        perm = torch.randperm(n, generator=gen)
        total = 0.0
        for i in range(0, n, cfg.batch):
            b = perm[i : i + cfg.batch]
            loss = batch_loss(b)
            opt.zero_grad()
            loss.backward()
            opt.step()
            total += float(loss.detach()) * len(b)
        sched.step()
        losses.append(total / n)
        bar.set_postfix(loss=f"{losses[-1]:.4f}")
    head.eval()
    return losses


def train_head(head: BackEdgeHead, data: Cached, cfg: FitConfig, progress: bool = True) -> list[float]:
    """Fit ``head`` to the cached targets (AdamW, cosine decay); returns the mean loss per epoch."""
    loss_fn = nn.BCEWithLogitsLoss(pos_weight=torch.tensor(cfg.pos_weight))
    return fit_epochs(
        head, data.pooled.shape[0], lambda b: loss_fn(head(data.pooled[b].float()), data.target[b]), cfg,
        "back edges: fit", progress,
    )  # fmt: skip


@torch.no_grad()
def head_probs(head: nn.Module, pooled: torch.Tensor) -> torch.Tensor:
    """The head's probabilities over cached pooled features, 256 frames at a time."""
    head.eval()
    return torch.sigmoid(torch.cat([head(pooled[i : i + 256].float()) for i in range(0, len(pooled), 256)]))


def reading_errors(
    seq: np.ndarray, depth: np.ndarray, read: Callable[[int, DepthReader], float | None], model: MVRackLay
) -> dict[str, Any]:
    """Errors of the rack depth ``read(k, reader)`` gives after adding cached frame ``k`` to ``reader``: per
    frame (a fresh reader), running (one reader per sequence ``seq[k]``) and at a sequence's end, against
    the true ``depth[k]`` (metres; None where nothing was read)."""
    view, z_extent = model.cfg.view, model.cfg.spec.z_extent
    frame_err, run_err, last = [], [], {}
    readers: dict[int, DepthReader] = {}
    for k in range(len(seq)):
        s = int(seq[k])
        one = read(k, DepthReader(view, z_extent))
        run = read(k, readers.setdefault(s, DepthReader(view, z_extent)))
        if one is not None:
            frame_err.append(abs(one - depth[k]))
        if run is not None:
            run_err.append(abs(run - depth[k]))
            last[s] = run - depth[k]
    return {
        "frames": len(seq),
        "sequences": len(readers),
        "mae_frame": float(np.mean(frame_err)) if frame_err else None,
        "mae_running": float(np.mean(run_err)) if run_err else None,
        "mae_sequence": float(np.mean(np.abs(list(last.values())))) if last else None,
        "read_fraction": len(run_err) / max(len(seq), 1),
    }


def depth_errors(head: BackEdgeHead, data: Cached, model: MVRackLay) -> dict[str, Any]:
    """Rack depth read on cached frames (the row head's boards, as at inference): mean absolute error
    per frame (that frame alone), running (the frames so far of its sequence) and at a sequence's end,
    in metres."""
    probs = head_probs(head, data.pooled).numpy()
    fronts = [board_peaks(r, model.cfg.view) for r in torch.sigmoid(data.rows)]
    return reading_errors(
        data.seq, data.depth, lambda k, reader: reader.add(probs[k], fronts[k], float(data.distance[k])), model
    )


def fit_head(
    model: MVRackLay,
    train: list[Any],
    val: list[Any],
    cfg: FitConfig,
    *,
    what: str,
    cache: Callable[[MVRackLay, list[Any], int, bool], Any],
    make_head: Callable[[Any], nn.Module],
    fit: Callable[[Any, Any, FitConfig, bool], list[float]],
    errors: Callable[[Any, Any, MVRackLay], dict[str, Any]],
    progress: bool = True,
) -> tuple[Any, dict[str, Any]]:
    """One column head fitted to ``model`` (its trunk unchanged): ``cache`` the frozen trunk's features of
    ``train``, ``make_head`` for them, ``fit`` it, and measure the depth read (``errors``) on the training
    and ``val`` frames; returns the head and a summary for the checkpoint's record."""
    cfg.validate()
    if not train:
        raise InputError(f"no training sequences to fit {what} on")
    torch.manual_seed(cfg.seed)
    t0 = time.perf_counter()
    data = cache(model, train, cfg.every, progress)
    head = make_head(data)
    losses = fit(head, data, cfg, progress)
    summary: dict[str, Any] = {
        "train_sequences": len(train),
        "train_frames": int(data.pooled.shape[0]),
        "epochs": cfg.epochs,
        "every": cfg.every,
        "seed": cfg.seed,
        "final_loss": losses[-1],
        "train_depth": errors(head, data, model),
    }
    if val:
        summary["val_depth"] = errors(head, cache(model, val, cfg.every, progress), model)
    summary["wall_minutes"] = (time.perf_counter() - t0) / 60
    return head, summary


def fit_back_edges(
    model: MVRackLay,
    train: list[Any],
    val: list[Any],
    cfg: FitConfig,
    progress: bool = True,
) -> tuple[BackEdgeHead, dict[str, Any]]:
    """A fitted head for ``model`` (its trunk unchanged) and a summary for the checkpoint's record."""
    return fit_head(
        model, train, val, cfg, what="the back-edge head", cache=cache_features,
        make_head=lambda data: BackEdgeHead(data.pooled.shape[1], model.cfg.input_height),
        fit=train_head, errors=depth_errors, progress=progress,
    )  # fmt: skip
