"""Stage ``graft`` of ``mvracklay train``: a network with the depth heads of another checkpoint, copied as they are.

The back-edge, upright and box-depth heads are fitted with the network frozen (the ``fit-*`` stages), on
the features of that network. Fitted apart (each on its own copy of one network), or after
``train --init-from HEADS`` has moved the network a little, they are joined here: this writes NET's
weights and record with HEADS' head weights, head flags and fit records beside them (the box decision
offsets stay NET's; the rack-depth offset goes with the rack heads, HEADS' where one is copied). The
record says where the heads came from (``heads_grafted_from``, ``heads_grafted``). ``--only FLAG ...``
copies some of the heads and leaves NET its own others.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from layouts.errors import InputError
from mvracklay.settings import setting
from network.checkpoint import RACK_DEPTH_HEADS, load_checkpoint, save_checkpoint
from network.model.config import ModelConfig

#: (model-config flag, state-dict prefix, record key) of each head fitted after training
HEADS = (
    ("back_edges", "back", "back_edges"),
    ("uprights", "uprights", "uprights"),
    ("box_depth", "box_depth", "box_depth"),
)
#: model-config flags that belong to the box-depth head
BOX_OPTIONS = ("box_parallax", "box_width", "box_front")


def graft(heads_path: Path, net_path: Path, out: Path, only: tuple[str, ...] = ()) -> list[str]:
    """Write ``out``; return the heads copied (those of ``only`` if given; NET keeps its other heads)."""
    h_payload, h_record = load_checkpoint(heads_path)
    n_payload, n_record = load_checkpoint(net_path)
    h_cfg = ModelConfig.from_dict(h_record.get("model_config"), f"{heads_path} (model_config)")
    n_cfg = ModelConfig.from_dict(n_record.get("model_config"), f"{net_path} (model_config)")
    for name in ("input_width", "input_height", "encoder_width", "hidden", "spec"):
        if getattr(h_cfg, name) != getattr(n_cfg, name):
            raise InputError(f"{net_path}: {name} differs from {heads_path}'s; the heads would not fit it")
    state = dict(n_payload["model"])
    dtype = next(v.dtype for v in state.values() if v.is_floating_point())
    record = dict(n_record)
    flags, copied = {}, []
    for flag, prefix, key in HEADS:
        if not getattr(h_cfg, flag) or (only and flag not in only):
            continue
        state = {k: v for k, v in state.items() if not k.startswith(f"{prefix}.")}
        state.update(
            {
                k: (v.to(dtype) if v.is_floating_point() else v)
                for k, v in h_payload["model"].items()
                if k.startswith(f"{prefix}.")
            }
        )
        flags[flag] = True
        record[key] = h_record.get(key)
        copied.append(flag)
    if not copied:
        raise InputError(f"{heads_path}: has no depth heads to copy" + (f" of {', '.join(only)}" if only else ""))
    if set(copied) & set(RACK_DEPTH_HEADS):  # the reader's offset belongs to the heads it was measured on
        record.pop("rack_depth_offset", None)
        if h_record.get("rack_depth_offset") is not None:
            record["rack_depth_offset"] = h_record["rack_depth_offset"]
    if "box_depth" in copied:
        flags.update({k: getattr(h_cfg, k) for k in BOX_OPTIONS})
    write_with_heads(
        out, n_payload, state, record, replace(n_cfg, **flags), heads_grafted_from=str(heads_path), heads_grafted=copied
    )
    return copied


def write_with_heads(
    out: Path, payload: dict[str, Any], state: dict[str, Any], record: dict[str, Any], cfg: ModelConfig, **notes: Any
) -> None:
    """Write ``out``: ``payload`` with the model weights ``state`` and ``record`` with ``cfg`` (its head flags
    changed) and ``notes`` (where the heads came from or went); shared with drop_heads.py."""
    rest = {k: v for k, v in payload.items() if k != "record_json"}
    kept = {k: v for k, v in record.items() if k not in ("format", "format_version")}  # save_checkpoint writes them
    save_checkpoint(out, {**rest, "model": state}, {**kept, "model_config": cfg.to_dict(), **notes})


NAME = "graft"
HELP = "copy the depth heads of one checkpoint onto another network (e.g. fine-tuned from it, or fitted apart)"
DESCRIPTION = __doc__.split("\n\n")[0]


@dataclass(frozen=True)
class GraftSettings:
    """The options of stage ``graft`` (each field's option, default and help in its metadata)."""

    heads: Path | None = setting("--heads", "checkpoint with fitted depth heads", type=Path, required=True)
    net: Path | None = setting(
        "--net", "the network to give them (e.g. train --init-from HEADS)", type=Path, required=True
    )
    out: Path | None = setting("--out", "checkpoint to write", type=Path, required=True)
    only: list[str] = setting(
        "--only", "copy only these heads; NET keeps its own others (to measure which head a difference comes from)",
        [], nargs="+", choices=[h[0] for h in HEADS],
    )  # fmt: skip


SETTINGS = GraftSettings


def run(args: GraftSettings) -> int:
    copied = graft(args.heads, args.net, args.out, tuple(args.only))
    print(f"wrote {args.out}: {args.net.name}'s network with {', '.join(copied)} from {args.heads}")
    return 0
