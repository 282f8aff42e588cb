"""`torchrun -m mvracklay train` with 2 gloo processes on localhost: DDP training, rank-0 writes, resume."""

from __future__ import annotations

import json
import math
import os
import socket
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from layouts import InputError
from network.checkpoint import load_checkpoint, load_model
from network.device import DistEnv, device_for, single_process_device
from network.model.config import ModelConfig
from network.model.discriminator import build_discriminators
from network.training.distributed import rank_indices
from network.training.run_records import weights_fingerprint

ROOT = Path(__file__).resolve().parents[1]
TORCHRUN = Path(sys.executable).with_name("torchrun")
TINY = [
    "--input-size", "64", "64", "--layout-size", "16", "--encoder-width", "8", "--hidden", "16",
    "--decoder-width", "8", "--threads", "1", "--frames-per-step", "4", "--steps-per-epoch", "3",
    "--checkpoint-every", "2", "--device", "cpu", "--quiet",
]  # fmt: skip


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


#: launch failures from a port taken between choosing it and binding it: retried once on a new port
PORT_CLASH = ("address already in use", "eaddrinuse", "failed to listen", "distnetworkerror")


def torchrun_train(data: Path, out: Path, *extra: str) -> subprocess.CompletedProcess:
    res = _torchrun_train(data, out, *extra)
    if res.returncode != 0 and any(m in res.stderr.lower() for m in PORT_CLASH):
        res = _torchrun_train(data, out, *extra)
    return res


def _torchrun_train(data: Path, out: Path, *extra: str) -> subprocess.CompletedProcess:
    cmd = [
        str(TORCHRUN), "--nproc_per_node=2", "--nnodes=1", "--master_addr=127.0.0.1",
        f"--master_port={free_port()}", "-m", "mvracklay", "train", "--data", str(data), "--out", str(out),
        *TINY, *extra,
    ]  # fmt: skip
    env = {**os.environ, "PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": "1"}
    return subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True, timeout=240)


def saved_fingerprint(path: Path) -> str:
    """The fingerprint of the weights a checkpoint holds, computed here from the file."""
    model, record = load_model(path)
    payload, _ = load_checkpoint(path)
    discs = build_discriminators(ModelConfig.from_dict(record["model_config"]))
    if discs is not None:
        discs.load_state_dict(payload["discriminators"])
    return weights_fingerprint(model, discs)


@pytest.mark.skipif(not TORCHRUN.exists(), reason="torchrun is not installed beside the interpreter")
def test_two_gloo_ranks_train_in_sync_write_once_and_resume(tiny_dataset, tmp_path):
    out = tmp_path / "run"
    res = torchrun_train(tiny_dataset, out, "--epochs", "1")
    assert res.returncode == 0, res.stderr[-3000:]
    # Only rank 0 speaks and writes: one start line, one end line, one set of files, no temporaries.
    assert res.stdout.count("training mvracklay-disc-4") == 1 and "2 processes (gloo)" in res.stdout
    assert res.stdout.count("done: step 3") == 1
    assert sorted(p.name for p in out.iterdir()) == ["best.json", "best.pt", "last.json", "last.pt", "metrics.jsonl"]
    rec = json.loads((out / "last.json").read_text())
    assert rec["world_size"] == 2 and rec["step"] == 3
    # Both ranks' weights (gathered at the last save) equal each other and the saved weights.
    fps = rec["replica_fingerprints"]
    assert len(fps) == 2 and fps[0] == fps[1] == saved_fingerprint(out / "last.pt")
    hist = [json.loads(line) for line in (out / "metrics.jsonl").read_text().splitlines()]
    assert [e["step"] for e in hist] == [3] and all(e["world_size"] == 2 for e in hist)
    assert all(math.isfinite(v) for e in hist for v in e["loss"].values())
    assert "adv" in hist[-1]["loss"] and "disc" in hist[-1]["loss"]

    # Resume under DDP: the step count, optimiser state and discriminators continue from last.pt.
    before, _ = load_checkpoint(out / "last.pt")
    res = torchrun_train(tiny_dataset, out, "--epochs", "2", "--resume")
    assert res.returncode == 0, res.stderr[-3000:]
    assert "resuming at step 3" in res.stdout and res.stdout.count("done: step 6") == 1
    after, rec = load_checkpoint(out / "last.pt")
    assert rec["step"] == 6 and len(set(rec["replica_fingerprints"])) == 1
    assert rec["replica_fingerprints"][0] == saved_fingerprint(out / "last.pt")
    # Adam's step counters went on from the saved ones (3 -> 6), they did not restart.
    steps = {float(s["step"]) for s in after["optimizer"]["state"].values()}
    assert steps == {6.0} and {float(s["step"]) for s in before["optimizer"]["state"].values()} == {3.0}
    assert {float(s["step"]) for s in after["optimizer_d"]["state"].values()} == {6.0}
    assert [e["step"] for e in map(json.loads, (out / "metrics.jsonl").read_text().splitlines())] == [3, 6]


