"""`kill -9` during `mvracklay train`, then the same command with --resume, continues exactly."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import torch
from tiny_net import tiny_config

from layouts import InputError
from mvracklay.cli import main
from network.checkpoint import load_checkpoint
from network.model.config import ModelConfig
from network.training.train_config import TrainConfig
from network.training.train_data import open_data
from network.training.trainer import Trainer

ROOT = Path(__file__).resolve().parents[1]
NAMES = ["best.json", "best.pt", "last.json", "last.pt", "metrics.jsonl"]


def train_args(data: Path, out: Path) -> list[str]:
    return [
        "train", "--data", str(data), "--out", str(out), "--epochs", "2", "--steps-per-epoch", "4",
        "--checkpoint-every", "2", "--frames-per-step", "4", "--input-size", "64", "64", "--layout-size", "16",
        "--encoder-width", "8", "--hidden", "16", "--decoder-width", "8", "--threads", "1", "--device", "cpu",
        "--seed", "4", "--val-frames", "2", "--quiet",
    ]  # fmt: skip


def kill_after_first_checkpoint(args: list[str], run: Path) -> int:
    """Start training in a subprocess, SIGKILL it once last.pt loads; returns how many loads succeeded."""
    env = {**os.environ, "PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": "1"}
    proc = subprocess.Popen(
        [sys.executable, "-m", "mvracklay", *args], cwd=ROOT, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE
    )
    loads = 0
    try:
        deadline = time.monotonic() + 120
        while proc.poll() is None and time.monotonic() < deadline:
            if (run / "last.pt").exists():
                load_checkpoint(run / "last.pt")  # whatever sits under the final name is whole
                loads += 1
                os.kill(proc.pid, signal.SIGKILL)
                break
            time.sleep(0.02)
        proc.wait(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == -signal.SIGKILL, (
        f"training ended on its own before the kill: {proc.stderr.read()[-2000:]}"
    )
    return loads


def test_kill_9_then_resume_continues_from_the_last_checkpoint(tiny_dataset, tmp_path, capsys):
    ref, run = tmp_path / "ref", tmp_path / "run"
    assert main(train_args(tiny_dataset, ref)) == 0  # the uninterrupted run
    assert kill_after_first_checkpoint(train_args(tiny_dataset, run), run) == 1

    # Every checkpoint on disk is whole; the run stopped part-way.
    for p in run.glob("*.pt"):
        load_checkpoint(p)
    payload, record = load_checkpoint(run / "last.pt")
    k = int(payload["step"])
    assert 2 <= k < 8 and k % 2 == 0 and record["step"] == k

    # The same command without --resume refuses to overwrite the run.
    assert main(train_args(tiny_dataset, run)) == 2
    assert "pass --resume" in capsys.readouterr().err

    # A resuming trainer holds the checkpoint's step count, epoch position and optimiser states.
    ds = open_data(tiny_dataset)
    tcfg = TrainConfig(**{**record["train_config"], "class_weights": tuple(record["train_config"]["class_weights"])})
    mcfg = ModelConfig.from_dict(record["model_config"])
    t = Trainer(mcfg, tcfg, ds.sequences("train"), [], run, resume=True, progress=False)
    assert (t.step, t.epoch * 4 + t.epoch_step) == (k, k)
    for opt, key in ((t.opt, "optimizer"), (t.opt_d, "optimizer_d")):
        saved = payload[key]["state"]
        assert saved and set(opt.state_dict()["state"]) == set(saved)
        for i, st in opt.state_dict()["state"].items():
            for name, v in st.items():
                assert torch.equal(v, saved[i][name]), (key, i, name)

    # The same command with --resume finishes the run: same step count and the very same weights
    # and optimiser states as the uninterrupted run (same windows, same learning rates).
    assert main([*train_args(tiny_dataset, run), "--resume"]) == 0
    assert f"resuming at step {k}" in capsys.readouterr().out
    assert sorted(p.name for p in run.iterdir()) == NAMES  # no temporary left behind
    got, rec = load_checkpoint(run / "last.pt")
    want, _ = load_checkpoint(ref / "last.pt")
    assert rec["step"] == 8 and got["epoch"] == 2 and got["epoch_step"] == 0
    for part in ("model", "discriminators"):
        for name, v in want[part].items():
            assert torch.equal(got[part][name], v), (part, name)
    for key in ("optimizer", "optimizer_d"):
        for i, st in want[key]["state"].items():
            for name, v in st.items():
                assert torch.equal(got[key]["state"][i][name], v), (key, i, name)
    steps = [json.loads(line)["step"] for line in (run / "metrics.jsonl").read_text().splitlines()]
    assert steps == [4, 8]
    want_loss = [json.loads(line)["loss"] for line in (ref / "metrics.jsonl").read_text().splitlines()]
    got_loss = [json.loads(line)["loss"] for line in (run / "metrics.jsonl").read_text().splitlines()]
    assert got_loss == want_loss  # the epoch's loss sums were carried across the crash too


def test_stale_temporaries_are_removed_and_bad_flags_refused(tmp_path):
    from layouts import LayoutSpec
    from network.training.toy import ToySequence

    spec = LayoutSpec(num_slots=2, size=16)
    cfg = tiny_config(spec, "mvracklay-4")
    data = [ToySequence(spec, num_frames=5, step_cols=2, seed=0, name="toy0")]
    tcfg = TrainConfig(frames_per_step=4, steps_per_epoch=3, epochs=1, checkpoint_every=1, seed=1, threads=1)
    run = tmp_path / "run"
    Trainer(cfg, tcfg, data, [], run, progress=False).fit()
    stale = run / ".last.pt.abc123.tmp"
    stale.write_bytes(b"half a checkpoint")
    other = run / ".notes.txt.tmp"
    other.write_bytes(b"not ours")
    t = Trainer(cfg, TrainConfig(**{**tcfg.__dict__, "epochs": 2}), data, [], run, resume=True, progress=False)
    assert not stale.exists() and other.exists() and t.step == 3
    for bad in ({"checkpoint_every": -1}, {"device": "tpu"}):
        try:
            TrainConfig(**bad).validate()
        except InputError as e:
            assert next(iter(bad)).replace("_", "-") in str(e)
        else:
            raise AssertionError(f"{bad} accepted")
