"""A frame's readers beside the next frame's network pass (`network.inference.overlap`): the same results, in
order, and a live stream's frame never waits for the next one to arrive."""

from __future__ import annotations

import threading

import numpy as np
import pytest
import torch

from network.inference.overlap import overlapped


def test_results_come_in_order_from_a_worker_while_the_next_item_is_made():
    events: list[str] = []
    workers: set[str] = set()

    def items():
        for i in range(5):
            events.append(f"make {i}")
            yield (i,)

    def fn(i):
        workers.add(threading.current_thread().name)
        assert not torch.is_grad_enabled()  # no autograd, on the worker or not
        return i * i

    got = list(overlapped(fn, items(), lambda: True))
    assert got == [0, 1, 4, 9, 16]
    assert workers and threading.current_thread().name not in workers
    # item i+1 is made before item i's result is given: the two overlap
    assert events == [f"make {i}" for i in range(5)]
    assert list(overlapped(fn, items(), None)) == got  # no worker: the same, in turn


def test_a_result_is_given_before_waiting_for_an_item_that_is_not_at_hand():
    """A live stream with an empty buffer: frame i's result comes out before frame i+1 is asked for."""
    log: list[str] = []

    def items():
        for i in range(3):
            log.append(f"make {i}")
            yield (i,)

    for out in overlapped(lambda i: i, items(), lambda: False):
        log.append(f"got {out}")
    assert log == ["make 0", "got 0", "make 1", "got 1", "make 2", "got 2"]


def test_a_failure_on_the_worker_reaches_the_caller_and_an_early_stop_waits_for_it():
    def fn(i):
        if i == 2:
            raise ValueError("bad frame 2")
        return i

    with pytest.raises(ValueError, match="bad frame 2"):
        list(overlapped(fn, ((i,) for i in range(5)), lambda: True))
    done: list[int] = []

    def slow(i):
        done.append(i)
        return i

    gen = overlapped(slow, ((i,) for i in range(10)), lambda: True)
    assert next(gen) == 0
    gen.close()  # the call running on the worker finishes before the generator is closed
    assert done == [0, 1]


def test_streaming_with_the_overlap_gives_the_outputs_without_it(tiny_checkpoint, tiny_dataset, monkeypatch):
    """A model with a parallax box-depth head: every output, box depths included, is the same whether a frame's
    readers run beside the next frame or after it; with one CPU thread they run after it."""
    from network.checkpoint import load_model
    from network.inference import predictor
    from network.inference.predictor import Predictor
    from network.training.fit_box_depth import with_box_head
    from waresynth.dataset import open_dataset

    model = with_box_head(load_model(tiny_checkpoint)[0], parallax=True)
    seq = open_dataset(tiny_dataset).sequences()[0]
    frames = [seq.rgb(i) for i in range(len(seq))]
    calls = []

    def spy(fn, items, ahead, apart=False):
        calls.append(ahead is not None)
        return overlapped(fn, items, None if apart else ahead)

    threads = torch.get_num_threads()
    try:
        torch.set_num_threads(2)
        monkeypatch.setattr(predictor, "overlapped", spy)
        together = list(Predictor(model).stream(frames))
        monkeypatch.setattr(predictor, "overlapped", lambda *a: spy(*a, apart=True))
        apart = list(Predictor(model).stream(frames))
        torch.set_num_threads(1)
        list(Predictor(model).stream(frames[:2]))
    finally:
        torch.set_num_threads(threads)
    assert calls == [True, True, False]
    assert len(together) == len(apart) == len(frames)
    for a, b in zip(together, apart):
        assert torch.equal(a.top, b.top) and torch.equal(a.front, b.front)
        assert a.box_back is not None and np.array_equal(a.box_back, b.box_back, equal_nan=True)
        assert a.camera_step == b.camera_step
