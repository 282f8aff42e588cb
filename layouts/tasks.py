"""Map a picklable function over work items in local worker processes, each result as it completes.

A work item is a ``(key, argument)`` pair; ``fn(argument)`` runs in a worker and ``(key, result)`` is yielded
in the order the items finish. `TaskMap` is the shape of every such mapper: a library that fans work out
(`waresynth.generate` writes one sequence per item) takes one as an argument, so that the application decides
where the work runs (`process_map` here by default; Ray tasks on a cluster in `mvracklay.parallel`).
"""

from __future__ import annotations

import multiprocessing as mp
from collections.abc import Callable, Hashable, Iterable, Iterator
from typing import Any

#: ``tasks(fn, items)``: ``fn`` run over ``(key, argument)`` pairs somewhere, ``(key, result)`` yielded as each
#: completes; a task's exception is raised (as itself) from the iteration
TaskMap = Callable[[Callable[[Any], Any], list[tuple[Hashable, Any]]], Iterable[tuple[Hashable, Any]]]


def process_map(
    fn: Callable[[Any], Any],
    items: Iterable[tuple[Hashable, Any]],
    workers: int,
    mp_context: mp.context.BaseContext | None = None,
) -> Iterator[tuple[Hashable, Any]]:
    """``(key, fn(argument))`` for each ``(key, argument)`` of ``items``, as each completes, from ``workers``
    processes (``mp_context``: how they start; None: Python's default). ``fn`` and the arguments must pickle
    (``fn`` a module-level function). The first task that raises ends the run: its exception is raised here, the
    tasks not started are cancelled and the running ones finish before it propagates (so does stopping the
    iteration early)."""
    from concurrent.futures import ProcessPoolExecutor, as_completed

    items = list(items)
    if not items:
        return
    # An executor, not `with Pool()`: leaving a Pool's block terminates it, which can deadlock when a worker is
    # stopped while it holds the task queue's lock; the executor shuts down by joining.
    with ProcessPoolExecutor(max_workers=max(1, min(workers, len(items))), mp_context=mp_context) as ex:
        futures = {ex.submit(fn, arg): key for key, arg in items}
        try:
            for fut in as_completed(futures):
                yield futures[fut], fut.result()
        except BaseException:
            for fut in futures:
                fut.cancel()
            raise
