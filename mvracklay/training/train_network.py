"""Stage ``train`` of ``mvracklay train`` (and the plain ``mvracklay train --data ... --out ...``): train an
MVRackLay variant (or the RackLay baseline) on a generated dataset, or export a checkpoint's weights."""

from __future__ import annotations

import math
import sys
from dataclasses import dataclass
from pathlib import Path

from layouts.errors import InputError
from mvracklay.settings import ComputeSettings, same_as, setting
from mvracklay.threads import resolve_threads
from mvracklay.training import TRAIN_DESCRIPTION
from network.device import DistEnv, device_for
from network.model.config import DEFAULT_VARIANT, VARIANTS, ModelConfig
from network.precision import cpu_has_native_bf16
from network.training.distributed import DEFAULT_TIMEOUT_MIN, init_process_group, shutdown
from network.training.train_config import TrainConfig, default_model_config
from network.training.train_data import open_data
from network.training.trainer import Trainer

NAME = "train"
HELP = "train the layout network on a WareSynth dataset (checkpoints, metrics, resume)"
DESCRIPTION = TRAIN_DESCRIPTION


_M, _T = ModelConfig(), TrainConfig()  # the defaults the options show


def _model(name: str, help: str, default: object = None, **kwargs: object) -> object:
    return setting(name, help, default, group="model", **kwargs)


def _opt(name: str, help: str, default: object = None, **kwargs: object) -> object:
    return setting(name, help, default, group="optimisation", **kwargs)


def _val(name: str, help: str, default: object = None, **kwargs: object) -> object:
    return setting(name, help, default, group="validation", **kwargs)


