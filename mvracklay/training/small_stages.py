"""The small stages of a recipe: copy a checkpoint, export fp16 weights, check the held-out seeds, draw learning
curves, run a Python module or script (benchmarks, tables)."""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

from layouts.errors import InputError
from layouts.fileio import atomic_write_bytes


class _Stage:
    """A stage as a command module has it: ``NAME``, ``HELP``, ``add_arguments``, ``run``."""

    NAME = ""
    HELP = ""

    @staticmethod
    def add_arguments(p: argparse.ArgumentParser) -> None:  # pragma: no cover - overridden
        raise NotImplementedError

    @staticmethod
    def run(args: argparse.Namespace) -> int:  # pragma: no cover - overridden
        raise NotImplementedError


class copy(_Stage):  # noqa: N801 - named as the stage
    NAME = "copy"
    HELP = "copy a checkpoint and its .json record (e.g. a run paused at a stage, before it goes on)"

    @staticmethod
    def add_arguments(p: argparse.ArgumentParser) -> None:
        p.add_argument("--from", dest="src", type=Path, required=True, help="the .pt checkpoint to copy")
        p.add_argument("--to", dest="dst", type=Path, required=True, help="where to write the copy")

    @staticmethod
    def run(args: argparse.Namespace) -> int:
        if not args.src.is_file():
            raise InputError(f"--from {args.src}: no such file")
        args.dst.parent.mkdir(parents=True, exist_ok=True)
        for src, dst in ((args.src.with_suffix(".json"), args.dst.with_suffix(".json")), (args.src, args.dst)):
            if src.is_file():
                atomic_write_bytes(dst, src.read_bytes())
        print(f"wrote {args.dst}")
        return 0


class export(_Stage):  # noqa: N801
    NAME = "export"
    HELP = "write a checkpoint's model weights as fp16 (as train --export does)"

    @staticmethod
    def add_arguments(p: argparse.ArgumentParser) -> None:
        p.add_argument("--checkpoint", type=Path, required=True, help="the .pt checkpoint to export")
        p.add_argument("--out", type=Path, required=True, help="the weights file to write (its .json beside)")
        p.add_argument("--note", help="a line on how the weights were trained, kept in their JSON")
        p.add_argument("--with-discriminators", action="store_true", help="keep the discriminators too (fp16)")

    @staticmethod
    def run(args: argparse.Namespace) -> int:
        from network.checkpoint import export_weights

        args.out.parent.mkdir(parents=True, exist_ok=True)
        export_weights(args.checkpoint, args.out, note=args.note, discriminators=args.with_discriminators)
        print(f"wrote {args.out} ({args.out.stat().st_size / 2**20:.1f} MiB, fp16)")
        return 0


class check_seeds(_Stage):  # noqa: N801
    NAME = "check-seeds"
    HELP = "refuse held-out sequence seeds that a training or the tuning set uses"

    @staticmethod
    def add_arguments(p: argparse.ArgumentParser) -> None:
        p.add_argument("--heldout", type=Path, required=True, help="the held-out dataset folder")
        p.add_argument("--tune", type=Path, required=True, help="the tuning dataset folder")
        p.add_argument("--train", type=Path, nargs="+", required=True, help="the training dataset folders")

    @staticmethod
    def run(args: argparse.Namespace) -> int:
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


class curves(_Stage):  # noqa: N801
    NAME = "curves"
    HELP = "draw runs' validation mIoU (top/front x rack/box) against training time or steps as a PNG"

    @staticmethod
    def add_arguments(p: argparse.ArgumentParser) -> None:
        from network.training.curves import X_AXES

        p.add_argument("out", metavar="OUT.png", help="PNG to write")
        p.add_argument(
            "runs", nargs="+", metavar="LABEL=RUN_DIR", help="a run directory (or metrics.jsonl) and its label"
        )
        p.add_argument("--from", dest="x_from", type=float, default=0.0, metavar="X", help="draw points from this x on")
        p.add_argument("--x", choices=sorted(X_AXES), default="cpu-minutes",
                       help="x axis: training CPU-minutes (default), wall-clock minutes, or optimiser steps")  # fmt: skip

    @staticmethod
    def run(args: argparse.Namespace) -> int:
        from network.training.curves import X_AXES, plot_curves

        bad = [a for a in args.runs if "=" not in a or not a.split("=", 1)[0]]
        if bad:
            raise InputError(f"not LABEL=RUN_DIR: {bad[0]!r}")
        plot_curves(dict(a.split("=", 1) for a in args.runs), args.out, x_key=X_AXES[args.x], x_from=args.x_from)
        print(f"wrote {args.out}")
        return 0


class python(_Stage):  # noqa: N801
    NAME = "python"
    HELP = "run a Python module (-m) or script with arguments; its output goes to the stage's log"

    @staticmethod
    def add_arguments(p: argparse.ArgumentParser) -> None:
        p.add_argument("--module", help="a module to run as python -m MODULE (e.g. a benchmark)")
        p.add_argument("--script", type=Path, help="a script file to run")
        p.add_argument("args", nargs="*", help="its arguments (the recipe's args = [...])")

    @staticmethod
    def run(args: argparse.Namespace) -> int:
        if (args.module is None) == (args.script is None):
            raise InputError("give one of --module and --script")
        if args.script is not None and not args.script.is_file():
            raise InputError(f"--script {args.script}: no such file")
        rest = args.args[1:] if args.args[:1] == ["--"] else args.args
        cmd = [sys.executable, *(["-m", args.module] if args.module else [str(args.script)]), *rest]
        sys.stdout.flush()
        done = subprocess.run(cmd, capture_output=True, text=True)
        sys.stdout.write(done.stdout)
        sys.stderr.write(done.stderr)
        if done.returncode:
            last = (done.stderr.strip().splitlines() or ["(no message)"])[-1]
            raise InputError(f"{' '.join(cmd[1:3])} exited with status {done.returncode}: {last}")
        return 0
