"""A frame's readers beside the next frame's network pass: `overlapped` runs a per-item function on a worker thread.

Streaming prediction has two halves per frame: the network's parts (ONNX Runtime or torch graphs, two CPU threads)
and the readers of their outputs (the parallax maps, the box-depth head, the rack depth, the fusion), which are
mostly small single-threaded operations. Run one after the other they keep 2 cores about 1.57 busy; with a frame's
readers on a worker thread while the next frame goes through the network, about 1.73, and 256x256 streaming gains
about a tenth in frames/s (`benchmarks/bench_infer.py`). The results are the same: the readers see the frames in
order, on one thread, with the same thread count.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Any

import torch


def always() -> bool:
    """The next frame is at hand (frames from files: reading one never waits for the camera)."""
    return True


def overlapped(fn: Callable[..., Any], items: Iterable[tuple], ahead: Callable[[], bool] | None) -> Iterator[Any]:
    """``fn(*item)`` of each item of ``items``, in order.

    Calls run without autograd. With ``ahead``, each runs on one worker thread (with torch's thread count here)
    while the next item is made, as long as ``ahead()`` says the next item is at hand; when it says not (a live
    stream's buffer is empty) the pending result is given first, so a frame's result never waits for the next
    frame to arrive. None: every call here, in turn (one CPU thread asked for)."""
    work = torch.no_grad()(fn)
    if ahead is None:
        for item in items:
            yield work(*item)
        return
    threads = torch.get_num_threads()
    it = iter(items)
    pending: Future | None = None
    with ThreadPoolExecutor(1, "mvracklay-readers", initializer=torch.set_num_threads, initargs=(threads,)) as pool:
        try:
            while True:
                if pending is not None and not ahead():
                    done, pending = pending, None
                    yield done.result()
                item = next(it, None)  # the next frame through the network, while ``pending`` runs
                if item is None:
                    break
                fut = pool.submit(work, *item)
                if pending is not None:
                    done, pending = pending, None
                    yield done.result()
                pending = fut
            if pending is not None:
                done, pending = pending, None
                yield done.result()
        finally:
            if pending is not None:  # the caller stopped early or an item failed: the running call is let finish
                with contextlib.suppress(Exception):
                    pending.result()
