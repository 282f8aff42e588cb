"""`mvracklay train --recipe smoke` end to end: killed (as `kill -9` would) after a group of stages, the same
command goes on at the stage it reached, and its RUNS/model.pt runs with `mvracklay run`."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

from mvracklay.cli import main
from mvracklay.training.runner import KILL_AFTER_ENV

ROOT = Path(__file__).resolve().parents[1]
#: the smoke recipe smaller still: fewer training and held-out sequences, fewer steps, fewer frames scored
SMALLER = [
    *("--set", "data.train.sequences=3", "--set", "data.heldout.sequences=1", "--set", "data.tune.sequences=1"),
    *(x for part in ("tune", "heldout") for x in ("--set", f"data.{part}.size=64")),
    *("--set", "vars.steps=30", "--set", "vars.fit_epochs=1"),
    *("--set", "stage.evaluate.max-frames=4"),
]


def test_smoke_recipe_resumes_after_a_kill_and_its_model_runs(tmp_path: Path, capsys) -> None:
    runs = tmp_path / "runs"
    args = ["train", "--recipe", "smoke", "--out", str(runs), "--quiet", *SMALLER]
    env = {**os.environ, "PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": "1", KILL_AFTER_ENV: "5"}
    killed = subprocess.run(
        [sys.executable, "-m", "mvracklay", *args], cwd=ROOT, env=env, capture_output=True, text=True, timeout=300
    )
    assert killed.returncode == -signal.SIGKILL, killed.stderr[-2000:]
    assert "[5/12] fit-uprights (uprights) ..." in killed.stdout and "[6/12]" not in killed.stdout
    state = json.loads((runs / "recipe-state.json").read_text())
    assert set(state["finished"]) == {"generate", "train", "calibrate", "back-edges", "uprights"}
    assert "--resume" in state["finished"]["train"]["argv"]  # a training stage always goes on from its last.pt
    assert not (runs / "model.pt").exists()

    capsys.readouterr()
    assert main(args) == 0
    said = capsys.readouterr().out
    for n, name, sid in [(1, "generate", "generate"), (2, "train", "train"), (5, "fit-uprights", "uprights")]:
        assert f"[{n}/12] {name} ({sid}): finished before, skipped" in said
    assert "[6/12] fit-box-depth (box-depth) ..." in said and "[12/12] evaluate (evaluate) ..." in said
    assert "summary" in said and str(runs / "model.pt") in said
    budget = json.loads((runs / "net" / "budget.json").read_text())
    assert budget["budget"] == 30 and set(budget) >= {"train", "rack-heads", "box-depth", "total"}
    record = json.loads((runs / "model.json").read_text())
    assert all(record["model_config"][h] for h in ("back_edges", "uprights", "box_depth"))
    assert "rack_depth_offset" in record and record["box_logit_offset"]
    assert json.loads((runs / "net" / "table1.json").read_text())
    assert (runs / "distance-reader.pt").is_file()  # the fit-distance stage's reader

    seq = runs / "data" / "heldout" / "seq_00000"
    run = ["run", str(seq), "--checkpoint", str(runs / "model.pt"), "--out", str(tmp_path / "out")]
    assert main([*run, "--no-rrd", "--quiet", "--threads", "1", "--max-frames", "4"]) == 0
    assert (tmp_path / "out" / "warehouse.json").is_file()
