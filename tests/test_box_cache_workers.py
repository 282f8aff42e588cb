"""The box-depth head's streamed pass split over processes (`network.training.box_cache.cache_part`) and
the `fit-box-depth` stage's `--cache-workers N --cache-only`: the same inputs as one pass, kept and reused (by
fits of other settings too: --lr, --weight-decay); a bf16 pass (--precision) keeps a cache of its own; a pass
cut by the clock (--pass-minutes) fits on what it streamed."""

from __future__ import annotations

import json
import runpy
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from layouts.errors import InputError
from mvracklay.training.stages import run_stage
from network.checkpoint import load_checkpoint, load_model
from network.training.box_cache import (
    CACHE_FIELDS,
    FrameChoice,
    StreamedPass,
    cache_inputs,
    cache_part,
    shard_name,
    split_contiguous,
)
from network.training.fit_box_depth import with_box_head
from network.training.kept_box_cache import part_name
from waresynth.dataset import open_dataset
from waresynth.visibility import SeenTracker


@pytest.mark.parametrize("frames", [[12] * 7, [3, 12, 5, 1, 1, 8], [4], [6, 6]])
@pytest.mark.parametrize("count", [1, 2, 3, 5])
def test_split_contiguous_covers_the_sequences_in_order_in_balanced_runs(frames, count):
    seqs = [SimpleNamespace(num_frames=f, k=k) for k, f in enumerate(frames)]
    runs = split_contiguous(seqs, count, FrameChoice())
    assert [s.k for run in runs for s in run] == list(range(len(seqs)))  # all of them, in order, once
    assert all(runs) and len(runs) <= min(count, len(seqs))
    if count <= len(seqs) and len(set(frames)) == 1:
        assert len(runs) == count and max(map(len, runs)) - min(map(len, runs)) <= 1
    capped = split_contiguous(seqs, count, FrameChoice(frames=2))  # balanced by the frames streamed
    if count <= len(seqs):
        assert len(capped) == count


def test_a_pass_split_over_processes_gives_the_inputs_of_one_pass(tiny_checkpoint, tiny_dataset, tmp_path):
    torch.set_num_threads(1)
    model = with_box_head(load_model(tiny_checkpoint)[0], parallax=True)
    seqs = open_dataset(tiny_dataset).sequences()
    choice = FrameChoice(4, 1)
    (tmp_path / "one").mkdir()
    one = cache_inputs(model, seqs, SeenTracker, tmp_path / "one", progress=False, choice=choice)
    for workers in (2, 3):
        job = StreamedPass(model, SeenTracker, choice, progress=False, workers=workers)
        caches, counts, streamed = cache_part(job, seqs, tmp_path / f"w{workers}")
        assert counts is not None and len(counts) == workers and sum(counts) == len(one) and streamed == len(seqs)
        assert sorted(p.name for p in (tmp_path / f"w{workers}").iterdir()) == [shard_name(k) for k in range(workers)]
        for k in CACHE_FIELDS:
            np.testing.assert_array_equal(np.concatenate([np.asarray(getattr(c, k)) for c in caches]), getattr(one, k))
    caches, counts, streamed = cache_part(StreamedPass(model, SeenTracker, choice, False), seqs, tmp_path / "w1")
    assert counts is None and len(caches) == 1 and len(caches[0]) == len(one) and streamed == len(seqs)


def test_a_pass_past_its_deadline_streams_each_process_s_first_sequence_only(tiny_checkpoint, tiny_dataset, tmp_path):
    torch.set_num_threads(1)
    model = with_box_head(load_model(tiny_checkpoint)[0])
    seqs = open_dataset(tiny_dataset).sequences()
    choice = FrameChoice(3)
    (tmp_path / "first").mkdir()
    first = cache_inputs(model, seqs[:1], SeenTracker, tmp_path / "first", progress=False, choice=choice)
    past = time.monotonic()
    job = StreamedPass(model, SeenTracker, choice, progress=False, deadline=past)
    caches, counts, streamed = cache_part(job, seqs, tmp_path / "one")
    assert (counts, streamed) == (None, 1)
    for k in CACHE_FIELDS:  # the first sequence's inputs, nothing after it
        np.testing.assert_array_equal(np.asarray(getattr(caches[0], k)), getattr(first, k))
    caches, counts, streamed = cache_part(replace(job, workers=2), seqs, tmp_path / "two")
    runs = split_contiguous(seqs, 2, choice)
    assert streamed == 2 and len(runs) == 2 and max(map(len, runs)) > 1  # a shard of two stopped after its first
    assert counts is not None and counts[0] == len(first)
    _, _, streamed = cache_part(replace(job, workers=2, deadline=past + 3600), seqs, tmp_path / "late")
    assert streamed == len(seqs)  # a deadline not reached stops nothing


