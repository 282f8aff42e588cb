"""Training loop: supervised + LSGAN + consistency losses, validation, checkpoints, resume.

A run folder holds ``last.pt`` / ``best.pt`` (+ ``.json`` records) and ``metrics.jsonl`` (one
JSON object per epoch: step, wall and CPU minutes, mean losses, validation Table I). Epochs are
``steps_per_epoch`` optimiser steps over randomly drawn windows; the learning rate follows a
cosine from ``lr`` to ``lr * lr_floor`` over the run's ``epochs x steps_per_epoch`` steps (or a minute
cap, ``minutes``, whichever is further along); ``stop_step`` pauses the run inside that schedule. ``resume=True`` continues from ``last.pt`` with its optimiser state, step count
and elapsed time; a checkpoint taken inside an epoch (``checkpoint_every``, Ctrl-C) resumes at the
same place in the epoch's seeded window order, so a killed and resumed run trains on the same
windows as an uninterrupted one.

Under torchrun (`network.training.distributed`) the model and discriminators are wrapped in
`DistributedDataParallel`: every rank draws its own share of windows, gradients are averaged, and
only rank 0 validates and writes checkpoints, metrics and progress bars. Elapsed time is the
slowest rank's, so the learning rate and the minute budget agree on every rank.

The settings: `network.training.train_config`; the data: `network.training.train_data`; what the run folder's
records hold: `network.training.run_records`.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import asdict
from pathlib import Path
from typing import Any

import torch
from torch import nn
from torch.nn.parallel import DistributedDataParallel
from tqdm import tqdm

from layouts import NUM_CLASSES, VIEWS
from layouts.errors import InputError
from layouts.fileio import atomic_write_text
from network.checkpoint import init_weights_from, load_checkpoint, save_checkpoint
from network.data import WindowDataset
from network.device import DistEnv, device_for
from network.inference.layout_eval import evaluate_sequences, score
from network.model.config import ModelConfig
from network.model.discriminator import build_discriminators
from network.model.net import MVRackLay
from network.model.resnet import load_imagenet_weights
from network.precision import forward_autocast
from network.training.distributed import ListSampler, all_reduce, gather_fingerprints, rank_indices
from network.training.feature_keeper import FeatureKeeper
from network.training.losses import (
    consistency_loss,
    lsgan_discriminator_loss,
    lsgan_generator_loss,
    one_hot_layouts,
    row_loss,
    supervised_loss,
)
from network.training.run_records import best_on_disk, compact_metrics, epoch_summary, is_tmp_of, weights_fingerprint
from network.training.train_config import TrainConfig, retired_options_off
from network.training.train_data import data_record


def keep_batch_norm_statistics(module: nn.Module) -> None:
    """Put ``module``'s batch-norm layers in eval mode (the rest stays as it is): a training step normalises with,
    and leaves, their running statistics; their affine weights still learn."""
    for m in module.modules():
        if isinstance(m, nn.modules.batchnorm._BatchNorm):
            m.eval()


class _DiscriminatorLoss(nn.Module):
    """Both views' LSGAN discriminator loss in one forward, so one DDP wrapper covers a whole update."""

    def __init__(self, discs: nn.ModuleDict) -> None:
        super().__init__()
        self.discs = discs

    def forward(self, real: dict[str, torch.Tensor], fake: dict[str, torch.Tensor]) -> torch.Tensor:
        loss = 0
        for v in VIEWS:
            loss = loss + lsgan_discriminator_loss(self.discs[v](real[v]), self.discs[v](fake[v]))
        return loss


