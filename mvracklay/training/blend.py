"""Stage ``blend`` of ``mvracklay train``: a fine-tuned network blended back into the network it started from.

Fine-tuned on other looks and camera set-ups, a network gains on them and loses a little on the footage it was
trained for; the weights part of the way between the two keep the first and most of the gain (weight-space
ensembling, Wortsman et al., "Robust fine-tuning of zero-shot models", CVPR 2022). This writes BASE's record and
depth heads with network weights ``(1 - alpha) * BASE + alpha * TUNED`` (batch-norm statistics too). The heads
(back edges, uprights, box depth) are BASE's as they are: fitted on BASE's features, they read a blend that stays
near them, and fitting them again costs hours. The box decision offsets and the rack-depth offset are BASE's
until ``calibrate`` measures them on the blend.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch

from layouts.errors import InputError
from mvracklay.settings import setting
from mvracklay.training.graft import HEADS, write_with_heads
from network.checkpoint import load_checkpoint
from network.model.config import ModelConfig

#: model-config fields two checkpoints must share to be blended (the network's shape)
SAME_NETWORK = ("variant", "input_width", "input_height", "encoder_width", "hidden", "memory_hidden", "decoder_width",
                "lstm_layers", "arch", "spec")  # fmt: skip
#: state-dict prefixes of the depth heads: BASE's, never blended
HEAD_PREFIXES = tuple(f"{prefix}." for _, prefix, _ in HEADS)


def blend_states(
    base: dict[str, torch.Tensor], tuned: dict[str, torch.Tensor], alpha: float, where: str
) -> tuple[dict[str, torch.Tensor], int]:
    """BASE's state with every floating network tensor ``(1 - alpha) * base + alpha * tuned`` (computed in fp32,
    stored as fp32); the heads and integer counters BASE's. Returns the state and the count blended."""
    out: dict[str, torch.Tensor] = {}
    blended = 0
    for k, v in base.items():
        if k.startswith(HEAD_PREFIXES) or not v.is_floating_point():
            out[k] = v
            continue
        w = tuned.get(k)
        if w is None:
            raise InputError(f"{where}: has no tensor {k}, which the base network has; not the same network")
        if tuple(w.shape) != tuple(v.shape):
            raise InputError(
                f"{where}: tensor {k} is {tuple(w.shape)}, the base's {tuple(v.shape)}; not the same network"
            )
        out[k] = torch.lerp(v.float(), w.float(), alpha)
        blended += 1
    return out, blended


def blend(base_path: Path, tuned_path: Path, alpha: float, out: Path) -> int:
    """Write ``out`` (module docstring); return the number of tensors blended."""
    if not 0.0 <= alpha <= 1.0:
        raise InputError(f"--alpha: {alpha:g} is outside 0..1 (0 = the base as it is, 1 = the tuned network)")
    b_payload, b_record = load_checkpoint(base_path)
    t_payload, t_record = load_checkpoint(tuned_path)
    b_cfg = ModelConfig.from_dict(b_record.get("model_config"), f"{base_path} (model_config)")
    t_cfg = ModelConfig.from_dict(t_record.get("model_config"), f"{tuned_path} (model_config)")
    for name in SAME_NETWORK:
        if getattr(b_cfg, name) != getattr(t_cfg, name):
            raise InputError(
                f"{tuned_path}: {name} is {getattr(t_cfg, name)!r}, the base's {getattr(b_cfg, name)!r}; "
                "only a network fine-tuned from the base blends with it"
            )
    state, count = blend_states(b_payload["model"], t_payload["model"], alpha, str(tuned_path))
    note: dict[str, Any] = {"base": str(base_path), "tuned": str(tuned_path), "alpha": alpha, "tensors": count}
    for key in ("step", "data", "train_config", "best_score"):
        if t_record.get(key) is not None:
            note[f"tuned_{key}"] = t_record[key]
    write_with_heads(out, {}, state, dict(b_record), b_cfg, blended=note)
    return count


NAME = "blend"
HELP = "blend a fine-tuned network back into the one it started from, keeping that one's depth heads"
DESCRIPTION = __doc__.split("\n\n")[1]


@dataclass(frozen=True)
class BlendSettings:
    """The options of stage ``blend`` (each field's option, default and help in its metadata)."""

    base: str | None = setting(
        "--base", "the network fine-tuned from (a .pt checkpoint or a shipped model's name): its record and heads",
        required=True,
    )  # fmt: skip
    tuned: Path | None = setting("--tuned", "the network fine-tuned from --base (train --init-from BASE)", type=Path,
                                 required=True)  # fmt: skip
    alpha: float = setting("--alpha", "the tuned network's share of the weights (0..1)", 0.3, type=float)
    out: Path | None = setting("--out", "checkpoint to write", type=Path, required=True)


SETTINGS = BlendSettings


def run(args: BlendSettings) -> int:
    from mvracklay.models import resolve_checkpoint

    base = Path(resolve_checkpoint(args.base, "--base"))
    count = blend(base, args.tuned, args.alpha, args.out)
    print(
        f"wrote {args.out}: {args.alpha:g} of {args.tuned.name}'s network in {base.name}'s ({count} tensors), its heads"
    )
    return 0
