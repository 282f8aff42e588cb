"""A training run's optimisation settings (`TrainConfig`) and the model a dataset trains (`default_model_config`)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any

from layouts import NUM_CLASSES, LayoutSpec
from layouts.errors import InputError
from network.data import check_jpeg
from network.model.config import ModelConfig
from network.precision import check_precision

#: options of earlier versions (record key -> flag) that no shipped weights use: records name them at 0
RETIRED_OPTIONS = {"prefix_frames": "--prefix-frames", "seen_weight": "--seen-weight"}
#: keys of earlier versions dropped when read whatever their value: the pause point in minutes (a pause leaves
#: the weights as they were; ``stop_step`` took its place)
DROPPED_OPTIONS = ("stop_minutes",)


@dataclass
class TrainConfig:
    """Optimisation settings (the model's own settings live in `ModelConfig`)."""

    frames_per_step: int = 16  #: batch = frames_per_step // seq_len windows (same frames for every variant)
    steps_per_epoch: int = 200
    epochs: int = 40
    minutes: float = (
        0.0  #: a wall-clock cap in minutes of optimiser steps (0 = none): a quick run's; recipes budget in steps
    )
    stop_step: int = 0  #: pause once this many optimiser steps are done (0 = none); the schedule still spans them all
    lr: float = 1e-3
    lr_floor: float = 0.05
    weight_decay: float = 1e-5
    disc_lr: float = 1e-4
    class_weights: tuple[float, float, float] = (1.0, 1.0, 2.0)
    dice_weight: float = 0.5
    row_weight: float = 1.0  #: the row head's board-finding loss
    adv_weight: float = 0.01
    short_weight: float = 0.1
    long_weight: float = 0.05
    augment: bool = True
    max_stride: int = 3  #: training windows skip up to this - 1 frames between theirs (the memory sees wider motion)
    jpeg: float = 0.0  #: share of training windows whose frames pass through JPEG (0 = none)
    jpeg_quality: tuple[int, int] = (30, 95)  #: the JPEG quality range those windows draw from
    precision: str = "fp32"  #: fp32, or bf16: forward passes under bf16 autocast (weights and optimiser stay fp32)
    seed: int = 0
    threads: int = 2
    workers: int = 0
    val_frames: int = 0  #: frames per validation sequence (0 = all)
    val_sequences: int = 0  #: validation sequences used (0 = all)
    val_mode: str = "window"
    imagenet_weights: str | None = None
    init_from: str | None = None  #: warm start: a checkpoint whose weights seed the model (see init_weights_from)
    #: batch-norm layers keep their running statistics while training (fine-tuning on other looks without
    #: renormalising the looks the weights know: the statistics move far faster than the weights)
    frozen_bn: bool = False
    #: weight of the feature-keeping term: the pyramid maps (what the depth heads read) of ``init_from``'s network,
    #: frozen, are the targets of the trained network's on the same frames, so heads fitted on the first still
    #: read the second (0 = off)
    keep_features: float = 0.0
    checkpoint_every: int = 0  #: also write last.pt every this many steps (0 = at epoch ends only)
    device: str = "cpu"  #: cpu, cuda or auto (cuda:LOCAL_RANK when CUDA is present)
    extra: dict[str, Any] = field(default_factory=dict)

    def validate(self) -> None:
        for name in ("frames_per_step", "steps_per_epoch", "epochs", "threads", "max_stride"):
            if getattr(self, name) < 1:
                raise InputError(f"--{name.replace('_', '-')} must be >= 1, got {getattr(self, name)}")
        if self.checkpoint_every < 0:
            raise InputError(f"--checkpoint-every must be >= 0, got {self.checkpoint_every}")
        if self.stop_step < 0:
            raise InputError(f"--stop-at must be a number of steps >= 0, got {self.stop_step}")
        if self.device not in ("auto", "cpu", "cuda"):
            raise InputError(f"--device must be auto, cpu or cuda, got {self.device!r}")
        for name in (
            "minutes",
            "lr",
            "dice_weight",
            "row_weight",
            "adv_weight",
            "short_weight",
            "long_weight",
            "keep_features",
            "workers",
        ):
            v = getattr(self, name)
            if not math.isfinite(v) or v < 0:
                raise InputError(f"--{name.replace('_', '-')} must be a finite number >= 0, got {v}")
        check_jpeg(self.jpeg, tuple(self.jpeg_quality), ("--jpeg", "--jpeg-quality"))
        if len(self.class_weights) != NUM_CLASSES or min(self.class_weights) <= 0:
            raise InputError(f"--class-weights needs {NUM_CLASSES} positive numbers, got {self.class_weights}")
        check_precision(self.precision)
        if self.keep_features > 0 and not self.init_from:
            raise InputError("--keep-features needs --init-from: the network whose features are kept")
        if self.val_mode not in ("window", "stream"):
            raise InputError(f"--val-mode must be window or stream, got {self.val_mode!r}")

    @classmethod
    def from_dict(cls, d: Any, source: str = "train config") -> TrainConfig:
        """A record's ``train_config`` (`asdict` of one) as a TrainConfig; options of earlier versions that
        this one no longer has (`RETIRED_OPTIONS`) load when off and are refused in one line when on."""
        if not isinstance(d, dict):
            raise InputError(f"{source}: train config must be a JSON object")
        d = retired_options_off(d, source)
        unknown = sorted(set(d) - set(cls.__dataclass_fields__))
        if unknown:
            raise InputError(f"{source}: unknown train config keys {unknown}")
        for name in ("class_weights", "jpeg_quality"):  # JSON lists
            if name in d:
                d[name] = tuple(d[name])
        return cls(**d)


def retired_options_off(d: dict[str, Any], source: str) -> dict[str, Any]:
    """``d`` (a record's train config) without the `RETIRED_OPTIONS` it names at 0; one line naming the first
    that is on (a run trained with it cannot be resumed the same way)."""
    d = {k: v for k, v in d.items() if k not in DROPPED_OPTIONS}
    for name, flag in RETIRED_OPTIONS.items():
        v = d.pop(name, 0)
        if v != 0:
            raise InputError(f"{source}: trained with {flag} {v}, an option this version no longer has")
    return d


def default_model_config(variant: str, spec: LayoutSpec, layout_size: int, **kw: Any) -> ModelConfig:
    """The model for a dataset: its slots and extents at the model's own resolution."""
    return ModelConfig(variant=variant, spec=replace(spec, size=layout_size), **kw)
