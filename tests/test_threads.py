"""CPU thread settings: OpenMP's wait policy is set before torch loads (unless the user set one), ``--threads
auto`` picks the free cores, and `benchmarks/bench_infer.py --compete` measures beside busy processes."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from layouts.errors import InputError
from mvracklay import threads

ROOT = Path(__file__).resolve().parents[1]
BENCH = ROOT / "benchmarks" / "bench_infer.py"

#: a command run through the CLI (free-space's ``run`` replaced): what it sees of the environment and torch
_SEEN = (
    "import json, os, sys\n"
    "from mvracklay.cli import main\n"
    "import mvracklay.commands.free_space as command\n"
    "command.run = lambda args: print(json.dumps([os.environ.get('OMP_WAIT_POLICY'), 'torch' in sys.modules]))\n"
    "main(['free-space', 'map.json', '--box', '1x1x1'])\n"
)


def _env(**set_: str) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if k not in threads.OPENMP_ENV}
    return {**env, **set_}


@pytest.mark.parametrize("given, seen", [(None, "PASSIVE"), ("ACTIVE", "ACTIVE")])
def test_a_command_runs_with_openmp_threads_sleeping_unless_the_user_said_otherwise(given, seen):
    env = _env(**({"OMP_WAIT_POLICY": given} if given else {}))
    done = subprocess.run([sys.executable, "-c", _SEEN], cwd=ROOT, env=env, capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    assert json.loads(done.stdout.strip().splitlines()[-1]) == [seen, False]  # set, and torch not loaded yet


def test_python_m_mvracklay_and_the_package_set_it_before_torch_loads():
    code = "import os, sys, mvracklay; print(os.environ.get('OMP_WAIT_POLICY'), 'torch' in sys.modules)"
    done = subprocess.run([sys.executable, "-c", code], cwd=ROOT, env=_env(), capture_output=True, text=True)
    assert done.stdout.split() == ["PASSIVE", "False"], done.stderr
    assert "quiet_openmp()" in (ROOT / "mvracklay" / "__main__.py").read_text()


def test_quiet_openmp_keeps_what_is_set_and_says_whether_it_is_in_time():
    env = {"KMP_BLOCKTIME": "200"}
    in_time = threads.quiet_openmp(env)
    assert env == {"KMP_BLOCKTIME": "200", "OMP_WAIT_POLICY": "PASSIVE"}
    assert in_time is ("torch" not in sys.modules)


@pytest.mark.parametrize(
    "cores, busy, want",
    [(2, 0.0, 2), (2, 0.3, 2), (2, 1.0, 1), (2, 1.6, 2), (2, 2.0, 2), (2, None, 2), (16, 3.2, 8), (16, 10.0, 6)],
)
def test_auto_threads_takes_the_free_cores_or_all_when_none_is_free(cores, busy, want):
    assert threads.auto_threads(cores, busy) == want


def test_busy_cores_reads_the_cpus_of_this_process_from_proc_stat(tmp_path):
    stat = tmp_path / "stat"
    stat.write_text("cpu  9 0 9 9 0 0 0 0\ncpu0 100 0 0 900 0 0 0 0 0 0\ncpu1 10 0 0 990 0 0 0 0 0 0\n")
    assert threads.busy_cores([0, 1], 0.0, stat) is None  # no ticks between the samples: unknown
    assert threads.busy_cores([0, 5], 0.0, stat) is None  # a CPU the file lacks
    assert threads.busy_cores([0], 0.0, tmp_path / "missing") is None
    real = threads.busy_cores(threads.usable_cores(), 0.05)
    assert real is None or 0.0 <= real <= len(threads.usable_cores())


def test_threads_values():
    assert threads.parse_threads("auto") == "auto" and threads.parse_threads("3") == 3
    assert threads.resolve_threads("4") == 4
    assert 1 <= threads.resolve_threads("auto") <= min(threads.AUTO_MAX, len(threads.usable_cores()))
    for bad, says in (("0", "--threads must be >= 1, got 0"), ("two", "--threads must be a count >= 1 or 'auto'")):
        with pytest.raises(InputError, match=says):
            threads.parse_threads(bad)


def test_bench_infer_measures_beside_busy_processes_and_stops_them(tmp_path):
    out = tmp_path / "fps.json"
    argv = [sys.executable, str(BENCH), "--sizes", "64", "--frames", "2", "--repeats", "1", "--modes", "stream"]
    done = subprocess.run(
        [*argv, "--threads", "1", "--compete", "1", "--json", str(out)],
        env=_env(),
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 0, done.stderr
    (row,) = json.loads(out.read_text())
    assert row["compete"] == 1 and row["fps_compete_best"] > 0 and row["ratio_best"] > 0
    assert row["omp_wait_policy"] == "PASSIVE" and "beside 1 busy" in done.stdout
    assert len(row["compete_pids"]) == 1
    for pid in row["compete_pids"]:  # the busy processes are gone
        cmdline = Path(f"/proc/{pid}/cmdline")
        assert not cmdline.exists() or b"while True" not in cmdline.read_bytes()
