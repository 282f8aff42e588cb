"""The one way a model is loaded for inference: its checkpoint read, the model put on its device in its
arithmetic and runtime, torch's CPU threads set (`load_for_inference`). `mvracklay run`, `predict`, `evaluate` and
`eval-reconstruction` all load through it."""

from __future__ import annotations

import os
from typing import Any

import torch

from layouts.errors import InputError
from network.checkpoint import load_model
from network.device import single_process_device
from network.model.frozen import use_precision, use_runtime
from network.model.net import MVRackLay
from network.model.ortgraph import check_runtime, default_runtime


def load_for_inference(
    checkpoint: str | os.PathLike,
    command: str,
    device: str = "auto",
    precision: str = "fp32",
    threads: int | None = None,
    runtime: str | None = None,
) -> tuple[MVRackLay, dict[str, Any]]:
    """The model of ``checkpoint`` (eval mode, on ``device``: auto = the GPU when CUDA is present; its trunk in
    ``precision``; its CPU graphs in ``runtime``, None: `network.model.ortgraph.default_runtime`, ONNX Runtime
    where it is installed unless ``MVRACKLAY_RUNTIME`` says otherwise) and its record; ``threads``: torch's CPU
    threads (None leaves them). ``command`` names the one-process command in the refusal to run under torchrun."""
    runtime = default_runtime() if runtime is None else check_runtime(runtime, "runtime")  # refused before the load
    if threads is not None:
        if threads < 1:
            raise InputError(f"--threads must be >= 1, got {threads}")
        torch.set_num_threads(threads)
    model, record = load_model(checkpoint)
    model.to(single_process_device(command, device))
    use_precision(model, precision)
    use_runtime(model, runtime)
    return model, record
