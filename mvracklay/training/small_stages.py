"""The small stages of a recipe: copy a checkpoint, export fp16 weights, check the held-out seeds, draw learning
curves, run a Python module or script (benchmarks, tables). Each stage is a `mvracklay.training.stages.Stage`
whose options come from its settings dataclass (``SETTINGS``, `mvracklay.settings.add_options`)."""

from __future__ import annotations

import json
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

from layouts.errors import InputError
from layouts.fileio import atomic_write_bytes
from mvracklay.settings import setting
from mvracklay.training.stages import Stage
from network.training.curves import X_AXES


@dataclass(frozen=True)
class CopySettings:
    src: Path | None = setting("--from", "the .pt checkpoint to copy", type=Path, required=True, dest="src")
    dst: Path | None = setting("--to", "where to write the copy", type=Path, required=True, dest="dst")


@dataclass(frozen=True)
class ExportSettings:
    checkpoint: Path | None = setting("--checkpoint", "the .pt checkpoint to export", type=Path, required=True)
    out: Path | None = setting("--out", "the weights file to write (its .json beside)", type=Path, required=True)
    note: str | None = setting("--note", "a line on how the weights were trained, kept in their JSON")
    with_discriminators: bool = setting(
        "--with-discriminators", "keep the discriminators too (fp16)", False, action="store_true"
    )


@dataclass(frozen=True)
class CheckSeedsSettings:
    heldout: Path | None = setting("--heldout", "the held-out dataset folder", type=Path, required=True)
    tune: Path | None = setting("--tune", "the tuning dataset folder", type=Path, required=True)
    train: list[Path] | None = setting("--train", "the training dataset folders", type=Path, nargs="+", required=True)


@dataclass(frozen=True)
class CurvesSettings:
    out: str | None = setting("out", "PNG to write", metavar="OUT.png")
    runs: list[str] | None = setting(
        "runs", "a run directory (or metrics.jsonl) and its label", nargs="+", metavar="LABEL=RUN_DIR"
    )
    x_from: float = setting("--from", "draw points from this x on", 0.0, type=float, metavar="X", dest="x_from")
    x: str = setting(
        "--x", "x axis: training CPU-minutes (default), wall-clock minutes, or optimiser steps", "cpu-minutes",
        choices=sorted(X_AXES),
    )  # fmt: skip


@dataclass(frozen=True)
class PythonSettings:
    module: str | None = setting("--module", "a module to run as python -m MODULE (e.g. a benchmark)")
    script: Path | None = setting("--script", "a script file to run", type=Path)
    args: list[str] | None = setting("args", "its arguments (the recipe's args = [...])", nargs="*")


def _copy(args: CopySettings) -> int:
    if not args.src.is_file():
        raise InputError(f"--from {args.src}: no such file")
    args.dst.parent.mkdir(parents=True, exist_ok=True)
    for src, dst in ((args.src.with_suffix(".json"), args.dst.with_suffix(".json")), (args.src, args.dst)):
        if src.is_file():
            atomic_write_bytes(dst, src.read_bytes())
    print(f"wrote {args.dst}")
    return 0


COPY = Stage(
    "copy",
    "copy a checkpoint and its .json record (e.g. a run paused at a stage, before it goes on)",
    CopySettings,
    _copy,
)


def _export(args: ExportSettings) -> int:
    from network.checkpoint import export_weights

    args.out.parent.mkdir(parents=True, exist_ok=True)
    export_weights(args.checkpoint, args.out, note=args.note, discriminators=args.with_discriminators)
    print(f"wrote {args.out} ({args.out.stat().st_size / 2**20:.1f} MiB, fp16)")
    return 0


EXPORT = Stage("export", "write a checkpoint's model weights as fp16 (as train --export does)", ExportSettings, _export)


def _check_seeds(args: CheckSeedsSettings) -> int:
    def seeds(folder: Path) -> set[int]:
        path = folder / "manifest.json"
        if not path.is_file():
            raise InputError(f"{folder}: no manifest.json (not a generated dataset)")
        return {e["seed"] for e in json.loads(path.read_text())["sequences"]}

    held, tune = seeds(args.heldout), seeds(args.tune)
    used = set().union(*(seeds(f) for f in args.train))
    if held & (used | tune):
        raise InputError(f"{args.heldout}: held-out sequence seeds overlap a training or the tuning set")
    print(f"held-out: {len(held)} sequence seeds, none used in training ({len(used)}) or tuning ({len(tune)})")
    return 0


CHECK_SEEDS = Stage(
    "check-seeds",
    "refuse held-out sequence seeds that a training or the tuning set uses",
    CheckSeedsSettings,
    _check_seeds,
)


def _curves(args: CurvesSettings) -> int:
    from network.training.curves import plot_curves

    bad = [a for a in args.runs if "=" not in a or not a.split("=", 1)[0]]
    if bad:
        raise InputError(f"not LABEL=RUN_DIR: {bad[0]!r}")
    plot_curves(dict(a.split("=", 1) for a in args.runs), args.out, x_key=X_AXES[args.x], x_from=args.x_from)
    print(f"wrote {args.out}")
    return 0


CURVES = Stage(
    "curves",
    "draw runs' validation mIoU (top/front x rack/box) against training time or steps as a PNG",
    CurvesSettings,
    _curves,
)


def _python(args: PythonSettings) -> int:
    if (args.module is None) == (args.script is None):
        raise InputError("give one of --module and --script")
    if args.script is not None and not args.script.is_file():
        raise InputError(f"--script {args.script}: no such file")
    given = list(args.args or [])
    rest = given[1:] if given[:1] == ["--"] else given
    cmd = [sys.executable, *(["-m", args.module] if args.module else [str(args.script)]), *rest]
    sys.stdout.flush()
    done = subprocess.run(cmd, capture_output=True, text=True)
    sys.stdout.write(done.stdout)
    sys.stderr.write(done.stderr)
    if done.returncode:
        last = (done.stderr.strip().splitlines() or ["(no message)"])[-1]
        raise InputError(f"{' '.join(cmd[1:3])} exited with status {done.returncode}: {last}")
    return 0


PYTHON = Stage(
    "python",
    "run a Python module (-m) or script with arguments; its output goes to the stage's log",
    PythonSettings,
    _python,
)
