"""The stages that run a job of the command line on its settings: ``generate``, ``evaluate``, ``evaluate-baseline``
and ``eval-reconstruction`` call the library's jobs (`mvracklay.generate_job`, `mvracklay.evaluate_job`,
`mvracklay.reconstruction_eval`) as their commands do, with the options those commands take."""

from __future__ import annotations

from mvracklay.command_settings import (
    EvalReconstructionSettings,
    EvaluateBaselineSettings,
    EvaluateSettings,
    GenerateSettings,
)
from mvracklay.evaluate_job import evaluate, evaluate_baseline
from mvracklay.generate_job import generate
from mvracklay.reconstruction_eval import eval_reconstruction
from mvracklay.training.stages import Stage

GENERATE = Stage("generate", "generate a WareSynth dataset (as mvracklay generate)", GenerateSettings, generate)
EVALUATE = Stage("evaluate", "Table I of a checkpoint (as mvracklay evaluate)", EvaluateSettings, evaluate)
EVALUATE_BASELINE = Stage(
    "evaluate-baseline",
    "Table I of the depth-projection baseline (as mvracklay evaluate-baseline)",
    EvaluateBaselineSettings,
    evaluate_baseline,
)
EVAL_RECONSTRUCTION = Stage(
    "eval-reconstruction",
    "stitch sequences and score the maps against ground truth (as mvracklay eval-reconstruction)",
    EvalReconstructionSettings,
    eval_reconstruction,
)
