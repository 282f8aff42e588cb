#!/usr/bin/env python3
"""A checkpoint with some of its depth heads taken out, the rest as it was.

    .venv/bin/python benchmarks/drop_heads.py weights/mvracklay-disc-4-256.pt runs/rack-heads.pt --heads box_depth
    mvracklay evaluate --checkpoint runs/rack-heads.pt --data data/heldout256 --split all

``evaluate --no-depth-read`` turns every head off at once; this writes the file without the heads named, so
that a file with fitted heads can be compared with another that was given only some of them (the shipped
256x256 network with its rack-depth heads alone against a recipe that fits no box-depth head). The
network's weights, the other heads and the box decision offsets are kept bit for bit; the record notes
``heads_dropped``.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from mvracklay.training.graft import BOX_OPTIONS, HEADS, write_with_heads  # noqa: E402

from layouts.errors import InputError  # noqa: E402
from network.checkpoint import load_checkpoint  # noqa: E402
from network.model.net import ModelConfig  # noqa: E402


def drop(path: Path, out: Path, heads: tuple[str, ...]) -> list[str]:
    """Write ``out``: ``path`` without the heads ``heads`` (model-config flags); return those it had."""
    if not heads:
        raise InputError("--heads: name at least one head to drop")
    payload, record = load_checkpoint(path)
    cfg = ModelConfig.from_dict(record.get("model_config"), f"{path} (model_config)")
    had = [flag for flag, _, _ in HEADS if flag in heads and getattr(cfg, flag)]
    if not had:
        raise InputError(f"{path}: has none of the heads {', '.join(heads)}")
    state = dict(payload["model"])
    flags: dict[str, bool] = {}
    for flag, prefix, key in HEADS:
        if flag in had:
            state = {k: v for k, v in state.items() if not k.startswith(f"{prefix}.")}
            flags[flag] = False
            record.pop(key, None)
    if "box_depth" in had:
        flags.update(dict.fromkeys(BOX_OPTIONS, False))
    write_with_heads(out, payload, state, record, replace(cfg, **flags), heads_dropped=had)
    return had


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("checkpoint", type=Path, help="checkpoint with fitted depth heads")
    ap.add_argument("out", type=Path, help="checkpoint to write")
    ap.add_argument("--heads", nargs="+", required=True, choices=[h[0] for h in HEADS], help="the heads to take out")
    args = ap.parse_args(argv)
    try:
        had = drop(args.checkpoint, args.out, tuple(args.heads))
    except InputError as e:
        print(f"drop_heads: error: {e}", file=sys.stderr)
        return 2
    print(f"wrote {args.out}: {args.checkpoint.name} without {', '.join(had)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
