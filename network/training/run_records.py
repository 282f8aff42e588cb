"""What a run folder's records hold: the weights' fingerprint, the best score on disk, the temporary files a
crash leaves, and the epoch's metrics as logged and printed."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

from torch import nn

from network.training.distributed import state_fingerprint


def is_tmp_of(path: Path, names: tuple[str, ...]) -> bool:
    """A temporary file `layouts.fileio.atomic_write_bytes` left behind for one of ``names``."""
    return path.name.endswith(".tmp") and any(path.name.startswith(f".{n}.") for n in names)


def weights_fingerprint(model: nn.Module, discs: nn.Module | None = None) -> str:
    """SHA-256 of the trainable weights (model, then discriminators): what DDP keeps identical on every rank.

    BatchNorm running statistics are left out: each rank updates them from its own batch and DDP
    re-broadcasts rank 0's at every forward, so the checkpoint (rank 0) holds rank 0's.
    """
    params = {f"model.{k}": p for k, p in model.named_parameters()}
    if discs is not None:
        params.update({f"discs.{k}": p for k, p in discs.named_parameters()})
    return state_fingerprint(params)


def best_on_disk(path: Path) -> float:
    """The score recorded beside best.pt (it may be newer than last.pt after a crash); -inf if none."""
    try:
        v = json.loads(path.read_text()).get("best_score")
        return float(v) if v is not None and math.isfinite(float(v)) else -math.inf
    except (OSError, ValueError, TypeError, AttributeError):
        return -math.inf


def compact_metrics(table: dict[str, Any]) -> dict[str, Any]:
    """A validation table with its NaNs as None (JSON has no NaN)."""
    return {
        v: {c: {k: (None if isinstance(x, float) and math.isnan(x) else x) for k, x in m.items()} for c, m in d.items()}
        for v, d in table.items()
    }


def epoch_summary(e: dict[str, Any]) -> str:
    """The line printed after an epoch: its step, minutes, loss and validation mIoUs."""
    s = f"epoch {e['epoch']} step {e['step']} {e['train_wall_minutes']:.1f} min loss {e['loss'].get('total', float('nan')):.3f}"
    if "val_visible" in e:
        t = e["val_visible"]
        f = lambda x: "nan" if x is None else f"{100 * x:.1f}"  # noqa: E731
        s += (
            f" | val mIoU top rack {f(t['top']['rack']['miou'])} box {f(t['top']['box']['miou'])}"
            f" front rack {f(t['front']['rack']['miou'])} box {f(t['front']['box']['miou'])}"
        )
    return s