# long on purpose: a flat list of every training option reads best in one place
@dataclass(frozen=True)
class TrainSettings:
    """The options of stage ``train`` and of ``mvracklay train`` without ``--recipe`` (each field's option,
    default, help and help group in its metadata); `_train_config` turns them into a `TrainConfig`."""

    data: list[Path] | None = setting(
        "--data",
        "dataset folder(s) written by 'mvracklay generate', or RackLay/MVRackLay exports written by "
        "'mvracklay export --format racklay' (several are joined; same layout spec)",
        type=Path, nargs="+",
    )  # fmt: skip
    out: Path | None = setting("--out", "run folder (or the weights file with --export)", type=Path, required=True)
    variant: str = setting(
        "--variant",
        "racklay: one frame, no memory (the baseline); mvracklay-T: windows of T frames through the slot memory; "
        "-disc-: with the LSGAN discriminators",
        DEFAULT_VARIANT, choices=sorted(VARIANTS),
    )  # fmt: skip
    resume: bool = setting(
        "--resume", "continue from RUN/last.pt when it exists (else start)", False, action="store_true"
    )
    export: Path | None = setting(
        "--export", "write CKPT's model weights as fp16 to --out, then stop", type=Path, metavar="CKPT"
    )
    input_size: list[int] = _model(
        "--input-size", "network input in pixels (frames are resized to it)", [_M.input_width, _M.input_height],
        type=int, nargs=2, metavar=("W", "H"),
    )  # fmt: skip
    layout_size: int = _model("--layout-size", "D of the predicted layouts", _M.spec.size, type=int)
    encoder_width: int = _model("--encoder-width", "ResNet-18 base width (64 = standard)", _M.encoder_width, type=int)
    hidden: int = _model("--hidden", "channels of the reduced 1/32 map", _M.hidden, type=int)
    memory_hidden: int = _model("--memory-hidden", "ConvLSTM channels of the slot memory", _M.memory_hidden, type=int)
    decoder_width: int = _model("--decoder-width", "channels of the layout decoders", _M.decoder_width, type=int)
    imagenet_weights: Path | None = _model(
        "--imagenet-weights", "local torchvision resnet18 state dict (needs width 64)", type=Path
    )
    init_from: Path | None = _model(
        "--init-from",
        "warm start from a trained checkpoint (e.g. a racklay run's best.pt; same sizes and widths)",
        type=Path, metavar="CKPT",
    )  # fmt: skip
    epochs: int = _opt("--epochs", "epochs (validation and checkpoints after each)", _T.epochs, type=int)
    steps_per_epoch: int = _opt("--steps-per-epoch", "optimiser steps per epoch", _T.steps_per_epoch, type=int)
    minutes: float = _opt(
        "--minutes",
        "a cap in wall-clock minutes spent in optimiser steps, for a quick run (data loading and validation not "
        "counted; 0 = none); the schedule then ends at the cap if it comes before --epochs x --steps-per-epoch",
        _T.minutes, type=float,
    )  # fmt: skip
    stop_at: int = _opt(
        "--stop-at",
        "pause (saving last.pt) after STEPS optimiser steps while the learning-rate schedule still spans "
        "--epochs x --steps-per-epoch; --resume continues it (0 = no pause)",
        _T.stop_step, type=int, metavar="STEPS",
    )  # fmt: skip
    frames_per_step: int = _opt("--frames-per-step", "frames per batch (all variants)", _T.frames_per_step, type=int)
    lr: float = _opt("--lr", "peak learning rate (one-cycle schedule)", _T.lr, type=float)
    class_weights: list[float] = _opt(
        "--class-weights", "per-class weights of the cross entropy (the rare box class weighted up)",
        list(_T.class_weights), type=float, nargs=3, metavar=("BG", "SHELF", "BOX"),
    )  # fmt: skip
    dice_weight: float = _opt("--dice-weight", "soft Dice on the box class", _T.dice_weight, type=float)
    row_weight: float = _opt("--row-weight", "the row head's board-finding loss", _T.row_weight, type=float)
    adv_weight: float = _opt("--adv-weight", "LSGAN weight (0 drops the discriminators)", _T.adv_weight, type=float)
    short_weight: float = _opt("--short-weight", "consistency j vs j+1", _T.short_weight, type=float)
    long_weight: float = _opt("--long-weight", "consistency j vs k >= j+2", _T.long_weight, type=float)
    augment: bool = _opt("--no-augment", "no colour jitter or horizontal flips", True, invert=True)
    frozen_bn: bool = _opt(
        "--frozen-bn",
        "batch-norm layers keep their running statistics (eval mode) while training: for fine-tuning on other "
        "looks with --init-from",
        _T.frozen_bn,
        action="store_true",
    )  # fmt: skip
    keep_features: float = _opt(
        "--keep-features",
        "weight of a term keeping the --init-from network's pyramid maps (what its depth heads read) on the same "
        "frames, so its fitted heads still read the fine-tuned network; with --frozen-bn (0 = off)",
        _T.keep_features, type=float, metavar="W",
    )  # fmt: skip
    max_stride: int = _opt(
        "--max-stride",
        "training windows take every s-th frame, s drawn from 1..N per window, so the slot memory "
        "learns from viewpoints further apart (default %(default)s; 1 = consecutive frames)",
        _T.max_stride, type=int,
    )  # fmt: skip
    jpeg: float = _opt(
        "--jpeg",
        "share of training windows whose frames go through JPEG before the canonical warp, one quality per "
        "window drawn from --jpeg-quality, as a compressing camera or a video file delivers them; drawn from a "
        "stream of its own, so the windows, jitter and flips are those of the same run without it "
        "(0 = off, default %(default)s)",
        _T.jpeg, type=float, metavar="P",
    )  # fmt: skip
    jpeg_quality: list[int] = _opt(
        "--jpeg-quality", "the JPEG quality range of --jpeg, 1 (worst) to 95 (default %(default)s)",
        list(_T.jpeg_quality), type=int, nargs=2, metavar=("LOW", "HIGH"),
    )  # fmt: skip
    precision: str = same_as(
        ComputeSettings,
        "precision",
        "bf16 runs the training forward passes under bf16 autocast (weights, optimiser, validation and "
        "the saved checkpoints stay fp32): ~1.6x the steps per minute on CPUs with native bf16 (AVX512-BF16, "
        "AMX) and on recent GPUs; elsewhere it is emulated, 18-24x slower (a warning says so) (default %(default)s)",
        default=_T.precision, group="optimisation",
    )  # fmt: skip
    seed: int = _opt("--seed", "seed of the weights, the data order and augmentation", _T.seed, type=int)
    threads: int | str = same_as(ComputeSettings, "threads", "torch CPU threads: a count, or auto: the cores free of "
                                 "other work when training starts", default=_T.threads, group="optimisation")  # fmt: skip
    workers: int = _opt("--workers", "data-loader worker processes", _T.workers, type=int)
    checkpoint_every: int = _opt(
        "--checkpoint-every",
        "also write last.pt every STEPS optimiser steps (0 = at epoch ends only); bounds the work a crash loses",
        _T.checkpoint_every, type=int, metavar="STEPS",
    )  # fmt: skip
    device: str = same_as(
        ComputeSettings, "device", "auto = cuda:LOCAL_RANK when CUDA is present, else CPU", group="optimisation"
    )
    dist_timeout: float = _opt(
        "--dist-timeout", "under torchrun: minutes a rank may wait for the others (rank 0 validates while they wait)",
        DEFAULT_TIMEOUT_MIN, type=float, metavar="MIN",
    )  # fmt: skip
    val_sequences: int = _val("--val-sequences", "0 = all 'val' sequences", _T.val_sequences, type=int)
    val_frames: int = _val("--val-frames", "frames per sequence (0 = all)", _T.val_frames, type=int)
    val_mode: str = _val(
        "--val-mode", "validate on windows (the paper) or streaming", _T.val_mode, choices=["window", "stream"]
    )
    note: str | None = setting("--note", "with --export: a line on how the weights were trained, kept in their JSON")
    with_discriminators: bool = setting(
        "--with-discriminators",
        "with --export: keep the discriminators too (fp16), for a warm start (--init-from) from the copy",
        False, action="store_true",
    )  # fmt: skip
    quiet: bool = setting("--quiet", "no progress bars", False, action="store_true")


