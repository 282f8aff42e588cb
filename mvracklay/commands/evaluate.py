"""``mvracklay evaluate``: Table I metrics of a checkpoint on a dataset split."""

from __future__ import annotations

from mvracklay.command_settings import EvaluateSettings

NAME = "evaluate"
HELP = "Table I metrics (top/front x rack/box, mIoU/mAP, averaged and pooled) of a checkpoint"
DESCRIPTION = (
    "Run CKPT over every sequence of a split and print the paper's Table I: per view and class, the "
    "per-(frame, slot) averaged mIoU and 'mAP' (mean pixel precision, as RackLay defines it) and the "
    "pooled figures, over the columns in view and over all cells. --metric reference scores with the "
    "authors' own evaluation instead (MVRackLay eval_vracklay.py: all cells, an empty pair scores 1, "
    "sums over frames x slots, the targets of their windows)."
)
GROUP = "models"
ORDER = 31
SETTINGS = EvaluateSettings


def run(args: EvaluateSettings) -> int:
    from mvracklay.evaluate_job import evaluate

    return evaluate(args)
