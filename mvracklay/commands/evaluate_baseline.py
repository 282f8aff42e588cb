"""``mvracklay evaluate-baseline``: Table I of the depth-projection baseline on a generated dataset."""

from __future__ import annotations

from mvracklay.command_settings import EvaluateBaselineSettings

NAME = "evaluate-baseline"
HELP = "Table I of the depth-projection baseline (ground-truth depth + masks, visible surfaces only)"
DESCRIPTION = (
    "Back-project each frame's ground-truth depth with its ground-truth semantic masks into shelf-centric "
    "layouts (no learning, no amodal reasoning: see mvracklay/baselines/depth_projection.py) and score them "
    "like 'mvracklay evaluate' does a checkpoint: what seeing alone gives."
)
GROUP = "models"
ORDER = 32
SETTINGS = EvaluateBaselineSettings


def run(args: EvaluateBaselineSettings) -> int:
    from mvracklay.evaluate_job import evaluate_baseline

    return evaluate_baseline(args)
