"""Parts of the network as ONNX Runtime sessions: the ``onnx`` runtime of `network.model.frozen`'s graphs.

ONNX Runtime's CPU kernels run the network's parts faster than torch's frozen graphs on the CPUs we measured
(2 cores of an AMD EPYC with AVX2, 256x256, each part alone: the trunk 18.0 -> 12.9 ms, the slot maps
15.2 -> 11.8, the box-depth head 22.3 -> 16.9), and far faster beside other jobs (its pool lets the calling
thread take the work of a thread that is not scheduled, where an OpenMP region waits for it: docs/results.md
*Speed*). Outputs are within float rounding of the graphs' (~1e-4 on the logits; Table I the same to the
second decimal on held-out sets). A part is exported from the model's own weights in memory when it first
runs (nothing downloaded: it works offline; ~2-7 s for all parts at 256x256) and its session is kept like a
TorchScript graph (per part and input shapes, rebuilt when a weight changes). The exported bytes are cached in
`cache_dir` (written atomically, named by a digest of everything the export depends on: the part's weights and
buffers, input shapes, the model config, the network's source code and the library versions), so a later
process loads the part in a fraction of a second; a cache file that does not load is exported again.

The runtime is chosen per model (`network.model.frozen.set_runtime`): ``torch`` (TorchScript graphs, the
arithmetic the shipped layouts' digests pin), ``onnx`` (ONNX Runtime; torch where it is not installed or a
part does not export) or ``auto`` (``onnx`` where ONNX Runtime is installed). Commands load models with
`default_runtime`: the environment variable ``MVRACKLAY_RUNTIME`` (one of `RUNTIMES`), else ``auto``.
"""

from __future__ import annotations

import contextlib
import functools
import hashlib
import importlib.util
import io
import os
import warnings
from pathlib import Path
from typing import Any

import torch
from torch import nn

from layouts.errors import InputError
from layouts.fileio import atomic_write_bytes, user_cache_dir

#: names the folder of the exported parts (`cache_dir`); ``off`` (or ``0``) caches nothing
CACHE_ENV = "MVRACKLAY_ONNX_CACHE"
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


def cache_dir() -> Path | None:
    """Where exported parts are kept: ``$MVRACKLAY_ONNX_CACHE``, else ``$XDG_CACHE_HOME/mvracklay/onnx``, else
    ``~/.cache/mvracklay/onnx``; None where ``$MVRACKLAY_ONNX_CACHE`` is ``off`` or ``0``."""
    given = os.environ.get(CACHE_ENV, "").strip()
    if given.lower() in ("off", "0"):
        return None
    if given:
        return Path(given).expanduser()
    return user_cache_dir("onnx")  # None with no home folder to find: nothing cached


@functools.cache
def _code_digest() -> str:
    """sha256 over the source the parts are traced from (`network`, `layouts`) and the exporting libraries' versions."""
    import onnx
    import onnxruntime

    h = hashlib.sha256(f"{torch.__version__} {onnx.__version__} {onnxruntime.__version__} {OPSET}".encode())
    root = Path(__file__).resolve().parents[2]
    for pkg in ("network", "layouts"):
        for f in sorted((root / pkg).rglob("*.py")):
            h.update(f.relative_to(root).as_posix().encode() + b"\0" + f.read_bytes())
    return h.hexdigest()


def export_key(module: nn.Module, xs: tuple[torch.Tensor, ...], context: str) -> str:
    """The digest an export of ``module`` on inputs shaped like ``xs`` is cached under: every parameter and buffer
    (names, shapes, values), the inputs' shapes and dtypes, ``context`` (the part, its function, the model config)
    and `_code_digest`."""
    h = hashlib.sha256(f"{_code_digest()}\n{context}\n".encode())
    h.update(repr([(tuple(x.shape), str(x.dtype)) for x in xs]).encode())
    for name, t in [*module.named_parameters(), *module.named_buffers()]:
        h.update(f"{name}:{t.dtype}:{tuple(t.shape)}".encode())
        flat = t.detach().cpu().contiguous().reshape(-1)  # 1-d: a 0-d tensor cannot be viewed as bytes
        h.update(flat.view(torch.uint8).numpy().tobytes() if flat.numel() else b"")
    return h.hexdigest()


def export(module: nn.Module, xs: tuple[torch.Tensor, ...]) -> bytes:
    """``module``'s function of inputs shaped like ``xs`` as ONNX bytes (torch's exporter, traced)."""
    buf = io.BytesIO()
    with warnings.catch_warnings(), torch.no_grad():
        warnings.simplefilter("ignore")  # the exporter's notes on tracing and its deprecation
        torch.onnx.export(module, xs, buf, dynamo=False, opset_version=OPSET, do_constant_folding=True)
    return buf.getvalue()


class OrtGraph:
    """A module's function of fixed-shape inputs as an ONNX Runtime session; called with tensors, it returns
    float32 tensors (a tuple where the function returns several). ``context`` names what the module's tensors
    do not (the part, its function, the model config) for the cache (`export_key`)."""

    def __init__(self, module: nn.Module, xs: tuple[torch.Tensor, ...], threads: int, context: str = "") -> None:
        import onnxruntime as ort

        opts = ort.SessionOptions()
        opts.intra_op_num_threads = max(1, int(threads))
        opts.inter_op_num_threads = 1
        # idle pool threads sleep rather than spin: torch's own threads run between the parts
        opts.add_session_config_entry("session.intra_op.allow_spinning", "0")
        opts.log_severity_level = 3
        folder = cache_dir()
        path = None if folder is None else folder / f"{export_key(module, xs, context)}.onnx"
        self.cached = False  #: the session was made from a cached export
        if path is not None and path.is_file():
            try:
                self.session = ort.InferenceSession(path.read_bytes(), opts, providers=["CPUExecutionProvider"])
                self.cached = True
            except Exception:  # noqa: BLE001 - a damaged cache file: exported again below
                pass
        if not self.cached:
            data = export(module, xs)
            self.session = ort.InferenceSession(data, opts, providers=["CPUExecutionProvider"])
            if path is not None:
                with contextlib.suppress(OSError):  # a cache that cannot be written only costs the next export
                    atomic_write_bytes(path, data)
        self.inputs = [i.name for i in self.session.get_inputs()]
        self.single = len(self.session.get_outputs()) == 1

    def __call__(self, *xs: torch.Tensor) -> Any:
        feed = {name: x.detach().contiguous().numpy() for name, x in zip(self.inputs, xs, strict=True)}
        out = tuple(torch.from_numpy(o) for o in self.session.run(None, feed))
        return out[0] if self.single else out
