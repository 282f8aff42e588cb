"""Parts of the network as ONNX Runtime sessions: the ``onnx`` runtime of `network.model.frozen`'s graphs.

ONNX Runtime's CPU kernels run the network's parts faster than torch's frozen graphs on the CPUs we measured
(2 cores of an AMD EPYC with AVX2, 256x256, each part alone: the trunk 18.0 -> 12.9 ms, the slot maps
15.2 -> 11.8, the box-depth head 22.3 -> 16.9), and far faster beside other jobs (its pool lets the calling
thread take the work of a thread that is not scheduled, where an OpenMP region waits for it: docs/results.md
*Speed*). Outputs are within float rounding of the graphs' (~1e-4 on the logits; Table I the same to the
second decimal on held-out sets). A part is exported from the model's own weights in memory when it first
runs (no file, nothing downloaded: it works offline; ~2 s for all parts at 256x256) and its session is kept
like a TorchScript graph (per part and input shapes, rebuilt when a weight changes).

The runtime is chosen per model (`network.model.frozen.set_runtime`): ``torch`` (TorchScript graphs, the
arithmetic the shipped layouts' digests pin), ``onnx`` (ONNX Runtime; torch where it is not installed or a
part does not export) or ``auto`` (``onnx`` where ONNX Runtime is installed). Commands load models with
`default_runtime`: the environment variable ``MVRACKLAY_RUNTIME`` (one of `RUNTIMES`), else ``auto``.
"""

from __future__ import annotations

import functools
import importlib.util
import io
import os
import warnings
from typing import Any

import torch
from torch import nn

from layouts.errors import InputError

RUNTIMES = ("auto", "torch", "onnx")  #: the runtimes a model's CPU graphs run in
ENV = "MVRACKLAY_RUNTIME"  #: names the runtime commands load models with (`default_runtime`)
OPSET = 17  #: the ONNX operator set the parts are exported in (GridSample needs >= 16)


def check_runtime(runtime: str, option: str = ENV) -> str:
    """``runtime`` when it is one of `RUNTIMES`, else one line naming ``option``."""
    if runtime not in RUNTIMES:
        raise InputError(f"{option} must be one of {', '.join(RUNTIMES)}, got {runtime!r}")
    return runtime


def default_runtime() -> str:
    """The runtime commands load models with: ``$MVRACKLAY_RUNTIME`` if set (checked), else ``auto``."""
    return check_runtime(os.environ.get(ENV, "").strip().lower() or "auto")


@functools.cache
def available() -> bool:
    """Whether ONNX Runtime and the ONNX exporter's package are installed (looked up once: every part asks per frame)."""
    return all(importlib.util.find_spec(name) is not None for name in ("onnxruntime", "onnx"))


def resolve(runtime: str) -> str:
    """What ``runtime`` runs as here: ``torch`` or ``onnx`` (``auto`` and ``onnx`` need ONNX Runtime)."""
    return "onnx" if runtime in ("auto", "onnx") and available() else "torch"


class OrtGraph:
    """A module's function of fixed-shape inputs as an ONNX Runtime session; called with tensors, it returns
    float32 tensors (a tuple where the function returns several)."""

    def __init__(self, module: nn.Module, xs: tuple[torch.Tensor, ...], threads: int) -> None:
        import onnxruntime as ort

        buf = io.BytesIO()
        with warnings.catch_warnings(), torch.no_grad():
            warnings.simplefilter("ignore")  # the exporter's notes on tracing and its deprecation
            torch.onnx.export(module, xs, buf, dynamo=False, opset_version=OPSET, do_constant_folding=True)
        opts = ort.SessionOptions()
        opts.intra_op_num_threads = max(1, int(threads))
        opts.inter_op_num_threads = 1
        # idle pool threads sleep rather than spin: torch's own threads run between the parts
        opts.add_session_config_entry("session.intra_op.allow_spinning", "0")
        opts.log_severity_level = 3
        self.session = ort.InferenceSession(buf.getvalue(), opts, providers=["CPUExecutionProvider"])
        self.inputs = [i.name for i in self.session.get_inputs()]
        self.single = len(self.session.get_outputs()) == 1

    def __call__(self, *xs: torch.Tensor) -> Any:
        feed = {name: x.detach().contiguous().numpy() for name, x in zip(self.inputs, xs, strict=True)}
        out = tuple(torch.from_numpy(o) for o in self.session.run(None, feed))
        return out[0] if self.single else out
