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
from collections.abc import Iterator, Mapping

import torch
import torch.distributed as dist

from network.device import DistEnv

#: how long a collective may wait (rank 0 validating while the others wait, a slow checkpoint write)
DEFAULT_TIMEOUT_MIN = 120.0


def default_backend() -> str:
    return "nccl" if torch.cuda.is_available() else "gloo"


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
