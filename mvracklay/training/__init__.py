"""Training one's own model: the recipes of ``mvracklay train --recipe`` and the stages they run.

`recipe` reads and checks a recipe file, `plan` turns its stages into argument lists, `runner` runs them
(resumably, with one progress display), `stages` names every stage and runs one (`stages.run_stage`);
the stage modules themselves (`train_network`, `calibrate`, `fit_back_edges`, `fit_uprights`,
`fit_box_depth`, `graft`, `small_stages`, `budget`) hold each stage's options and work.
"""
