"""Stage ``train`` of ``mvracklay train`` (and the plain ``mvracklay train --data ... --out ...``): train an
MVRackLay variant (or the RackLay baseline) on a generated dataset, or export a checkpoint's weights."""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

from layouts.errors import InputError
from network.device import DistEnv, device_for
from network.model.config import DEFAULT_VARIANT, VARIANTS, ModelConfig
from network.precision import PRECISIONS, cpu_has_native_bf16
from network.training.distributed import DEFAULT_TIMEOUT_MIN, init_process_group, shutdown
from network.training.train_config import TrainConfig, default_model_config
from network.training.train_data import open_data
from network.training.trainer import Trainer

NAME = "train"
HELP = "train the layout network on a WareSynth dataset (checkpoints, metrics, resume)"
DESCRIPTION = (
    "Train a variant on the 'train' split of DATA, validating with the Table I metrics on the 'val' split "
    "after every epoch. RUN receives last.pt / best.pt (+ .json records) and metrics.jsonl; --resume "
    "continues an interrupted run (also after kill -9: --checkpoint-every N bounds the lost steps). "
    "Under torchrun (torchrun --nproc_per_node=N -m mvracklay train ...) it trains with "
    "DistributedDataParallel: gloo on CPU, NCCL on GPUs, each rank on its own share of the windows, "
    "rank 0 writing checkpoints and metrics; see docs/distributed.md. "
    "--export CKPT writes a fp16 weights-only copy of a checkpoint to --out."
)


# long on purpose: a flat list of every training option reads best in one place
def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--data",
        type=Path,
        nargs="+",
        help="dataset folder(s) written by 'mvracklay generate', or RackLay/MVRackLay exports written by "
        "'mvracklay export --format racklay' (several are joined; same layout spec)",
    )
    p.add_argument("--out", type=Path, required=True, help="run folder (or the weights file with --export)")
    p.add_argument(
        "--variant", choices=sorted(VARIANTS), default=DEFAULT_VARIANT,
        help="racklay: one frame, no memory (the baseline); mvracklay-T: windows of T frames through the slot memory; "
        "-disc-: with the LSGAN discriminators",
    )  # fmt: skip
    p.add_argument("--resume", action="store_true", help="continue from RUN/last.pt when it exists (else start)")
    p.add_argument("--export", type=Path, metavar="CKPT", help="write CKPT's model weights as fp16 to --out, then stop")
    m = ModelConfig()
    g = p.add_argument_group("model")
    g.add_argument("--input-size", type=int, nargs=2, default=[m.input_width, m.input_height], metavar=("W", "H"),
                   help="network input in pixels (frames are resized to it)")  # fmt: skip
    g.add_argument("--layout-size", type=int, default=m.spec.size, help="D of the predicted layouts")
    g.add_argument("--encoder-width", type=int, default=m.encoder_width, help="ResNet-18 base width (64 = standard)")
    g.add_argument("--hidden", type=int, default=m.hidden, help="channels of the reduced 1/32 map")
    g.add_argument("--memory-hidden", type=int, default=m.memory_hidden, help="ConvLSTM channels of the slot memory")
    g.add_argument("--decoder-width", type=int, default=m.decoder_width, help="channels of the layout decoders")
    g.add_argument("--imagenet-weights", type=Path, help="local torchvision resnet18 state dict (needs width 64)")
    g.add_argument(
        "--init-from",
        type=Path,
        metavar="CKPT",
        help="warm start from a trained checkpoint (e.g. a racklay run's best.pt; same sizes and widths)",
    )
    t = TrainConfig()
    g = p.add_argument_group("optimisation")
    g.add_argument("--epochs", type=int, default=t.epochs, help="epochs (validation and checkpoints after each)")
    g.add_argument("--steps-per-epoch", type=int, default=t.steps_per_epoch, help="optimiser steps per epoch")
    g.add_argument(
        "--minutes",
        type=float,
        default=t.minutes,
        help="budget: wall-clock minutes spent in optimiser steps (data loading and validation not counted; 0 = none)",
    )
    g.add_argument(
        "--stop-at",
        type=float,
        default=t.stop_minutes,
        metavar="MIN",
        help="pause (saving last.pt) after MIN step-minutes while the learning-rate schedule still spans --minutes; "
        "--resume continues it (0 = no pause)",
    )
    g.add_argument("--frames-per-step", type=int, default=t.frames_per_step, help="frames per batch (all variants)")
    g.add_argument("--lr", type=float, default=t.lr, help="peak learning rate (one-cycle schedule)")
    g.add_argument(
        "--class-weights",
        type=float,
        nargs=3,
        default=list(t.class_weights),
        metavar=("BG", "SHELF", "BOX"),
        help="per-class weights of the cross entropy (the rare box class weighted up)",
    )
    g.add_argument("--dice-weight", type=float, default=t.dice_weight, help="soft Dice on the box class")
    g.add_argument("--row-weight", type=float, default=t.row_weight, help="the row head's board-finding loss")
    g.add_argument("--adv-weight", type=float, default=t.adv_weight, help="LSGAN weight (0 drops the discriminators)")
    g.add_argument("--short-weight", type=float, default=t.short_weight, help="consistency j vs j+1")
    g.add_argument("--long-weight", type=float, default=t.long_weight, help="consistency j vs k >= j+2")
    g.add_argument("--no-augment", action="store_true", help="no colour jitter or horizontal flips")
    g.add_argument(
        "--max-stride",
        type=int,
        default=t.max_stride,
        help="training windows take every s-th frame, s drawn from 1..N per window, so the slot memory "
        "learns from viewpoints further apart (default %(default)s; 1 = consecutive frames)",
    )
    g.add_argument(
        "--jpeg",
        type=float,
        default=t.jpeg,
        metavar="P",
        help="share of training windows whose frames go through JPEG before the canonical warp, one quality per "
        "window drawn from --jpeg-quality, as a compressing camera or a video file delivers them; drawn from a "
        "stream of its own, so the windows, jitter and flips are those of the same run without it "
        "(0 = off, default %(default)s)",
    )
    g.add_argument(
        "--jpeg-quality",
        type=int,
        nargs=2,
        default=list(t.jpeg_quality),
        metavar=("LOW", "HIGH"),
        help="the JPEG quality range of --jpeg, 1 (worst) to 95 (default %(default)s)",
    )
    g.add_argument(
        "--precision",
        choices=list(PRECISIONS),
        default=t.precision,
        help="bf16 runs the training forward passes under bf16 autocast (weights, optimiser, validation and "
        "the saved checkpoints stay fp32): ~1.6x the steps per minute on CPUs with native bf16 (AVX512-BF16, "
        "AMX) and on recent GPUs; elsewhere it is emulated, 18-24x slower (a warning says so) (default %(default)s)",
    )
    g.add_argument("--seed", type=int, default=t.seed, help="seed of the weights, the data order and augmentation")
    g.add_argument("--threads", type=int, default=t.threads, help="torch CPU threads")
    g.add_argument("--workers", type=int, default=t.workers, help="data-loader worker processes")
    g.add_argument(
        "--checkpoint-every",
        type=int,
        default=t.checkpoint_every,
        metavar="STEPS",
        help="also write last.pt every STEPS optimiser steps (0 = at epoch ends only); bounds the work a crash loses",
    )
    g.add_argument(
        "--device",
        choices=["auto", "cpu", "cuda"],
        default="auto",
        help="auto = cuda:LOCAL_RANK when CUDA is present, else CPU",
    )
    g.add_argument(
        "--dist-timeout",
        type=float,
        default=DEFAULT_TIMEOUT_MIN,
        metavar="MIN",
        help="under torchrun: minutes a rank may wait for the others (rank 0 validates while they wait)",
    )
    g = p.add_argument_group("validation")
    g.add_argument("--val-sequences", type=int, default=t.val_sequences, help="0 = all 'val' sequences")
    g.add_argument("--val-frames", type=int, default=t.val_frames, help="frames per sequence (0 = all)")
    g.add_argument(
        "--val-mode", choices=["window", "stream"], default=t.val_mode,
        help="validate on windows (the paper) or streaming",
    )  # fmt: skip
    p.add_argument("--note", help="with --export: a line on how the weights were trained, kept in their JSON")
    p.add_argument(
        "--with-discriminators",
        action="store_true",
        help="with --export: keep the discriminators too (fp16), for a warm start (--init-from) from the copy",
    )
    p.add_argument("--quiet", action="store_true", help="no progress bars")