def test_pass_minutes_fits_on_the_sequences_streamed_in_time(tiny_checkpoint, tiny_dataset, tmp_path, capsys):
    base = ["--checkpoint", str(tiny_checkpoint), "--data", str(tiny_dataset), "--frames", "3",
            "--epochs", "1", "--threads", "1", "--cache-workers", "2", "--quiet"]  # fmt: skip
    assert run_stage("fit-box-depth", [*base, "--pass-minutes", "1e-9", "--out", str(tmp_path / "cut.pt")]) == 0
    assert "sequences (of 3: the pass stopped at --pass-minutes 1e-09)" in capsys.readouterr().out
    cut = load_checkpoint(tmp_path / "cut.pt")[1]["box_depth"]
    assert (cut["train_sequences"], cut["sequences_given"], cut["pass_minutes"]) == (2, 3, 1e-9)
    assert run_stage("fit-box-depth", [*base, "--pass-minutes", "60", "--out", str(tmp_path / "all.pt")]) == 0
    assert "the pass stopped" not in capsys.readouterr().out
    whole = load_checkpoint(tmp_path / "all.pt")[1]["box_depth"]
    assert (whole["train_sequences"], whole["sequences_given"]) == (3, 3)
    # how many slots the third sequence adds depends on which frames were streamed, not on the clock
    assert whole["train_slots"] >= cut["train_slots"] > 0


def test_a_failing_process_stops_the_pass_with_one_line(tiny_checkpoint, tiny_dataset, tmp_path):
    model = with_box_head(load_model(tiny_checkpoint)[0])
    seqs = open_dataset(tiny_dataset).sequences()

    def labels(seq):
        if seq is seqs[-1]:
            raise ValueError("no instance file for this one")
        return SeenTracker(seq)

    with pytest.raises(InputError) as err:
        cache_part(StreamedPass(model, labels, progress=False, workers=2), seqs, tmp_path)
    msg = str(err.value)
    assert "\n" not in msg and shard_name(1) in msg and "no instance file for this one" in msg


