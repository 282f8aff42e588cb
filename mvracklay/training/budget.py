"""A recipe's time budget: the minutes spent so far, what the box-depth head's streamed pass may take of
the rest, and the ``budget`` stage that adds them up (refused over the total).

The minutes counted are a training stage's step minutes (its run's ``last.json``, ``train_wall_minutes``),
the step minutes recorded with the ``prior`` checkpoints (a warm start trained before), and the whole
wall minutes of the other stages and groups ``count`` names, model loading and caching included. The
box-depth head's ``--pass-minutes`` is the rest less the margin, shared between the pass and the fit
after it: ``(total - spent - margin) / (1 + fit_ratio)``, the fit taking ``fit_ratio`` minutes per
minute of pass (measured per precision), so a faster machine fits the head on more scenes.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from layouts.errors import InputError
from layouts.fileio import atomic_write_json
from mvracklay.settings import setting

NAME = "budget"
HELP = "add up the minutes the recipe's budget counts, write them, and refuse a run over the total"


@dataclass(frozen=True)
class BudgetSettings:
    """The options of stage ``budget``."""

    out: Path | None = setting("--out", "write the minutes per counted stage and their total as JSON here", type=Path)


SETTINGS = BudgetSettings


def run(args: BudgetSettings) -> int:
    raise InputError("the budget stage adds up a recipe's minutes: it runs inside `mvracklay train --recipe` only")


def _train_minutes(record: Path) -> float:
    if not record.is_file():
        raise InputError(f"{record}: missing (the budget counts its train_wall_minutes)")
    try:
        return float(json.loads(record.read_text())["train_wall_minutes"])
    except (ValueError, KeyError, TypeError) as e:
        raise InputError(f"{record}: no train_wall_minutes ({e})") from None


def spent(budget: dict[str, Any], resolve: Any, train_runs: dict[str, str], wall: dict[str, float]) -> dict[str, float]:
    """Minutes per counted item and their ``total``: ``train_runs`` maps a training stage's id to its run
    folder, ``wall`` a stage's or group's id to its recorded wall minutes (0 while not run)."""
    parts: dict[str, float] = {}
    for path in budget.get("prior", []):
        ckpt = Path(resolve(path))
        parts[f"prior:{ckpt.name}"] = _train_minutes(ckpt.with_suffix(".json"))
    for name in budget.get("count", []):
        if name in train_runs:
            last = Path(train_runs[name]) / "last.json"
            parts[name] = _train_minutes(last) if last.is_file() else 0.0
        else:
            parts[name] = wall.get(name, 0.0)
    parts["total"] = sum(parts.values())
    return parts


def pass_minutes(budget: dict[str, Any], ratio: float, spent_total: float) -> float:
    """The box-depth head's ``--pass-minutes``: the minutes left less the margin, shared with the fit."""
    total, margin = float(budget["total"]), float(budget.get("margin", 0.0))
    left = total - spent_total - margin
    if left <= 0:
        raise InputError(f"{spent_total:.1f} of {total:g} minutes spent, none left for the box-depth head")
    return left / (1 + ratio)


def write_record(budget: dict[str, Any], parts: dict[str, float], out: Path | None) -> str:
    """Write the budget's record (when ``out``); refuse a total over the budget. Returns the summary line."""
    total = float(budget["total"])
    if out is not None:
        out.parent.mkdir(parents=True, exist_ok=True)
        atomic_write_json(out, {**{k: round(v, 3) for k, v in parts.items()}, "budget": total})
    if parts["total"] > total:
        raise InputError(f"{parts['total']:.1f} minutes spent, over the budget of {total:g}")
    return f"{parts['total']:.1f} of {total:g} minutes spent: " + ", ".join(
        f"{k} {v:.1f}" for k, v in parts.items() if k != "total"
    )
