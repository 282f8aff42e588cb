"""Where a process runs: its place among torchrun's processes (`DistEnv`) and its device (`device_for`), and the
device of a one-process command that runs a model (`single_process_device`: predict, run, evaluate).

Inference and training alike ask here; `network.training.distributed` adds the process group and the collectives.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from dataclasses import dataclass

import torch

from layouts.errors import InputError

ENV_VARS = ("RANK", "WORLD_SIZE", "LOCAL_RANK", "MASTER_ADDR", "MASTER_PORT")


@dataclass(frozen=True)
class DistEnv:
    """Where this process sits in a (possibly single-process) run."""

    rank: int = 0
    world_size: int = 1
    local_rank: int = 0

    @property
    def enabled(self) -> bool:
        return self.world_size > 1

    @property
    def is_main(self) -> bool:
        return self.rank == 0

    @classmethod
    def from_env(cls, environ: Mapping[str, str] | None = None) -> DistEnv:
        """Read torchrun's variables; none set -> single process. Inconsistent values -> `InputError`."""
        env = os.environ if environ is None else environ
        if "WORLD_SIZE" not in env and "RANK" not in env:
            return cls()
        vals: dict[str, int] = {}
        for name in ("RANK", "WORLD_SIZE", "LOCAL_RANK"):
            raw = env.get(name, "0" if name == "LOCAL_RANK" else None)
            if raw is None:
                raise InputError(
                    f"environment: {name} is not set (launch with torchrun, which sets {', '.join(ENV_VARS)})"
                )
            try:
                vals[name] = int(raw)
            except ValueError:
                raise InputError(f"environment: {name}={raw!r} is not an integer") from None
        rank, world, local = vals["RANK"], vals["WORLD_SIZE"], vals["LOCAL_RANK"]
        if world < 1 or not 0 <= rank < world or local < 0:
            raise InputError(f"environment: RANK={rank}, WORLD_SIZE={world}, LOCAL_RANK={local} are inconsistent")
        if world > 1:
            for name in ("MASTER_ADDR", "MASTER_PORT"):
                if not env.get(name):
                    raise InputError(f"environment: {name} is not set (launch with torchrun)")
        return cls(rank=rank, world_size=world, local_rank=local)


def device_for(env: DistEnv, device: str = "auto") -> torch.device:
    """The device this process trains on: ``auto`` = ``cuda:LOCAL_RANK`` when CUDA is present, else CPU."""
    if device not in ("auto", "cpu", "cuda"):
        raise InputError(f"--device must be auto, cpu or cuda, got {device!r}")
    if device == "cuda" or (device == "auto" and torch.cuda.is_available()):
        if not torch.cuda.is_available():
            raise InputError("--device cuda: no CUDA device is available")
        n = torch.cuda.device_count()
        if env.local_rank >= n:
            raise InputError(f"LOCAL_RANK {env.local_rank} has no GPU ({n} visible); use --nproc_per_node <= {n}")
        return torch.device("cuda", env.local_rank)
    return torch.device("cpu")


def single_process_device(command: str, device: str = "auto") -> torch.device:
    """Device for a one-process command (evaluate, predict); refuses to run as several torchrun ranks."""
    env = DistEnv.from_env()
    if env.enabled:
        raise InputError(f"{command} runs in one process; start it without torchrun (WORLD_SIZE={env.world_size})")
    return device_for(env, device)
