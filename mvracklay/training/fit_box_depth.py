"""Stage ``fit-box-depth`` of ``mvracklay train``: give a trained checkpoint the head that reads each box's depth."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import torch

from layouts.errors import InputError
from layouts.fileio import atomic_write_json, nan_to_null
from mvracklay.options import check_counts
from mvracklay.settings import json_out_setting, precision_setting, quiet_setting, setting
from mvracklay.training.depth_heads import jpeg_quality_setting, jpeg_record, jpeg_share_setting, training_sequences
from network.heads.boxdepth import BOX_WIDTH
from network.model.frozen import use_precision
from network.training.fit_box_depth import FitConfig

NAME = "fit-box-depth"
HELP = "fit the box-depth head (reads each box's depth, carried along the row) to a trained checkpoint"
DESCRIPTION = (
    "The top-view decoder places a box's front well but reads its depth poorly. This fits a small head that "
    "reads, per shelf slot and layout column, a box's back depth and whether the frame shows it (the rest of "
    "the network frozen, one streamed pass per frame over generated data with depth, instance and scene files), "
    "and writes CKPT with the head added; predict, run and evaluate then carry the depths the frames showed "
    "along the row and move every predicted box's back there (--no-depth-read turns that off). "
    "The inputs are cached on disk (about 4.4 GB per thousand 12-frame scenes at 256x256, 2.4 GB at 128x128; "
    "--cache-dir puts them where there is room) and removed at the end; --keep-cache DIR keeps them, one part "
    "per --data folder, and a later fit of the same checkpoint with --keep-cache DIR reuses the parts of the "
    "folders it shares (another seed, more epochs, --head-width or one more dataset without the hour-long "
    "passes already made). The pass streams one frame after another: --cache-workers 2 splits it over two "
    "processes of one thread each (nearly twice the frames per minute of one process on two threads), and "
    "--cache-only stops after it, so the fit can run later on one thread beside other work."
)


@dataclass(frozen=True)
class FitBoxDepthSettings:
    """The options of stage ``fit-box-depth`` (each field's option, default and help in its metadata)."""

    checkpoint: Path | None = setting(
        "--checkpoint", "a trained .pt checkpoint (its .json beside)", type=Path, required=True
    )
    data: list[Path] | None = setting(
        "--data", "generated dataset(s) with depth, instance and scene files to fit on", type=Path, nargs="+",
        required=True,
    )  # fmt: skip
    sequences: int = setting("--sequences", "training sequences to use (the first N of --data)", 1000, type=int)
    epochs: int = setting("--epochs", "passes over the cached inputs", FitConfig.epochs, type=int)
    seed: int = setting("--seed", "seed of the head's initial weights and batch order", 0, type=int)
    lr: float = setting("--lr", "peak learning rate of the fit's one-cycle schedule (AdamW)", FitConfig.lr, type=float)
    weight_decay: float = setting(
        "--weight-decay", "AdamW's decoupled weight decay, on all the head's parameters", FitConfig.weight_decay,
        type=float,
    )  # fmt: skip
    parallax: bool = setting(
        "--parallax",
        "the head also reads the plane-sweep parallax against the frames 1 and 3 back (a box's faces behind "
        "the rack front move less than the front as the camera moves); a cache ~2.4x as large, slower inference",
        False, action="store_true",
    )  # fmt: skip
    front: bool = setting(
        "--front",
        "the head also reads each box's front behind the rack front (its setback, 0-30 cm in 2 cm bins), "
        "carried along the row like the backs; predict, run and evaluate then move every box's front there too",
        False, action="store_true",
    )  # fmt: skip
    head_width: int = setting(
        "--head-width",
        "the head's channels (its 1-D block has twice as many); the inputs cached are the same for any width",
        BOX_WIDTH, type=int, metavar="C",
    )  # fmt: skip
    frames: int | None = setting(
        "--frames",
        "stream only the first N frames of each sequence (default: all): with fewer frames per scene the "
        "same minutes cover more scenes, and the head is short of scenes rather than of frames",
        type=int, metavar="N",
    )  # fmt: skip
    from_frame: int = setting(
        "--from-frame",
        "keep the slots of frame K on (0-based); the earlier frames are streamed only to build the "
        "model's memory and the parallax history (default %(default)s: every frame)",
        0, type=int, metavar="K",
    )  # fmt: skip
    cold_start: bool = setting(
        "--cold-start",
        "the frames before --from-frame skip the network: they enter only the motion estimate and the "
        "parallax history, and the memory starts at frame K (measured 1.5x the scenes per minute at --frames 6 "
        "--from-frame 3; the network's memory changes few cells)",
        False, action="store_true",
    )  # fmt: skip
    out: Path | None = setting("--out", "write the new checkpoint here (unset: CKPT is updated in place)", type=Path)
    cache_dir: Path | None = setting(
        "--cache-dir", "folder for the temporary input cache (default: the system's)", type=Path
    )
    keep_cache: Path | None = setting(
        "--keep-cache",
        "keep the input cache in DIR (created if missing), one part per data folder, and reuse a part when "
        "it holds this checkpoint's inputs for that folder's sequences; refused when it holds another's",
        type=Path, metavar="DIR",
    )  # fmt: skip
    cache_workers: int = setting(
        "--cache-workers",
        "split the streamed pass over N processes of one torch thread each (contiguous shares of the "
        "sequences; the same inputs as one pass); --threads then applies to the fit",
        1, type=int, metavar="N",
    )  # fmt: skip
    cache_only: bool = setting(
        "--cache-only",
        "make (or find) the input cache in --keep-cache DIR and stop: no head is fitted, no checkpoint "
        "written; a later fit with the same --keep-cache DIR and data reuses it",
        False, action="store_true",
    )  # fmt: skip
    pass_minutes: float | None = setting(
        "--pass-minutes",
        "start no sequence M minutes after the streamed pass began (each process streams at least one) and "
        "fit on the sequences streamed by then: a fit inside a time budget takes as many scenes as the machine "
        "streams (the record says how many); not with --keep-cache or --cache-only",
        type=float, metavar="M",
    )  # fmt: skip
    threads: int = setting("--threads", "CPU threads for torch (the fit's, and a one-process pass's)", 2, type=int)
    json_out: Path | None = json_out_setting("also write the fit's (or the cache's) summary as JSON here")
    quiet: bool = quiet_setting("hide the progress bars")
    precision: str = precision_setting(
        "; bf16 also runs the head's forward passes in the fit under bf16 autocast (about half the time with "
        "native bf16) and makes a cache of its own (--keep-cache)"
    )
    jpeg: float = jpeg_share_setting()
    jpeg_quality: list[int] = jpeg_quality_setting()


SETTINGS = FitBoxDepthSettings


def run(args: FitBoxDepthSettings) -> int:
    from network.checkpoint import load_checkpoint, model_from, save_with_head
    from network.training.box_cache import FrameChoice, StreamedPass
    from network.training.fit_box_depth import box_head_config, check_pass_minutes, fit_box_depth, keep_box_inputs
    from waresynth.visibility import SeenTracker

    check_counts(args, "threads", "sequences")
    if args.cache_dir is not None and not args.cache_dir.is_dir():
        raise InputError(f"--cache-dir {args.cache_dir}: not a folder")
    if args.keep_cache is not None and args.keep_cache.exists() and not args.keep_cache.is_dir():
        raise InputError(f"--keep-cache {args.keep_cache}: not a folder")
    if args.cache_workers < 1:
        raise InputError(f"--cache-workers must be >= 1, got {args.cache_workers}")
    if args.cache_only and args.keep_cache is None:
        raise InputError("--cache-only needs --keep-cache DIR (the cache it makes would be removed at once)")
    check_pass_minutes(args.pass_minutes, args.keep_cache)
    cfg = FitConfig(
        epochs=args.epochs, seed=args.seed, lr=args.lr, weight_decay=args.weight_decay, precision=args.precision
    )
    cfg.validate()
    choice = FrameChoice(args.frames, args.from_frame, args.cold_start)
    choice.validate()
    torch.set_num_threads(args.threads)
    payload, record = load_checkpoint(args.checkpoint)
    model = model_from(payload, record, args.checkpoint)
    use_precision(model, args.precision)  # the streamed pass's trunk (a kept cache records it)
    train = training_sequences(args)
    SeenTracker(train[0])  # fails at once, not after an hour, when the data lack depth, instance or scene files
    job = StreamedPass(model, SeenTracker, choice, progress=not args.quiet, workers=args.cache_workers)
    if args.cache_only:
        summary = keep_box_inputs(job, train, args.keep_cache, parallax=args.parallax)
        state = "found" if summary["cache_reused"] == summary["cache_parts"] else "made"
        print(
            f"{state} the inputs of {summary['train_slots']} shelf slots of {summary['train_sequences']} sequences "
            f"in {args.keep_cache} ({summary['cache_minutes']:.1f} minutes); fit with the same --keep-cache"
        )
        if args.json_out:
            atomic_write_json(args.json_out, nan_to_null(summary))
        return 0
    head, summary = fit_box_depth(
        job, train, cfg, args.cache_dir, parallax=args.parallax, keep_cache=args.keep_cache,
        pass_minutes=args.pass_minutes, width=args.head_width, front=args.front,
    )  # fmt: skip
    print(
        (
            f"reused the inputs cached in {args.keep_cache} for {summary['cache_reused']} of "
            f"{summary['cache_parts']} data folders; "
            if summary["cache_reused"]
            else ""
        )
        + f"fitted on {summary['train_slots']} shelf slots of {summary['train_sequences']} sequences "
        + (
            f"(of {summary['sequences_given']}: the pass stopped at --pass-minutes {args.pass_minutes:g}) "
            if summary["train_sequences"] < summary.get("sequences_given", 0)
            else ""
        )
        + f"({100 * summary['shown_fraction']:.0f} % of box columns shown); loss per epoch "
        + ", ".join(f"{v:.3f}" for v in summary["losses"])
    )
    out = args.out or args.checkpoint
    info = {"data": [str(d) for d in args.data], **jpeg_record(args), **summary}
    cfg_out = box_head_config(model.cfg, args.parallax, args.head_width, args.front)
    save_with_head(out, payload, record, cfg_out, "box_depth", head, "box_depth", info)
    print(f"wrote {out} (and {Path(out).with_suffix('.json').name})")
    if args.json_out:
        atomic_write_json(args.json_out, nan_to_null(summary))
    return 0
