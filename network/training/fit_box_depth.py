"""Fitting the box-depth head (`network.heads.boxdepth`) to a trained model, the rest of the network frozen.

The head's inputs come from one streamed pass of the frozen model over the training sequences, cached on
disk with their targets (`network.training.box_cache`; kept between fits with ``keep_cache``:
`network.training.kept_box_cache`). The head is then fitted with a two-hot cross entropy over the depth
bins (columns whose depth is shown weighted `FitConfig.shown_weight`) plus a binary cross entropy on the
shown logit; a head with fronts adds a two-hot cross entropy over the front bins (the truth's box front
behind the rack front, every box column).
"""

from __future__ import annotations

import contextlib
import math
import tempfile
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from tqdm import tqdm

from layouts.errors import InputError
from network.heads.boxdepth import BIN_STEP, BINS, BOX_WIDTH, FRONT_BINS, FRONT_STEP, BoxDepthHead, split_logits
from network.model.config import ModelConfig
from network.model.net import MVRackLay
from network.precision import check_precision, forward_autocast
from network.training.box_cache import Cache, Chain, StreamedPass, cache_part
from network.training.kept_box_cache import by_folder, kept_cache


@dataclass(frozen=True)
class FitConfig:
    """How the head is fitted (defaults: what was measured, docs/network.md)."""

    epochs: int = 3
    batch: int = 64
    lr: float = 2e-3
    weight_decay: float = 1e-2
    shown_weight: float = 4.0  #: depth loss weight of the columns whose depth the frame shows
    seed: int = 0
    #: the head's forward passes: fp32, or bf16 autocast (the loss in fp32). With native bf16 (AVX512-BF16) a
    #: batch of 64 slots took 1,030-1,100 -> 520 ms on one thread, the first epoch's loss within 0.1 %
    precision: str = "fp32"

    def validate(self) -> None:
        for name in ("epochs", "batch"):
            v = getattr(self, name)
            if not isinstance(v, int) or isinstance(v, bool) or v < 1:
                raise InputError(f"--{name} must be a positive integer, got {v!r}")
        for name in ("lr", "shown_weight"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise InputError(f"--{name.replace('_', '-')} must be a positive number, got {v!r}")
        v = self.weight_decay
        if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
            raise InputError(f"--weight-decay must be a number >= 0, got {v!r}")
        check_precision(self.precision)


def box_head_config(
    cfg: ModelConfig, parallax: bool = False, width: int = BOX_WIDTH, front: bool = False
) -> ModelConfig:
    """``cfg`` with a box-depth head of that kind (``parallax``: it reads the plane-sweep maps; ``width``: its
    channels; ``front``: it also reads each box's front): what a fitted head's checkpoint records."""
    return replace(cfg, box_depth=True, box_parallax=parallax, box_width=width, box_front=front)


def with_box_head(model: MVRackLay, parallax: bool = False, width: int = BOX_WIDTH, front: bool = False) -> MVRackLay:
    """``model`` itself if it has a box-depth head of that kind (``parallax``: it reads the plane-sweep maps;
    ``width``: its channels; ``front``: it reads fronts too), else a copy with a fresh one (same weights
    otherwise)."""
    cfg = model.cfg
    if model.box_depth is not None and (cfg.box_parallax, cfg.box_width, cfg.box_front) == (parallax, width, front):
        return model
    out = MVRackLay(box_head_config(cfg, parallax, width, front))
    state = {k: v for k, v in model.state_dict().items() if not k.startswith("box_depth.")}
    missing, unexpected = out.load_state_dict(state, strict=False)
    if unexpected or any(not k.startswith("box_depth.") for k in missing):
        raise InputError(f"model weights do not fit the model with a box-depth head: {unexpected or missing}")
    out.box_logit_offset = dict(model.box_logit_offset)
    out.rack_depth_offset = model.rack_depth_offset
    out.graph_precision = model.graph_precision
    return out.to(next(model.parameters()).device).eval()


def train_head(head: BoxDepthHead, data: Cache | Chain, cfg: FitConfig, progress: bool = True) -> list[float]:
    """Fit ``head`` to the cached targets (AdamW, one-cycle schedule); returns the mean loss per epoch."""
    cfg.validate()
    opt = torch.optim.AdamW(head.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    n = len(data)
    per_epoch = math.ceil(n / cfg.batch)
    sched = torch.optim.lr_scheduler.OneCycleLR(opt, cfg.lr, total_steps=cfg.epochs * per_epoch)
    bins = torch.as_tensor(BINS, dtype=torch.float32)
    front_bins = torch.as_tensor(FRONT_BINS, dtype=torch.float32)
    if head.front and not np.isfinite(data.field("front")).any():
        raise InputError("the cached inputs hold no box fronts (a cache kept before them); fit --front on a new cache")
    gen = torch.Generator().manual_seed(cfg.seed)
    head.train()
    losses = []
    for ep in range(cfg.epochs):
        perm = torch.randperm(n, generator=gen)
        total = 0.0
        for idx in tqdm(perm.split(cfg.batch), desc=f"box depth: epoch {ep + 1}/{cfg.epochs}", disable=not progress):
            b = np.sort(idx.numpy())  # sorted: the memory map reads forward
            batch = data.take(b)
            with forward_autocast("cpu", cfg.precision):
                logits = head(torch.from_numpy(batch.win).float(), torch.from_numpy(batch.extra).float())
            lz, ls, lf = split_logits(logits.float())
            tb, sb = torch.from_numpy(batch.back), torch.from_numpy(batch.shown)
            m = torch.isfinite(tb)
            loss = F.binary_cross_entropy_with_logits(ls[m], sb[m].float()) if m.any() else ls.sum() * 0
            if m.any():
                wt = torch.where(sb, cfg.shown_weight, 1.0)
                loss = loss + (two_hot_ce(lz, tb, bins, BIN_STEP) * wt)[m].sum() / wt[m].sum()
            if lf is not None:
                tf = torch.from_numpy(np.asarray(batch.front, dtype=np.float32))
                mf = torch.isfinite(tf)
                if mf.any():
                    loss = loss + two_hot_ce(lf, tf, front_bins, FRONT_STEP)[mf].mean()
            opt.zero_grad()
            loss.backward()
            opt.step()
            sched.step()
            total += float(loss.detach())
        losses.append(total / per_epoch)
    head.eval()
    return losses


def two_hot_ce(logits: torch.Tensor, target: torch.Tensor, bins: torch.Tensor, step: float) -> torch.Tensor:
    """``(N, K, D)`` bin logits against ``(N, D)`` targets (metres; NaN anywhere, masked by the caller): the
    cross entropy with the target's two neighbouring bins weighted by nearness, ``(N, D)``."""
    t = target.nan_to_num(0.0).clamp(float(bins[0]), float(bins[-1]))
    w = (1 - (t[..., None] - bins).abs() / step).clamp(min=0)
    return -(w * torch.log_softmax(logits, 1).permute(0, 2, 1)).sum(-1)


def fit_box_depth(
    job: StreamedPass,
    train: list[Any],
    cfg: FitConfig,
    cache_dir: Path | None = None,
    parallax: bool = False,
    keep_cache: Path | None = None,
    pass_minutes: float | None = None,
    width: int = BOX_WIDTH,
    front: bool = False,
) -> tuple[BoxDepthHead, dict[str, Any]]:
    """A fitted head for ``job.model`` (its trunk unchanged; ``parallax``: the head also reads plane-sweep maps,
    `network.heads.boxdepth.ParallaxHistory`; ``width``, ``front``: `BoxDepthHead`'s) and a summary for the
    checkpoint's record, its inputs streamed as ``job`` says (`StreamedPass`: which frames of each sequence,
    how many processes of one thread each share the pass; its ``deadline`` is set here from ``pass_minutes``).
    The cache lives in a temporary folder (under ``cache_dir`` if given) removed at the end, or in
    ``keep_cache``, kept one part per dataset folder and reused by a later fit of the same trunk (`kept_cache`):
    heads of other seeds, epochs or designs, or on more data, skip the passes already made. ``pass_minutes``:
    no sequence is started that many minutes after the pass began (each process streams at least one), and
    the head is fitted on those streamed by then (not with ``keep_cache``: what such a pass holds depends on the
    machine, and a kept cache is keyed on its sequences)."""
    cfg.validate()
    check_pass_minutes(pass_minutes, keep_cache)
    t0 = time.perf_counter()
    check_width(width)
    job = _ready(job, train, parallax, width, front)
    streamed = len(train)
    with contextlib.ExitStack() as stack:
        if keep_cache is None:
            tmp = stack.enter_context(tempfile.TemporaryDirectory(prefix="box-depth-", dir=cache_dir))
            deadline = None if pass_minutes is None else time.monotonic() + 60 * pass_minutes
            caches, _, streamed = cache_part(replace(job, deadline=deadline), train, Path(tmp))
            data, reused = Chain(caches), 0
        else:
            data, reused = kept_cache(job, train, Path(keep_cache))
        t1 = time.perf_counter()
        torch.manual_seed(cfg.seed)
        first = data.parts[0]
        head = BoxDepthHead(first.win.shape[1], first.extra.shape[1], width=width, front=front)
        losses = train_head(head, data, cfg, job.progress)
        summary = _summary(data, train, job, parallax, reused)
        del data, first  # the memory maps closed before the temporary folder goes
    if pass_minutes is not None:
        summary.update(train_sequences=streamed, sequences_given=len(train), pass_minutes=pass_minutes)
    summary.update(
        width=width, front=front, epochs=cfg.epochs, seed=cfg.seed, lr=cfg.lr, weight_decay=cfg.weight_decay,
        fit_precision=cfg.precision, losses=losses,
        cache_minutes=(t1 - t0) / 60, fit_minutes=(time.perf_counter() - t1) / 60,
    )  # fmt: skip
    return head, summary


def keep_box_inputs(job: StreamedPass, train: list[Any], keep_cache: Path, parallax: bool = False) -> dict[str, Any]:
    """Only the streamed pass of `fit_box_depth`, kept in ``keep_cache`` (`kept_cache`) for later fits of the
    same checkpoint: the pass can then take every core and the fit one thread beside other work. Returns the
    summary of the cache (slots, shown fraction, minutes)."""
    t0 = time.perf_counter()
    job = _ready(job, train, parallax)
    data, reused = kept_cache(job, train, Path(keep_cache))
    summary = _summary(data, train, job, parallax, reused)
    del data
    return {**summary, "cache_minutes": (time.perf_counter() - t0) / 60}


def check_width(width: int) -> None:
    """``width`` (the head's channels) is an integer >= 4."""
    if isinstance(width, bool) or not isinstance(width, int) or width < 4:
        raise InputError(f"--head-width must be an integer >= 4, got {width!r}")


def check_pass_minutes(pass_minutes: float | None, keep_cache: Path | None) -> None:
    """``pass_minutes`` is None or a positive number of minutes, and not given with ``keep_cache``."""
    if pass_minutes is None:
        return
    number = isinstance(pass_minutes, (int, float)) and not isinstance(pass_minutes, bool)
    if not (number and math.isfinite(pass_minutes) and pass_minutes > 0):
        raise InputError(f"--pass-minutes must be a positive number, got {pass_minutes!r}")
    if keep_cache is not None:
        raise InputError(
            "--pass-minutes cannot be used with --keep-cache: the sequences a pass cut by the clock holds depend "
            "on the machine, and a kept cache is reused by its sequences"
        )


def _ready(
    job: StreamedPass, train: list[Any], parallax: bool, width: int = BOX_WIDTH, front: bool = False
) -> StreamedPass:
    """The checks shared by `fit_box_depth` and `keep_box_inputs`; ``job`` with its model given a fresh head
    to read with."""
    choice, workers = job.choice, job.workers
    choice.validate()
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise InputError(f"--cache-workers must be a positive integer, got {workers!r}")
    if not train:
        raise InputError("no training sequences to fit the box-depth head on")
    longest = max(choice.streamed(s) for s in train)
    if choice.from_frame >= longest:
        raise InputError(f"--from-frame {choice.from_frame}: the training sequences stream at most {longest} frames")
    return replace(job, model=with_box_head(job.model, parallax, width, front))


def _summary(data: Chain, train: list[Any], job: StreamedPass, parallax: bool, reused: int) -> dict[str, Any]:
    """What a fit's or a cache's record says of its inputs (``precision``: the streamed pass's trunk graph's)."""
    choice = job.choice
    back = data.field("back")
    return {
        "train_sequences": len(train),
        **choice.key(),
        "parallax": parallax,
        "cache_parts": len(by_folder(train)),
        "cache_reused": reused,
        "cache_workers": job.workers,
        "precision": job.model.graph_precision,
        "train_slots": len(data),
        "shown_fraction": float(np.mean(data.field("shown")[np.isfinite(back)])),
    }