SETTINGS = TrainSettings


def run(args: TrainSettings) -> int:
    env = DistEnv.from_env()
    if args.export:
        return _export(args, env)
    _check_arguments(args)
    datasets, train_seqs, val_seqs = _open_datasets(args.data)
    ds = datasets[0]
    variant = args.variant
    adv = args.adv_weight if VARIANTS[variant][2] else 0.0
    mcfg = default_model_config(
        variant,
        ds.spec,
        args.layout_size,
        input_width=args.input_size[0],
        input_height=args.input_size[1],
        encoder_width=args.encoder_width,
        hidden=args.hidden,
        decoder_width=args.decoder_width,
        memory_hidden=args.memory_hidden,
    )
    tcfg = _train_config(args, adv)
    tcfg.validate()
    info = {
        "root": str(args.data[0]) if len(args.data) == 1 else [str(d) for d in args.data],
        "seed": getattr(ds, "seed", None) if len(datasets) == 1 else [getattr(d, "seed", None) for d in datasets],
        "train_sequences": len(train_seqs),
        "val_sequences": len(val_seqs),
        "image_size": list(getattr(ds, "image_size", ())),
    }
    resume = bool(args.resume and (args.out / "last.pt").is_file())
    device = device_for(env, args.device)
    if args.precision == "bf16" and device.type == "cpu" and cpu_has_native_bf16() is False and env.is_main:
        print(
            "warning: --precision bf16 on a CPU without native bf16 (AVX512-BF16 or AMX): autocast emulates it, "
            "measured 18-24x slower per step than fp32 on such a CPU; prefer --precision fp32 here",
            file=sys.stderr,
        )
    backend = init_process_group(env, device, args.dist_timeout) if env.enabled else None
    finished = False  # every rank through fit(): wait for the others before closing the process group
    try:
        trainer = Trainer(
            mcfg,
            tcfg,
            train_seqs,
            val_seqs,
            args.out,
            resume=resume,
            data_info=info,
            progress=not args.quiet,
            dist_env=env,
        )
        if env.is_main:
            procs = f", {env.world_size} processes ({backend})" if env.enabled else ""
            print(
                f"training {variant} on {len(trainer.train_ds)} frames of {len(train_seqs)} sequences, "
                f"input {mcfg.input_width}x{mcfg.input_height}, layouts {mcfg.spec.shape}, "
                f"batch {trainer.batch} x {mcfg.seq_len} frames"
                + f" per process on {device}{procs}"
                + (f", resuming at step {trainer.step}" if resume else ""),
                flush=True,
            )
        record = trainer.fit()
        finished = True
    finally:
        shutdown(wait=finished)
    if env.is_main:
        print(
            f"done: step {record['step']}, {record['train_wall_minutes']:.1f} training minutes; "
            f"checkpoints in {args.out} (best score {record['best_score']})"
        )
    return 0


