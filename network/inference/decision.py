"""The decision offsets a checkpoint's record carries and how inference applies them.

`network.training.calibrate` chooses them on tuning data: one box-logit offset per view (subtracted from the
box logit before the argmax, undoing the prior shift of the training's class weights) and a rack-depth offset
(metres added to every rack depth read, `network.heads.backedge.DepthReader`). `network.checkpoint` checks a
record's values with `check_offsets` and `check_depth_offset`; `network.inference.predictor.Predictor` applies
the box offsets with `apply_box_offset`.
"""

from __future__ import annotations

import math
from typing import Any

import torch

from layouts import BOX, VIEWS
from layouts.errors import InputError

#: box-logit offsets outside this range are refused (they would erase or flood the box class)
LIMIT = 5.0
#: rack-depth offsets beyond this many metres are refused: a reader that far off is broken, not biased
DEPTH_OFFSET_LIMIT = 0.2


def check_offsets(value: Any, source: str) -> dict[str, float]:
    """``{"top": float, "front": float}`` from a record value (None = no calibration: zeros)."""
    if value is None:
        return {v: 0.0 for v in VIEWS}
    if not isinstance(value, dict) or set(value) != set(VIEWS):
        raise InputError(f"{source}: box_logit_offset must be an object with keys {list(VIEWS)}, got {value!r}")
    out = {}
    for v in VIEWS:
        x = value[v]
        if isinstance(x, bool) or not isinstance(x, (int, float)) or not math.isfinite(x) or abs(x) > LIMIT:
            raise InputError(f"{source}: box_logit_offset[{v!r}] must be a number in [-{LIMIT}, {LIMIT}], got {x!r}")
        out[v] = float(x)
    return out


def check_depth_offset(value: Any, source: str) -> float:
    """A record's ``rack_depth_offset`` in metres (None: not calibrated, 0), or a one-line `InputError`."""
    if value is None:
        return 0.0
    if (
        isinstance(value, bool)
        or not isinstance(value, (int, float))
        or not math.isfinite(value)
        or abs(value) > DEPTH_OFFSET_LIMIT
    ):
        raise InputError(
            f"{source}: rack_depth_offset must be a number of metres in [-{DEPTH_OFFSET_LIMIT}, "
            f"{DEPTH_OFFSET_LIMIT}], got {value!r}"
        )
    return float(value)


def apply_box_offset(logits: torch.Tensor, offset: float) -> torch.Tensor:
    """``(..., 3, D, D)`` logits with ``offset`` subtracted from the box class (a new tensor)."""
    if offset == 0.0:
        return logits
    shift = torch.zeros(logits.shape[-3], dtype=logits.dtype, device=logits.device)
    shift[BOX] = offset
    return logits - shift.view(-1, 1, 1)