def run(args: argparse.Namespace) -> int:
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


def _export(args: argparse.Namespace, env: DistEnv) -> int:
    """``--export CKPT``: write its fp16 weights-only copy to ``--out`` (the main process only)."""
    from network.checkpoint import export_weights

    if not env.is_main:
        return 0
    export_weights(args.export, args.out, note=args.note, discriminators=args.with_discriminators)
    size = args.out.stat().st_size / 2**20
    print(f"wrote {args.out} ({size:.1f} MiB, fp16) and {args.out.with_suffix('.json')}")
    return 0


def _check_arguments(args: argparse.Namespace) -> None:
    """The options training needs, checked before any data is opened (one-line errors)."""
    if args.data is None:
        raise InputError("--data is required for training")
    if args.layout_size < 8 or args.layout_size > 1024:
        raise InputError(f"--layout-size must be in [8, 1024], got {args.layout_size}")
    for name in ("lr", "minutes", "stop_at"):
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


def _train_config(args: argparse.Namespace, adv: float) -> TrainConfig:
    """The options as a `TrainConfig` (``adv``: the adversarial weight, 0 for a variant without discriminators)."""
    return TrainConfig(
        frames_per_step=args.frames_per_step,
        steps_per_epoch=args.steps_per_epoch,
        epochs=args.epochs,
        minutes=args.minutes,
        stop_minutes=args.stop_at,
        lr=args.lr,
        class_weights=tuple(args.class_weights),
        dice_weight=args.dice_weight,
        row_weight=args.row_weight,
        adv_weight=adv,
        short_weight=args.short_weight,
        long_weight=args.long_weight,
        augment=not args.no_augment,
        max_stride=args.max_stride,
        jpeg=args.jpeg,
        jpeg_quality=tuple(args.jpeg_quality),
        precision=args.precision,
        seed=args.seed,
        threads=args.threads,
        workers=args.workers,
        val_frames=args.val_frames,
        val_sequences=args.val_sequences,
        val_mode=args.val_mode,
        imagenet_weights=str(args.imagenet_weights) if args.imagenet_weights else None,
        init_from=str(args.init_from) if args.init_from else None,
        checkpoint_every=args.checkpoint_every,
        device=args.device,
    )
