"""Multi-process training support: torchrun detection, process group, per-rank data, small collectives.

``torchrun`` (``torch.distributed.run``) starts one process per worker and tells each its place
through environment variables (``RANK``, ``WORLD_SIZE``, ``LOCAL_RANK``, ``MASTER_ADDR``,
``MASTER_PORT``). `DistEnv.from_env` reads them; without them training is one process, as
before. The backend is NCCL when CUDA is present (one GPU per process, ``cuda:LOCAL_RANK``) and
gloo on CPU. Every rank draws its windows from one shared, seeded stream of permutations
(`rank_indices`), so ranks see disjoint windows within each pass over the data and the run is
reproducible for a given seed and world size.
"""

from __future__ import annotations

import datetime
import hashlib
import os
from collections.abc import Iterator, Mapping
from dataclasses import dataclass

import torch
import torch.distributed as dist

from layouts.errors import InputError

ENV_VARS = ("RANK", "WORLD_SIZE", "LOCAL_RANK", "MASTER_ADDR", "MASTER_PORT")
#: how long a collective may wait (rank 0 validating while the others wait, a slow checkpoint write)
DEFAULT_TIMEOUT_MIN = 120.0


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


def default_backend() -> str:
    return "nccl" if torch.cuda.is_available() else "gloo"


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


def init_process_group(env: DistEnv, device: torch.device, timeout_min: float = DEFAULT_TIMEOUT_MIN) -> str:
    """Join the process group (NCCL for CUDA devices, gloo on CPU); returns the backend's name."""
    backend = "nccl" if device.type == "cuda" else "gloo"
    if device.type == "cuda":
        torch.cuda.set_device(device)
    if not dist.is_initialized():
        dist.init_process_group(
            backend=backend,
            rank=env.rank,
            world_size=env.world_size,
            timeout=datetime.timedelta(minutes=timeout_min),
        )
    return backend


def shutdown(wait: bool = False) -> None:
    """Close the process group, if any. ``wait``: first a barrier, so no rank tears its connections
    down while another is still in its last collective or checkpoint write (gloo can abort a rank
    whose peer left early); only on the normal path, since after an error a peer may never arrive."""
    if dist.is_available() and dist.is_initialized():
        if wait and dist.get_world_size() > 1:
            try:
                dist.barrier()
            except RuntimeError:
                pass  # a peer is gone: nothing left to wait for
        dist.destroy_process_group()


def rank_indices(
    n_items: int, num_samples: int, *, rank: int, world_size: int, generator: torch.Generator
) -> list[int]:
    """This rank's ``num_samples`` item indices from a stream of random permutations shared by all ranks.

    The stream (``num_samples * world_size`` long) is the concatenation of seeded permutations of
    ``range(n_items)``, exactly what `torch.utils.data.RandomSampler` draws without replacement;
    rank r takes positions ``r, r + W, r + 2W, ...``, as `DistributedSampler` does. Within one
    permutation the ranks' windows are therefore disjoint, and one process (W = 1) gets the whole
    stream.
    """
    if n_items < 1:
        raise ValueError("no items to sample")
    total = num_samples * world_size
    stream: list[int] = []
    while len(stream) < total:
        stream.extend(torch.randperm(n_items, generator=generator).tolist())
    return stream[rank:total:world_size]


class ListSampler(torch.utils.data.Sampler[int]):
    """Yields a fixed list of indices (this rank's share of the epoch, minus the steps already done)."""

    def __init__(self, indices: list[int]) -> None:
        self.indices = indices

    def __iter__(self) -> Iterator[int]:
        return iter(self.indices)

    def __len__(self) -> int:
        return len(self.indices)


def _tensor(values: list[float], device: torch.device, dtype: torch.dtype = torch.float64) -> torch.Tensor:
    return torch.tensor(values, dtype=dtype, device=device)


def all_reduce(values: list[float], op: str, device: torch.device) -> list[float]:
    """Element-wise ``sum`` / ``max`` / ``min`` of a short list of numbers over all ranks."""
    if not (dist.is_available() and dist.is_initialized()):
        return list(values)
    ops = {"sum": dist.ReduceOp.SUM, "max": dist.ReduceOp.MAX, "min": dist.ReduceOp.MIN}
    t = _tensor(values, device)
    dist.all_reduce(t, op=ops[op])
    return [float(x) for x in t.cpu()]


def barrier(device: torch.device) -> None:
    """Wait for every rank (an all-reduce, which works the same on gloo and NCCL)."""
    all_reduce([0.0], "sum", device)


def state_fingerprint(*states: Mapping[str, torch.Tensor]) -> str:
    """SHA-256 over the names, dtypes, shapes and bytes of tensors: equal only for bit-identical weights."""
    h = hashlib.sha256()
    for state in states:
        for name in sorted(state):
            t = state[name].detach().cpu().contiguous()
            h.update(f"{name}|{t.dtype}|{tuple(t.shape)}|".encode())
            h.update(t.reshape(-1).view(torch.uint8).numpy().tobytes())
    return h.hexdigest()


def gather_fingerprints(fingerprint: str, device: torch.device) -> list[str]:
    """Every rank's fingerprint (hex SHA-256), in rank order; just ours without a process group."""
    if not (dist.is_available() and dist.is_initialized()):
        return [fingerprint]
    raw = bytes.fromhex(fingerprint)
    mine = torch.tensor(list(raw), dtype=torch.int64, device=device)
    parts = [torch.empty_like(mine) for _ in range(dist.get_world_size())]
    dist.all_gather(parts, mine)
    return [bytes(int(x) for x in p.cpu()).hex() for p in parts]
