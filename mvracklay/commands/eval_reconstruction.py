"""``mvracklay eval-reconstruction``: stitch sequences and score the maps against ground-truth cuboids."""

from __future__ import annotations

from mvracklay.command_settings import EvalReconstructionSettings

NAME = "eval-reconstruction"
HELP = "reconstruct sequences and score them against the generator's ground-truth cuboids"
DESCRIPTION = (
    "For each WareSynth sequence: stitch its layouts (ground truth, a layout folder, or ground truth "
    "degraded like network output) and compare the map with scene.json: box precision/recall at 3D "
    "IoU >= --iou (unit: a ground-truth stack), mean 3D IoU, per-shelf box-count accuracy, free-length "
    "error and end-of-sequence drift of the estimated camera shifts. The map is placed in the world "
    "using only the first frame's record. PATH is a dataset folder (manifest.json) or one sequence. "
    "--checkpoint scores the network instead: each sequence's layouts are predicted (streaming by default), "
    "then stitched and scored the same way (add --noisy for the clean-up settings meant for network output)."
)
GROUP = "models"
ORDER = 33
SETTINGS = EvalReconstructionSettings


def run(args: EvalReconstructionSettings) -> int:
    from mvracklay.reconstruction_eval import eval_reconstruction

    return eval_reconstruction(args)
