"""Fitting the upright head (`network.heads.uprights`) to a trained model, the rest of the network frozen.

The head reads row-pooled pyramid features, so one pass of the frozen trunk per frame gives all it
needs: `cache_features` runs it once over the training sequences, `train_head` fits the head to the
columns where the generator's semantic and depth images show front and rear uprights of the mapped
row (`waresynth.visibility.upright_faces`, sampled at the canonical pixels), and `depth_errors`
measures what matters, the rack depth the uprights give (`network.heads.backedge.DepthReader`) per frame,
over the frames so far and over a whole sequence.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from torch import nn
from tqdm import tqdm

from layouts.canonical import CanonicalView
from layouts.errors import InputError
from network.heads.uprights import UprightHead, pool_columns
from network.inference.predictor import Predictor, sequence_camera
from network.model.net import MVRackLay
from network.preprocess import frame_camera
from network.training.fit_back_edges import (
    FitConfig,
    fit_epochs,
    fit_head,
    frames_to_fit,
    head_probs,
    rack_row,
    reading_errors,
)
from network.training.train_data import require_level_camera, upright_faces

#: a canonical column is an upright's when this fraction of its rows inside the image show it
UPRIGHT_ROWS = 0.15
#: the fit's defaults (what was measured, docs/network.md)
DEFAULT_FIT = FitConfig(epochs=15, batch=64, pos_weight=3.0)


@dataclass
class Cached:
    """Per frame: pooled features ``(N, C, W/2)`` (fp16), targets ``(N, 2, W)`` (front, rear), the columns
    inside the source image ``(N, W)``, and the sequence index, camera distance and true rack depth."""

    pooled: torch.Tensor
    target: torch.Tensor
    inside: torch.Tensor
    seq: np.ndarray
    distance: np.ndarray
    depth: np.ndarray


def upright_targets(seq: Any, i: int, view: CanonicalView, rack_depth: float) -> tuple[np.ndarray, np.ndarray]:
    """Frame ``i``'s targets ``(2, W)``: does canonical column j show a front (0) / rear (1) upright (at
    least `UPRIGHT_ROWS` of its rows inside the image), and ``(W,)`` which columns lie inside the image."""
    require_level_camera(seq, "fitting the upright head")  # its masks are sampled as a level camera's
    intr, distance = frame_camera(seq, i)
    if intr is None:
        raise InputError(f"{getattr(seq, 'name', 'sequence')}: fitting the upright head needs the camera intrinsics")
    front, rear = upright_faces(seq.semantic(i), seq.depth(i), distance, rack_depth)
    u, v = view.source_coords(intr, distance)
    cols = (u >= 0) & (u < front.shape[1])
    rows = (v >= 0) & (v < front.shape[0])
    ui = np.clip(np.floor(u).astype(int), 0, front.shape[1] - 1)
    vi = np.floor(v[rows]).astype(int)
    target = np.zeros((2, view.width), np.float32)
    if rows.any():
        for k, mask in enumerate((front, rear)):
            target[k] = (mask[vi][:, ui].mean(0) >= UPRIGHT_ROWS) & cols
    return target, cols


@torch.no_grad()
def cache_features(model: MVRackLay, sequences: list[Any], every: int = 1, progress: bool = True) -> Cached:
    """Run the frozen trunk over ``sequences`` (every ``every``-th frame) and keep what the head needs."""
    view, total = model.cfg.view, frames_to_fit(model, sequences, every, "the upright head")
    pooled: torch.Tensor | None = None  # one block per array, filled in place (see network.training.fit_back_edges)
    target = np.zeros((total, 2, view.width), np.float32)
    inside = np.zeros((total, view.width), bool)
    seq_ids, dists, depths = np.zeros(total, np.int64), np.zeros(total), np.zeros(total)
    bar = tqdm(total=total, desc="uprights: features", unit="frame", disable=not progress, leave=False)
    n = 0
    for k, seq in enumerate(sequences):
        depth = rack_row(seq, "the upright head")[0]
        camera = sequence_camera(seq)
        ids = list(range(0, seq.num_frames, every))
        pred = Predictor(model, camera, fuse_tau=0)  # the canonical warp of inference, so the head sees what it will
        x = torch.cat([pred.preprocess(seq.rgb(i), i) for i in ids])
        p = pool_columns(*model.maps(x))
        if pooled is None:
            pooled = torch.empty((total, *p.shape[1:]), dtype=torch.float16)
        pooled[n : n + len(ids)] = p.half().cpu()
        for j, i in enumerate(ids):
            target[n + j], inside[n + j] = upright_targets(seq, i, view, depth)
            seq_ids[n + j], dists[n + j], depths[n + j] = k, camera(i)[1], depth
        n += len(ids)
        bar.update(len(ids))
    bar.close()
    if pooled is None:  # unreachable: total > 0 means one sequence ran
        raise InputError("no frames to fit the upright head on")
    return Cached(pooled, torch.from_numpy(target), torch.from_numpy(inside), seq_ids, dists, depths)


def train_head(head: UprightHead, data: Cached, cfg: FitConfig, progress: bool = True) -> list[float]:
    """Fit ``head`` to the cached targets over the columns inside the image (AdamW, cosine decay); returns
    the mean loss per epoch."""
    loss_fn = nn.BCEWithLogitsLoss(pos_weight=torch.tensor(cfg.pos_weight), reduction="none")

    def batch_loss(b: torch.Tensor) -> torch.Tensor:
        w = data.inside[b][:, None].float().expand(-1, 2, -1)
        return (loss_fn(head(data.pooled[b].float()), data.target[b]) * w).sum() / w.sum().clamp_min(1.0)

    return fit_epochs(head, data.pooled.shape[0], batch_loss, cfg, "uprights: fit", progress)


def depth_errors(head: UprightHead, data: Cached, model: MVRackLay) -> dict[str, Any]:
    """Rack depth the uprights alone give on cached frames: mean absolute error per frame (that frame
    alone), running (the frames so far of its sequence) and at a sequence's end, in metres; and the
    marks' precision and recall (columns inside the image, probability >= 0.5)."""
    probs = head_probs(head, data.pooled)
    ups = probs.numpy()
    summary = reading_errors(
        data.seq, data.depth, lambda k, reader: reader.add(None, [], float(data.distance[k]), ups[k]), model
    )
    marks = {}
    for c, name in enumerate(("front", "rear")):
        pred = (probs[:, c] >= 0.5) & data.inside
        true = (data.target[:, c] > 0.5) & data.inside
        tp = int((pred & true).sum())
        marks[name] = {"precision": tp / max(int(pred.sum()), 1), "recall": tp / max(int(true.sum()), 1)}
    return {**summary, "marks": marks}


def fit_uprights(
    model: MVRackLay, train: list[Any], val: list[Any], cfg: FitConfig = DEFAULT_FIT, progress: bool = True
) -> tuple[UprightHead, dict[str, Any]]:
    """A fitted head for ``model`` (its trunk unchanged) and a summary for the checkpoint's record."""
    return fit_head(
        model, train, val, cfg, what="the upright head", cache=cache_features,
        make_head=lambda data: UprightHead(data.pooled.shape[1], model.cfg.input_width),
        fit=train_head, errors=depth_errors, progress=progress,
    )  # fmt: skip