def test_cache_only_keeps_the_inputs_and_a_later_fit_reuses_them(tiny_checkpoint, tiny_dataset, tmp_path, capsys):
    keep = tmp_path / "cache"
    base = ["--checkpoint", str(tiny_checkpoint), "--data", str(tiny_dataset), "--parallax",
            "--frames", "4", "--from-frame", "1", "--epochs", "1", "--threads", "1", "--quiet"]  # fmt: skip
    made = ["--cache-only", "--cache-workers", "2", "--keep-cache", str(keep), "--out", str(tmp_path / "no.pt")]
    assert run_stage("fit-box-depth", [*base, *made, "--json-out", str(tmp_path / "cache.json")]) == 0
    out = capsys.readouterr().out
    assert out.startswith("made the inputs of ") and not (tmp_path / "no.pt").exists()  # no head, no checkpoint
    summary = json.loads((tmp_path / "cache.json").read_text())
    assert summary["cache_workers"] == 2 and summary["train_sequences"] == 3 and summary["train_slots"] > 0
    record = json.loads((keep / part_name(tiny_dataset) / "cache.json").read_text())
    assert len(record["shards"]) == 2 and sum(record["shards"]) == record["slots"] == summary["train_slots"]
    assert run_stage("fit-box-depth", [*base, *made]) == 0 and capsys.readouterr().out.startswith(
        "found the inputs of "
    )
    assert run_stage("fit-box-depth", [*base, "--keep-cache", str(keep), "--out", str(tmp_path / "kept.pt")]) == 0
    assert f"reused the inputs cached in {keep} for 1 of 1 data folders" in capsys.readouterr().out
    assert (
        run_stage("fit-box-depth", [*base, "--out", str(tmp_path / "plain.pt")]) == 0
    )  # one pass in one process, a temporary cache
    kept, plain = (load_checkpoint(tmp_path / f"{k}.pt") for k in ("kept", "plain"))
    heads = [k for k in plain[0]["model"] if k.startswith("box_depth.")]
    assert heads and all(torch.equal(kept[0]["model"][k], plain[0]["model"][k]) for k in heads)
    assert kept[1]["box_depth"]["train_slots"] == plain[1]["box_depth"]["train_slots"] == summary["train_slots"]
    assert (kept[1]["box_depth"]["lr"], kept[1]["box_depth"]["weight_decay"]) == (2e-3, 1e-2)  # the defaults
    fit = ["--keep-cache", str(keep), "--lr", "1e-2", "--weight-decay", "0", "--out", str(tmp_path / "tuned.pt")]
    assert (
        run_stage("fit-box-depth", [*base, *fit]) == 0 and "reused the inputs" in capsys.readouterr().out
    )  # other settings, no pass
    tuned = load_checkpoint(tmp_path / "tuned.pt")
    assert (tuned[1]["box_depth"]["lr"], tuned[1]["box_depth"]["weight_decay"]) == (1e-2, 0.0)
    assert not all(torch.equal(tuned[0]["model"][k], plain[0]["model"][k]) for k in heads)
    lost = shard_name(int(np.argmax(record["shards"])))  # a shard with slots loses a file: one line, no traceback
    (keep / part_name(tiny_dataset) / lost / "win.npy").unlink()
    assert run_stage("fit-box-depth", [*base, "--keep-cache", str(keep), "--out", str(tmp_path / "x.pt")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and lost in err and "remove the folder" in err


def test_a_bf16_pass_and_fit_keep_a_cache_of_their_own(tiny_checkpoint, tiny_dataset, tmp_path, capsys):
    base = ["--checkpoint", str(tiny_checkpoint), "--data", str(tiny_dataset), "--parallax",
            "--frames", "4", "--from-frame", "1", "--epochs", "2", "--threads", "1", "--quiet"]  # fmt: skip
    fp32, bf16 = tmp_path / "fp32", tmp_path / "bf16"
    assert run_stage("fit-box-depth", [*base, "--keep-cache", str(fp32), "--out", str(tmp_path / "a.pt")]) == 0
    capsys.readouterr()
    assert (
        run_stage(
            "fit-box-depth", [*base, "--keep-cache", str(fp32), "--precision", "bf16", "--out", str(tmp_path / "x.pt")]
        )
        == 2
    )
    # the float32 pass's inputs are not the bf16 pass's: refused, one error line (a CPU without native bf16
    # also prints a warning line before it)
    errors = [x for x in capsys.readouterr().err.splitlines() if ": error: " in x]
    assert len(errors) == 1 and "trunk precision" in errors[0] and not (tmp_path / "x.pt").exists()
    assert (
        run_stage(
            "fit-box-depth", [*base, "--keep-cache", str(bf16), "--precision", "bf16", "--out", str(tmp_path / "b.pt")]
        )
        == 0
    )
    a, b = (load_checkpoint(tmp_path / f"{k}.pt") for k in "ab")
    assert (a[1]["box_depth"]["precision"], a[1]["box_depth"]["fit_precision"]) == ("fp32", "fp32")
    assert (b[1]["box_depth"]["precision"], b[1]["box_depth"]["fit_precision"]) == ("bf16", "bf16")
    assert b[1]["box_depth"]["train_slots"] > 0 and np.isfinite(b[1]["box_depth"]["losses"]).all()
    keys = [json.loads((d / part_name(tiny_dataset) / "cache.json").read_text())["key"] for d in (fp32, bf16)]
    assert "precision" not in keys[0] and keys[1]["precision"] == "bf16"  # float32 caches keep their keys
    assert {k: v for k, v in keys[1].items() if k != "precision"} == keys[0]  # the same trunk and sequences


@pytest.mark.parametrize(
    ("extra", "needle"),
    [
        (["--cache-only"], "--cache-only needs --keep-cache"),
        (["--cache-workers", "0"], "--cache-workers must be"),
        (["--pass-minutes", "0"], "--pass-minutes must be a positive number"),
        (["--pass-minutes", "nan"], "--pass-minutes must be a positive number"),
        (["--pass-minutes", "5", "--keep-cache", "/tmp/k"], "--pass-minutes cannot be used with --keep-cache"),
        (["--lr", "0"], "--lr must be a positive number"),
        (["--weight-decay", "-0.1"], "--weight-decay must be a number >= 0"),
        (["--weight-decay", "nan"], "--weight-decay must be a number >= 0"),
    ],
)
def test_cache_options_are_checked_on_one_line(tiny_checkpoint, tiny_dataset, tmp_path, capsys, extra, needle):
    args = ["--checkpoint", str(tiny_checkpoint), "--data", str(tiny_dataset), "--quiet", *extra]
    assert run_stage("fit-box-depth", args) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and needle in err


def test_bench_box_cache_times_a_pass_split_over_processes(tiny_checkpoint, tiny_dataset, tmp_path, capsys):
    script = Path(__file__).resolve().parents[1] / "benchmarks" / "bench_box_cache.py"
    args = [sys.executable, str(script), str(tiny_checkpoint), str(tiny_dataset), "--sequences", "2", "--frames", "3",
            "--repeats", "1"]  # fmt: skip
    got = {}
    for workers in (1, 2):  # a bf16 trunk: the shards' processes inherit it (its boxes, so its slots, differ)
        out = tmp_path / f"w{workers}.json"
        flags = ["--workers", str(workers), "--precision", "bf16", "--json", str(out)]
        done = subprocess.run([*args, *flags], capture_output=True, text=True)
        assert done.returncode == 0, done.stderr
        got[workers] = json.loads(out.read_text())
        assert got[workers]["precision"] == "bf16" and "the trunk in bf16" in done.stdout
    assert "2 processes of 1 thread" in done.stdout and got[2]["workers"] == 2
    assert got[2]["slots"] == got[1]["slots"] > 0 and got[2]["frames"] == got[1]["frames"] == 6
    capsys.readouterr()
    bench = runpy.run_path(str(script))  # its main in this process: a refusal needs no interpreter of its own
    assert bench["main"]([*args[2:], "--workers", "0"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--workers" in err[0]
