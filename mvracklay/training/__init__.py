"""Training one's own model: the recipes of ``mvracklay train --recipe`` and the stages they run.

`recipe` reads and checks a recipe file, `plan` turns its stages into argument lists, `runner` runs them
(resumably, with one progress display), `stages` names every stage and runs one (`stages.run_stage`);
the stage modules themselves (`train_network`, `calibrate`, `fit_back_edges`, `fit_uprights`,
`fit_box_depth`, `graft`, `small_stages`, `budget`) hold each stage's options and work.
"""

#: what a plain training run does: the ``train`` stage's description, which ``mvracklay train`` extends (--recipe)
TRAIN_DESCRIPTION = (
    "Train a variant on the 'train' split of DATA, validating with the Table I metrics on the 'val' split "
    "after every epoch. RUN receives last.pt / best.pt (+ .json records) and metrics.jsonl; --resume "
    "continues an interrupted run (also after kill -9: --checkpoint-every N bounds the lost steps). "
    "Under torchrun (torchrun --nproc_per_node=N -m mvracklay train ...) it trains with "
    "DistributedDataParallel: gloo on CPU, NCCL on GPUs, each rank on its own share of the windows, "
    "rank 0 writing checkpoints and metrics; see docs/distributed.md. "
    "--export CKPT writes a fp16 weights-only copy of a checkpoint to --out."
)