def test_ranks_draw_disjoint_windows_from_one_seeded_stream():
    n, per_rank, world = 40, 10, 4
    shares = [rank_indices(n, per_rank, rank=r, world_size=world, generator=torch.Generator().manual_seed(5)) for r in range(world)]  # fmt: skip
    assert all(len(s) == per_rank for s in shares)
    flat = [i for s in shares for i in s]
    assert len(set(flat)) == n  # one permutation split four ways: disjoint, covering everything
    # One process gets exactly RandomSampler's order (without replacement) for the same generator.
    single = rank_indices(n, 25, rank=0, world_size=1, generator=torch.Generator().manual_seed(5))
    sampler = torch.utils.data.RandomSampler(range(n), num_samples=25, generator=torch.Generator().manual_seed(5))
    assert single == list(sampler)
    # Longer than the data: whole permutations back to back.
    long = rank_indices(3, 7, rank=0, world_size=1, generator=torch.Generator().manual_seed(1))
    assert sorted(long[:3]) == sorted(long[3:6]) == [0, 1, 2]


def test_torchrun_environment_is_detected_and_checked():
    assert DistEnv.from_env({}) == DistEnv()
    env = DistEnv.from_env(
        {"RANK": "1", "WORLD_SIZE": "2", "LOCAL_RANK": "1", "MASTER_ADDR": "127.0.0.1", "MASTER_PORT": "1"}
    )
    assert env.enabled and env.rank == 1 and not env.is_main
    with pytest.raises(InputError, match="RANK=2, WORLD_SIZE=2"):
        DistEnv.from_env({"RANK": "2", "WORLD_SIZE": "2", "MASTER_ADDR": "h", "MASTER_PORT": "1"})
    with pytest.raises(InputError, match="MASTER_ADDR is not set"):
        DistEnv.from_env({"RANK": "0", "WORLD_SIZE": "2", "MASTER_PORT": "1"})
    with pytest.raises(InputError, match="WORLD_SIZE='x'"):
        DistEnv.from_env({"RANK": "0", "WORLD_SIZE": "x"})


def test_one_process_commands_refuse_torchrun_and_missing_gpus(monkeypatch):
    for k, v in {"RANK": "0", "WORLD_SIZE": "2", "MASTER_ADDR": "127.0.0.1", "MASTER_PORT": "1"}.items():
        monkeypatch.setenv(k, v)
    with pytest.raises(InputError, match="evaluate runs in one process"):
        single_process_device("evaluate")
    monkeypatch.setenv("WORLD_SIZE", "1")
    assert single_process_device("evaluate", "cpu") == torch.device("cpu")
    if not torch.cuda.is_available():
        with pytest.raises(InputError, match="no CUDA device"):
            device_for(DistEnv(), "cuda")
        assert device_for(DistEnv(), "auto") == torch.device("cpu")