class Trainer:
    """Owns the model, optimisers and run folder; `fit` trains until the epochs or minutes run out.

    ``dist_env`` places the process in a torchrun job (the process group must already be
    initialised, see `network.training.distributed.init_process_group`); None = one process.
    """

    def __init__(
        self,
        model_cfg: ModelConfig,
        train_cfg: TrainConfig,
        train_seqs: list[Any],
        val_seqs: list[Any],
        out: str | Path,
        *,
        resume: bool = False,
        data_info: dict[str, Any] | None = None,
        progress: bool = True,
        dist_env: DistEnv | None = None,
    ) -> None:
        train_cfg.validate()
        self.mcfg, self.tcfg = model_cfg, train_cfg
        self.env = dist_env or DistEnv()
        if self.env.enabled and not (torch.distributed.is_available() and torch.distributed.is_initialized()):
            raise RuntimeError("distributed training: call network.training.distributed.init_process_group first")
        self.is_main = self.env.is_main
        self.device = device_for(self.env, train_cfg.device)
        self.out = Path(out)
        self.progress = progress and self.is_main
        torch.set_num_threads(train_cfg.threads)
        torch.manual_seed(train_cfg.seed)  # the same initial weights on every rank (DDP also broadcasts rank 0's)
        self.model = MVRackLay(model_cfg)
        if train_cfg.imagenet_weights:
            load_imagenet_weights(self.model.encoder, train_cfg.imagenet_weights)
        self.discs = build_discriminators(model_cfg) if train_cfg.adv_weight > 0 else None
        init_info = None
        if train_cfg.init_from and not resume:
            init_info = init_weights_from(self.model, train_cfg.init_from, self.discs)
        self.model.to(self.device)
        if self.discs is not None:
            self.discs.to(self.device)
        self.keeper = (
            FeatureKeeper(self.model, train_cfg.init_from, self.device, not train_cfg.frozen_bn)
            if train_cfg.keep_features > 0
            else None
        )
        self.opt = torch.optim.Adam(self.model.parameters(), lr=train_cfg.lr, weight_decay=train_cfg.weight_decay)
        self.opt_d = (
            torch.optim.Adam(self.discs.parameters(), lr=train_cfg.disc_lr, betas=(0.5, 0.999)) if self.discs else None
        )
        self.cw = torch.tensor(train_cfg.class_weights, dtype=torch.float32, device=self.device)
        self.train_ds = WindowDataset(
            train_seqs,
            seq_len=model_cfg.seq_len,
            input_size=(model_cfg.input_width, model_cfg.input_height),
            spec=model_cfg.spec,
            augment=train_cfg.augment,
            seed=train_cfg.seed,
            max_stride=train_cfg.max_stride,
            jpeg=train_cfg.jpeg,
            jpeg_quality=tuple(train_cfg.jpeg_quality),
        )
        self.val_seqs = val_seqs[: train_cfg.val_sequences or None]
        self.batch = max(1, train_cfg.frames_per_step // model_cfg.seq_len)
        self.step = 0
        self.epoch = 0
        self.epoch_step = 0  #: optimiser steps already done in the current epoch
        self.epoch_sums: dict[str, float] = {}  #: loss sums over those steps (this rank's)
        self.wall_s = 0.0
        self.cpu_s = 0.0
        self.best = -math.inf
        self.history: list[dict[str, Any]] = []
        self.info = data_record(train_seqs, data_info, len(self.train_ds))
        if init_info is not None:
            self.info["init_from"] = init_info
        self.fingerprints: list[str] = []
        self.out.mkdir(parents=True, exist_ok=True)
        if self.env.enabled:
            seen = all_reduce([float(resume)], "sum", self.device)[0]
            if 0 < seen < self.env.world_size:
                raise InputError(
                    f"{self.out / 'last.pt'}: found by {int(seen)} of {self.env.world_size} ranks; "
                    "a multi-node run needs --out on a filesystem shared by every node"
                )
        if resume:
            self._resume()
        elif (self.out / "last.pt").exists():
            raise InputError(f"{self.out}: already holds a run (last.pt); pass --resume or choose another --out")
        self.net, self.disc_loss = self._wrapped()

    def _wrapped(self) -> tuple[nn.Module, nn.Module | None]:
        """The model and the discriminators' loss as a step runs them: under DDP in a torchrun job."""
        net: nn.Module = self.model
        disc_loss: nn.Module | None = _DiscriminatorLoss(self.discs) if self.discs is not None else None
        if self.env.enabled:
            ids = [self.device] if self.device.type == "cuda" else None
            net = DistributedDataParallel(self.model, device_ids=ids)
            if disc_loss is not None:
                disc_loss = DistributedDataParallel(disc_loss, device_ids=ids)
        return net, disc_loss

    # ------------------------------------------------------------------ state
    def _record(self, metrics: dict[str, Any] | None) -> dict[str, Any]:
        return {
            "model_config": self.mcfg.to_dict(),
            "variant": self.mcfg.variant,
            "input_size": [self.mcfg.input_width, self.mcfg.input_height],
            "spec": self.mcfg.spec.to_dict(),
            "train_config": asdict(self.tcfg),
            "step": self.step,
            "epoch": self.epoch,
            "train_wall_minutes": self.wall_s / 60,
            "train_cpu_minutes": self.cpu_s / 60,
            "best_score": None if self.best == -math.inf else self.best,
            "metrics": metrics,
            "world_size": self.env.world_size,
            "replica_fingerprints": self.fingerprints,
            **self.info,
        }

    def _payload(self) -> dict[str, Any]:
        p: dict[str, Any] = {
            "model": self.model.state_dict(),
            "optimizer": self.opt.state_dict(),
            "step": self.step,
            "epoch": self.epoch,
            "wall_s": self.wall_s,
            "cpu_s": self.cpu_s,
            "best": self.best if self.best != -math.inf else -1.0,
            "epoch_step": self.epoch_step,
            "epoch_sums": dict(self.epoch_sums),
            "world_size": self.env.world_size,
        }
        if self.discs is not None and self.opt_d is not None:
            p["discriminators"] = self.discs.state_dict()
            p["optimizer_d"] = self.opt_d.state_dict()
        return p

    def _resume(self) -> None:
        path = self.out / "last.pt"
        payload, record = load_checkpoint(path)
        saved = ModelConfig.from_dict(record.get("model_config"), str(path))
        retired_options_off(record.get("train_config") or {}, str(path))
        if isinstance(record.get("init_from"), dict):
            self.info["init_from"] = record["init_from"]
        if saved != self.mcfg:
            raise InputError(f"{path}: was trained with a different model config ({saved.variant}); use the same flags")
        try:
            self.model.load_state_dict(payload["model"])
            self.opt.load_state_dict(payload["optimizer"])
            if self.discs is not None and self.opt_d is not None and "discriminators" in payload:
                self.discs.load_state_dict(payload["discriminators"])
                self.opt_d.load_state_dict(payload["optimizer_d"])
        except (KeyError, RuntimeError, ValueError) as e:
            raise InputError(f"{path}: cannot resume from it ({str(e).splitlines()[0][:160]})") from None
        self.step = int(payload["step"])
        self.epoch = int(payload["epoch"])
        self.epoch_step = int(payload.get("epoch_step", 0))
        self.epoch_sums = {str(k): float(v) for k, v in dict(payload.get("epoch_sums", {})).items()}
        self.wall_s = float(payload["wall_s"])
        self.cpu_s = float(payload["cpu_s"])
        self.best = float(payload["best"]) if float(payload["best"]) >= 0 else -math.inf
        self.best = max(self.best, best_on_disk(self.out / "best.json"))
        if self.env.enabled:
            lo, hi = all_reduce([float(self.step), -float(self.step)], "min", self.device)
            if lo != -hi:
                raise InputError(f"{path}: ranks read different steps ({int(lo)}..{int(-hi)}); is --out shared?")
        mpath = self.out / "metrics.jsonl"
        if mpath.exists():
            # Epochs logged after this checkpoint (a crash between the log and the save) are dropped.
            lines = [json.loads(line) for line in mpath.read_text().splitlines() if line.strip()]
            self.history = [e for e in lines if int(e.get("step", 0)) <= self.step]
        if self.is_main:
            names = ("last.pt", "last.json", "best.pt", "best.json", "metrics.jsonl")
            for p in self.out.iterdir():
                if is_tmp_of(p, names):
                    p.unlink(missing_ok=True)  # a write cut short by a crash; the final name was never touched

    # ------------------------------------------------------------------ schedule
    def _progress(self) -> float:
        total = self.tcfg.epochs * self.tcfg.steps_per_epoch
        p = self.step / total
        if self.tcfg.minutes > 0:
            p = max(p, self.wall_s / (60 * self.tcfg.minutes))
        return min(p, 1.0)

    def _set_lr(self) -> float:
        f = self.tcfg.lr_floor + (1 - self.tcfg.lr_floor) * 0.5 * (1 + math.cos(math.pi * self._progress()))
        lr = self.tcfg.lr * f
        for g in self.opt.param_groups:
            g["lr"] = lr
        return lr

    def _out_of_time(self) -> bool:
        return self.tcfg.minutes > 0 and self.wall_s >= 60 * self.tcfg.minutes

    def _paused(self) -> bool:
        """The pause step reached (the schedule still spans every step; --resume without it goes on)."""
        return self.tcfg.stop_step > 0 and self.step >= self.tcfg.stop_step

    def _done(self) -> bool:
        return self._out_of_time() or self._paused() or self.epoch >= self.tcfg.epochs

    # ------------------------------------------------------------------ one step
    def _autocast(self) -> torch.autocast:
        return forward_autocast(self.device.type, self.tcfg.precision)

    def train_step(self, batch: dict[str, torch.Tensor]) -> dict[str, float]:
        t = self.tcfg
        batch = {k: (v.to(self.device, non_blocking=True) if torch.is_tensor(v) else v) for k, v in batch.items()}
        self.net.train()
        if t.frozen_bn:
            keep_batch_norm_statistics(self.net)
        with self._autocast():
            out = self.net(batch["images"], batch["anchors"])
        out = {k: v.float() for k, v in out.items()}  # losses in fp32 whatever the forward ran in
        valid = torch.isfinite(batch["anchors"])
        losses: dict[str, torch.Tensor] = {}
        losses["sup"] = sum(supervised_loss(out[v], batch[v], self.cw, t.dice_weight, valid) for v in VIEWS)
        losses["rows"] = row_loss(out["rows"], batch["rows"])
        if self.mcfg.seq_len > 1 and (t.short_weight > 0 or t.long_weight > 0):
            spec = self.mcfg.spec
            losses["short"] = sum(
                consistency_loss(out[v], batch["cam_x"], batch["visible"], spec, long_range=False) for v in VIEWS
            )
            losses["long"] = sum(
                consistency_loss(out[v], batch["cam_x"], batch["visible"], spec, long_range=True) for v in VIEWS
            )
        fakes = {v: out[v].flatten(0, 1).softmax(2) for v in VIEWS}
        if self.discs is not None:
            with self._autocast():
                scores = {v: self.discs[v](fakes[v]).float() for v in VIEWS}
            losses["adv"] = sum(lsgan_generator_loss(scores[v]) for v in VIEWS)
        total = losses["sup"] + t.row_weight * losses["rows"]
        total = total + t.short_weight * losses.get("short", 0) + t.long_weight * losses.get("long", 0)
        total = total + t.adv_weight * losses.get("adv", 0)
        if self.keeper is not None:
            losses["keep"] = self.keeper.loss(batch["images"])
            total = total + t.keep_features * losses["keep"]
        self.opt.zero_grad(set_to_none=True)
        total.backward()
        self.opt.step()
        if self.disc_loss is not None and self.opt_d is not None:
            real = {v: one_hot_layouts(batch[v].flatten(0, 1), NUM_CLASSES) for v in VIEWS}
            with self._autocast():
                d_loss = self.disc_loss(real, {v: fakes[v].detach() for v in VIEWS}).float()
            self.opt_d.zero_grad(set_to_none=True)
            d_loss.backward()
            self.opt_d.step()
            losses["disc"] = d_loss
        self.step += 1
        res = {k: float(v.detach()) for k, v in losses.items()}
        res["total"] = float(total.detach())
        return res

    # ------------------------------------------------------------------ loop
    def validate(self) -> dict[str, Any] | None:
        if not self.val_seqs:
            return None
        return evaluate_sequences(
            self.model.eval(),
            self.val_seqs,
            mode=self.tcfg.val_mode,
            max_frames=self.tcfg.val_frames or None,
            progress=self.progress,
        )

    def epoch_indices(self) -> list[int]:
        """This rank's windows for the current epoch, in order, without those of steps already done."""
        g = torch.Generator().manual_seed(self.tcfg.seed * 100003 + self.epoch)
        n = self.tcfg.steps_per_epoch * self.batch
        idx = rank_indices(len(self.train_ds), n, rank=self.env.rank, world_size=self.env.world_size, generator=g)
        return idx[self.epoch_step * self.batch :]

    def _loader(self) -> torch.utils.data.DataLoader:
        self.train_ds.set_epoch(self.epoch)
        return torch.utils.data.DataLoader(
            self.train_ds,
            batch_size=self.batch,
            sampler=ListSampler(self.epoch_indices()),
            num_workers=self.tcfg.workers,
            drop_last=True,
            persistent_workers=False,
            pin_memory=self.device.type == "cuda",
        )

    def _save(self, name: str, metrics: dict[str, Any] | None) -> None:
        if self.is_main:
            save_checkpoint(self.out / f"{name}.pt", self._payload(), self._record(metrics))

    def _sync_fingerprints(self) -> None:
        """Every rank's weight fingerprint into the record (a collective: all ranks call it together)."""
        if self.env.enabled:
            self.fingerprints = gather_fingerprints(weights_fingerprint(self.model, self.discs), self.device)
            if len(set(self.fingerprints)) > 1 and self.is_main:
                print(f"warning: replicas' weights differ at step {self.step}: {self.fingerprints}", flush=True)

    def _log(self, entry: dict[str, Any]) -> None:
        self.history.append(entry)
        text = "".join(json.dumps(e, sort_keys=True) + "\n" for e in self.history)
        atomic_write_text(self.out / "metrics.jsonl", text)

    def _timed(self, w0: float, c0: float) -> None:
        """Add one step's wall and CPU time: wall = the slowest rank's, CPU = summed over ranks."""
        dw, dc = time.perf_counter() - w0, time.process_time() - c0
        if self.env.enabled:
            dw = all_reduce([dw], "max", self.device)[0]
            dc = all_reduce([dc], "sum", self.device)[0]
        self.wall_s += dw
        self.cpu_s += dc

    def _epoch_means(self) -> dict[str, float]:
        """Mean losses of the epoch over every rank's steps."""
        keys = sorted(self.epoch_sums)
        vals = all_reduce([self.epoch_sums[k] for k in keys] + [float(self.epoch_step)], "sum", self.device)
        n = max(vals[-1], 1.0)
        return {k: v / n for k, v in zip(keys, vals[:-1])}

    def fit(self) -> dict[str, Any]:
        """Train to the end of the budget; returns the last record."""
        record: dict[str, Any] = self._record(None)
        metrics: dict[str, Any] | None = None
        every = self.tcfg.checkpoint_every
        while not self._done():
            bar = tqdm(
                self._loader(),
                total=self.tcfg.steps_per_epoch,
                initial=self.epoch_step,
                desc=f"epoch {self.epoch + 1}/{self.tcfg.epochs}",
                unit="step",
                disable=not self.progress,
                leave=False,
            )
            try:
                for batch in bar:
                    w0, c0 = time.perf_counter(), time.process_time()
                    lr = self._set_lr()
                    res = self.train_step(batch)
                    self.epoch_step += 1
                    for k, v in res.items():
                        self.epoch_sums[k] = self.epoch_sums.get(k, 0.0) + v
                    self._timed(w0, c0)
                    bar.set_postfix(loss=f"{res['total']:.3f}", lr=f"{lr:.1e}")
                    if self._paused() and self.epoch_step < self.tcfg.steps_per_epoch:
                        self._sync_fingerprints()  # inside an epoch: saved where it is, to go on at this window
                        self._save("last", metrics)
                        return self._record(metrics)
                    if self._out_of_time():
                        break
                    if every and self.step % every == 0 and self.epoch_step < self.tcfg.steps_per_epoch:
                        self._sync_fingerprints()
                        self._save("last", metrics)
            except KeyboardInterrupt:
                self._save("last", metrics)
                raise
            finally:
                bar.close()
            losses = self._epoch_means()
            self.epoch += 1
            self.epoch_step, self.epoch_sums = 0, {}
            val = self.validate() if self.is_main else None
            entry: dict[str, Any] = {
                "epoch": self.epoch,
                "step": self.step,
                "train_wall_minutes": round(self.wall_s / 60, 4),
                "train_cpu_minutes": round(self.cpu_s / 60, 4),
                "lr": self.opt.param_groups[0]["lr"],
                "loss": losses,
            }
            if self.env.enabled:
                entry["world_size"] = self.env.world_size
            if val:
                s = score(val)
                entry["val_score"] = s
                entry["val_visible"] = compact_metrics(val["visible"])
                entry["val_all"] = compact_metrics(val["all"])
                metrics = {"visible": val["visible"], "all": val["all"]}
                if s > self.best:
                    self.best = s
                    self._save("best", metrics)
            if self.is_main:
                self._log(entry)
            self._sync_fingerprints()
            record = self._record(metrics if val else None)
            self._save("last", record["metrics"])
            if not val:
                self._save("best", None)
            if self.is_main:
                tqdm.write(epoch_summary(entry)) if self.progress else print(epoch_summary(entry), flush=True)
        return record
