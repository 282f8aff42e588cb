"""``mvracklay generate``: write a WareSynth synthetic dataset (resumable)."""

from __future__ import annotations

from mvracklay.command_settings import GenerateSettings

NAME = "generate"
GROUP = "data"
ORDER = 20
#: what `mvracklay` says when the command is interrupted
RESUME = "re-run the same command to resume: complete sequences are kept"
HELP = "generate a synthetic warehouse dataset (WareSynth) with ground-truth layouts"
DESCRIPTION = (
    "Render camera sequences along procedurally generated rack rows: RGB, depth, semantic and "
    "instance images plus top/front layouts per shelf, intrinsics, poses and 3D cuboids. "
    "Re-running the same command resumes an interrupted run (complete sequences are skipped) "
    "and gives byte-identical output. See docs/waresynth.md for the format and the config keys."
)


SETTINGS = GenerateSettings


def run(args: GenerateSettings) -> int:
    from mvracklay.generate_job import generate

    return generate(args)