def _export(args: TrainSettings, env: DistEnv) -> int:
    """``--export CKPT``: write its fp16 weights-only copy to ``--out`` (the main process only)."""
    from network.checkpoint import export_weights

    if not env.is_main:
        return 0
    export_weights(args.export, args.out, note=args.note, discriminators=args.with_discriminators)
    size = args.out.stat().st_size / 2**20
    print(f"wrote {args.out} ({size:.1f} MiB, fp16) and {args.out.with_suffix('.json')}")
    return 0


def _check_arguments(args: TrainSettings) -> None:
    """The options training needs, checked before any data is opened (one-line errors)."""
    if args.data is None:
        raise InputError("--data is required for training")
    if args.layout_size < 8 or args.layout_size > 1024:
        raise InputError(f"--layout-size must be in [8, 1024], got {args.layout_size}")
    for name in ("lr", "minutes"):
        if not math.isfinite(getattr(args, name)):
            raise InputError(f"--{name} must be finite")
    if not math.isfinite(args.dist_timeout) or args.dist_timeout <= 0:
        raise InputError(f"--dist-timeout must be a positive number of minutes, got {args.dist_timeout}")


def _open_datasets(paths: list[Path]) -> tuple[list, list, list]:
    """The datasets at ``paths`` (one layout spec among them) and their train and val sequences."""
    datasets = [open_data(d) for d in paths]
    ds = datasets[0]
    for d, other in zip(paths[1:], datasets[1:]):
        if other.spec != ds.spec:
            raise InputError(f"{d}: layout spec {other.spec.to_dict()} differs from {paths[0]}'s")
    train_seqs = [s for d in datasets for s in d.sequences("train")]
    val_seqs = [s for d in datasets for s in d.sequences("val")]
    if not train_seqs:
        raise InputError(f"{', '.join(map(str, paths))}: no 'train' sequences")
    return datasets, train_seqs, val_seqs


def _train_config(args: TrainSettings, adv: float) -> TrainConfig:
    """The options as a `TrainConfig` (``adv``: the adversarial weight, 0 for a variant without discriminators)."""
    return TrainConfig(
        frames_per_step=args.frames_per_step,
        steps_per_epoch=args.steps_per_epoch,
        epochs=args.epochs,
        minutes=args.minutes,
        stop_step=args.stop_at,
        lr=args.lr,
        class_weights=tuple(args.class_weights),
        dice_weight=args.dice_weight,
        row_weight=args.row_weight,
        adv_weight=adv,
        short_weight=args.short_weight,
        long_weight=args.long_weight,
        augment=args.augment,
        frozen_bn=args.frozen_bn,
        keep_features=args.keep_features,
        max_stride=args.max_stride,
        jpeg=args.jpeg,
        jpeg_quality=tuple(args.jpeg_quality),
        precision=args.precision,
        seed=args.seed,
        threads=resolve_threads(args.threads),
        workers=args.workers,
        val_frames=args.val_frames,
        val_sequences=args.val_sequences,
        val_mode=args.val_mode,
        imagenet_weights=str(args.imagenet_weights) if args.imagenet_weights else None,
        init_from=str(args.init_from) if args.init_from else None,
        checkpoint_every=args.checkpoint_every,
        device=args.device,
    )
