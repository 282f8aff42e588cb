"""The arithmetic precisions the network runs in, in one place: training's forward passes under bf16
autocast (`forward_autocast`), the inference trunk's frozen graph in bf16 (`network.model.frozen.set_precision`),
and whether this CPU computes bf16 natively (`cpu_has_native_bf16`), which decides whether either is worth it."""

from __future__ import annotations

import os
from pathlib import Path

import torch

from layouts.errors import InputError

PRECISIONS = ("fp32", "bf16")  #: the precisions a command's ``--precision`` takes


def check_precision(precision: str, option: str = "--precision") -> None:
    """One line naming ``option`` when ``precision`` is not one of `PRECISIONS`."""
    if precision not in PRECISIONS:
        raise InputError(f"{option} must be one of {', '.join(PRECISIONS)}, got {precision!r}")


def cpu_has_native_bf16(cpuinfo: str | os.PathLike = "/proc/cpuinfo") -> bool | None:
    """Whether this CPU computes bf16 natively (AVX512-BF16 or AMX-BF16); None where unknown (no ``cpuinfo``).

    Without it, bf16 autocast emulates the arithmetic: on an AVX2 AMD EPYC a `racklay` step at
    128x128 took 13.6 s in bf16 against 0.77 s in fp32, at 256x256 36.4 s against 1.52 s (`benchmarks/bench_train_step.py`).
    """
    try:
        text = Path(cpuinfo).read_text(errors="replace")
    except OSError:
        return None
    flags = {f for line in text.splitlines() if line.startswith("flags") for f in line.split(":", 1)[-1].split()}
    if not flags:
        return None
    return bool(flags & {"avx512_bf16", "amx_bf16"})


def auto_precision(cpuinfo: str | os.PathLike = "/proc/cpuinfo") -> str:
    """What ``precision = "auto"`` trains in: bf16 where the CPU computes it natively (AVX512-BF16 or AMX,
    `cpu_has_native_bf16`), else fp32 (emulated bf16 is 18-24x slower). Checkpoints stay fp32 either way."""
    return "bf16" if cpu_has_native_bf16(cpuinfo) else "fp32"


def forward_autocast(device_type: str, precision: str) -> torch.autocast:
    """The context training's forward passes run in: bf16 autocast for ``precision`` bf16, else a no-op.

    On CPUs with native bf16 (AVX512-BF16, AMX) a step takes ~0.6x the time; validation, evaluation
    and the written weights stay fp32.
    """
    return torch.autocast(device_type, dtype=torch.bfloat16, enabled=precision == "bf16")
