"""CPU thread settings for torch: OpenMP's wait policy and the ``--threads`` count.

torch's CPU kernels run on OpenMP (libgomp), whose idle threads spin on a core between parallel regions
by default. When other processes keep the cores busy, the spinning threads and the busy ones take turns
and every frame waits for a descheduled thread: `mvracklay run` on the demo sequence took 23.2 s on 2
threads beside one busy process against 11.3 s idle (docs/results.md, speed). With
``OMP_WAIT_POLICY=PASSIVE`` idle threads sleep instead, at no cost to the idle speed.

libgomp reads the variable once, when torch loads it: `quiet_openmp` must run before the first
``import torch``. The command line does it first thing (`mvracklay.cli.main`, ``python -m mvracklay``);
importing `mvracklay` does it too where torch is not loaded yet. A program that imports torch before
any of these sets ``OMP_WAIT_POLICY=PASSIVE`` itself (in the shell, or in ``os.environ`` before
``import torch``). A value the user set is kept. This module imports nothing heavy.
"""

from __future__ import annotations

import os
import sys
import time
from collections.abc import MutableMapping
from pathlib import Path

from layouts.errors import InputError

#: the OpenMP settings `quiet_openmp` makes unless already set: idle threads sleep rather than spin
#: (libgomp; ``PASSIVE`` also sets its spin count to 0) and Intel's OpenMP, where a build uses it, likewise
OPENMP_ENV = {"OMP_WAIT_POLICY": "PASSIVE", "KMP_BLOCKTIME": "0"}
#: what ``--threads`` takes besides a count: the cores this process may use less those other work keeps busy
AUTO = "auto"
#: the most threads ``--threads auto`` picks: the network's per-frame work gains little past this
AUTO_MAX = 8


def quiet_openmp(environ: MutableMapping[str, str] | None = None) -> bool:
    """Set `OPENMP_ENV`'s variables the user left unset (in ``os.environ`` by default).

    Returns whether they can still take effect: False when torch is already imported in this process.
    """
    env = os.environ if environ is None else environ
    for key, value in OPENMP_ENV.items():
        env.setdefault(key, value)
    return "torch" not in sys.modules


def usable_cores() -> list[int]:
    """The CPUs this process may run on (its affinity; all ``os.cpu_count`` where that is unknown)."""
    try:
        return sorted(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return list(range(os.cpu_count() or 1))


def _cpu_times(stat: str) -> dict[int, tuple[int, int]]:
    """Per CPU of a /proc/stat text: (idle ticks, all ticks); idle counts iowait."""
    out = {}
    for line in stat.splitlines():
        name, _, rest = line.partition(" ")
        if name.startswith("cpu") and name[3:].isdigit():
            ticks = [int(v) for v in rest.split()[:8]]
            out[int(name[3:])] = (ticks[3] + ticks[4], sum(ticks))
    return out


def busy_cores(cpus: list[int], interval: float = 0.1, stat: str = "/proc/stat") -> float | None:
    """How many of ``cpus`` other work keeps busy, sampled over ``interval`` seconds; None where unknown.

    Sampled now, not the load average, which lags a minute behind (and still counts the previous run).
    """
    try:
        before = _cpu_times(Path(stat).read_text())
        time.sleep(interval)
        after = _cpu_times(Path(stat).read_text())
    except (OSError, ValueError, IndexError):
        return None
    busy = 0.0
    for c in cpus:
        if c not in before or c not in after or after[c][1] <= before[c][1]:
            return None
        idle = (after[c][0] - before[c][0]) / (after[c][1] - before[c][1])
        busy += 1.0 - min(max(idle, 0.0), 1.0)
    return busy


def auto_threads(cores: int, busy: float | None, most: int = AUTO_MAX) -> int:
    """Threads for ``--threads auto`` on ``cores`` of which ``busy`` are taken (up to ``most``).

    The free cores when some are free; all ``cores`` when none is (threads then take turns with the others,
    and more of them get a larger share: at 128x128 beside 2 busy processes on 2 cores, 12.8 frames/s on
    2 threads, 6.1 on 1) or where ``busy`` is unknown. Beside 1 busy process, 1 thread kept the idle
    speed (19.2 frames/s) where 2 fell to 12.9.
    """
    taken = 0 if busy is None else int(busy + 0.5)
    free = cores - taken
    return max(1, min(most, free if free >= 1 else cores))


def parse_threads(value: str | int, option: str = "--threads") -> int | str:
    """A ``--threads`` value: a count >= 1 or ``auto``; one line naming ``option`` otherwise."""
    if isinstance(value, str) and value.strip().lower() == AUTO:
        return AUTO
    try:
        n = int(value)
    except (TypeError, ValueError):
        raise InputError(f"{option} must be a count >= 1 or {AUTO!r}, got {value!r}") from None
    if n < 1:
        raise InputError(f"{option} must be >= 1, got {n}")
    return n


def resolve_threads(value: str | int, option: str = "--threads") -> int:
    """The thread count ``value`` (a count or ``auto``) stands for; ``auto`` samples this machine's free
    cores (`usable_cores`, `busy_cores`, `auto_threads`)."""
    parsed = parse_threads(value, option)
    if parsed != AUTO:
        return int(parsed)
    cpus = usable_cores()
    return auto_threads(len(cpus), busy_cores(cpus))
