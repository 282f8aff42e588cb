"""Parts of the network as frozen TorchScript graphs for CPU inference.

Per frame the network runs three parts with most of its arithmetic: the trunk (encoder, 1/32 blocks,
pyramid), the slot heads' coarse maps and box windows, and the box-depth head. Each, traced once for
its input shapes, frozen (the weights become constants, batch norms folded into the convolutions) and
optimised for inference (`torch.jit.optimize_for_inference`: oneDNN layouts kept between convolutions;
the trunk instead traced in channels-last format, faster there, `Part`), runs faster on CPUs than as
modules, with outputs within float rounding of the modules' (~1e-6). Measured at 256x256 on 2 threads
(docs/network.md *Inference speed*): the trunk 26 -> 16 ms a frame, the slot maps 11.6 -> 10.8, the
box-depth head 6.7 -> 5.8.

Runtimes (`set_runtime`): ``torch`` runs the TorchScript graphs above; ``onnx`` runs each part as an ONNX Runtime
session exported from the same module (`network.model.ortgraph`, faster on the CPUs measured, outputs within
float rounding of the graphs'), a part in bf16 or one that fails to export still in TorchScript; ``auto`` is
``onnx`` where ONNX Runtime is installed. A model built in code runs ``torch``; commands load models in
`network.model.ortgraph.default_runtime` (``auto`` unless ``MVRACKLAY_RUNTIME`` says otherwise).

`run` uses a graph only where it gives the same function: the model in eval mode, no gradients, float32
on the CPU, no autocast. A graph is kept per model (weakly: it goes with the model), part and input
shapes, and rebuilt when any of the part's weights changes (weights are tracked by storage and version,
which every in-place update, an optimiser step or ``load_state_dict``, bumps), so training with
validation passes between its steps, or a head fitted on a frozen trunk, never reads stale weights.
``model.frozen_graphs = False`` turns the graphs off for a model.

`set_precision` (``bf16``) runs the trunk's graph in bfloat16 instead: a copy of its weights in bf16, its
input cast to bf16 and its maps back to float32. On CPUs that compute bf16 natively (AVX512-BF16, AMX) the
trunk's frame costs about half (measured at 256x256 on one thread of an AMD EPYC with AVX512-BF16: 29.5 ->
14.0 ms), its maps ~1.5 % off the float32 ones (mean relative difference); elsewhere bf16 is emulated and far
slower. The other parts stay float32: the slot maps gained 10.6 -> 8.6 ms there, their box windows 13-15 %
off.
"""

from __future__ import annotations

import copy
import sys
import warnings
from collections.abc import Callable
from typing import Any, NamedTuple, TypeVar
from weakref import WeakKeyDictionary

import torch
from torch import nn

from network.model import ortgraph
from network.precision import check_precision, cpu_has_native_bf16


class Part(NamedTuple):
    """A part of the network that runs as a graph."""

    modules: tuple[str, ...]  #: the model's submodules it reads (their tensors key its graphs)
    buffers: tuple[str, ...] = ()  #: the model's own buffers it reads
    #: traced in channels-last memory format and frozen without `torch.jit.optimize_for_inference`; its
    #: inputs converted to that format, its outputs back (measured for the trunk at 256x256 on 2 threads:
    #: 17.7 ms optimised, 15.0-15.4 channels-last; no gain for the other parts)
    channels_last: bool = False
    #: may run in bf16 under `set_precision` (measured worth it for the trunk only; see the module docstring)
    bf16: bool = False
    #: a graph in the ``onnx`` runtime only (the modules run it in ``torch``'s, whose arithmetic stays theirs)
    onnx_only: bool = False


PARTS: dict[str, Part] = {
    "trunk": Part(("encoder", "reduce", "temporal", "pyramid"), ("mean", "std"), channels_last=True, bf16=True),
    "slots": Part(("slots",)),
    "box_depth": Part(("box_depth",)),
    "rows": Part(("rows", "back", "uprights"), onnx_only=True),  # the row heads (a model may lack the last two)
    "decode": Part(("memory", "slots"), onnx_only=True),  # a stream's memory step and the logits
}
#: graphs kept per model and part, one per set of input shapes (a windowed pass and a stream alternate
#: two), the oldest dropped
SHAPES_KEPT = 4
#: per model, per (part, function, input shapes): the key its graph was built for, the part's tensors, the graph
#: (None: it failed)
Held = tuple[tuple[Any, ...], list[torch.Tensor], torch.jit.ScriptModule | None]
_GRAPHS: WeakKeyDictionary[nn.Module, dict[tuple[Any, ...], Held]] = WeakKeyDictionary()
T = TypeVar("T")


def set_precision(model: nn.Module, precision: str) -> None:
    """Run ``model``'s trunk graph in ``precision`` (`PRECISIONS`: ``fp32``, the default, or ``bf16``; see
    the module docstring) wherever its graphs apply; one line naming the option when it is neither."""
    check_precision(precision)
    model.graph_precision = precision


def set_runtime(model: nn.Module, runtime: str) -> None:
    """Run ``model``'s CPU graphs in ``runtime`` (`network.model.ortgraph.RUNTIMES`: ``torch``, ``onnx`` or ``auto``;
    see the module docstring); one line naming the option when it is none of them."""
    model.graph_runtime = ortgraph.check_runtime(runtime)


def use_runtime(model: nn.Module, runtime: str) -> None:
    """`set_runtime` for a command, with a line on stderr where ``onnx`` was asked for and ONNX Runtime is absent."""
    set_runtime(model, runtime)
    if runtime == "onnx" and not ortgraph.available():
        print("warning: runtime onnx: onnxruntime (or onnx) is not installed; running torch's graphs", file=sys.stderr)


def graph_runtime(model: nn.Module, part: str = "trunk") -> str:
    """The runtime ``part``'s graph runs in for ``model`` when its graphs apply: ``onnx`` or ``torch`` (a part in
    bf16 runs in torch)."""
    if in_bf16(model, part):
        return "torch"
    return ortgraph.resolve(getattr(model, "graph_runtime", "torch"))


def precision_warning(precision: str) -> str | None:
    """One line to print when ``precision`` is bf16 on a CPU known to lack native bf16, else None."""
    if precision == "bf16" and cpu_has_native_bf16() is False:
        return "--precision bf16: this CPU has no native bf16 (AVX512-BF16 or AMX): the trunk runs emulated, far slower"
    return None


def use_precision(model: nn.Module, precision: str) -> None:
    """`set_precision` for a command's ``--precision`` (the model already on its device), with a line on stderr
    where bf16 is emulated (`precision_warning`) or cannot apply (the graphs run on the CPU only)."""
    set_precision(model, precision)
    line = precision_warning(precision)
    if precision != "fp32" and trunk_precision(model) == "fp32":
        line = f"--precision {precision} applies to the CPU's frozen graphs; here the network runs in float32"
    if line:
        print(f"warning: {line}", file=sys.stderr)


def trunk_precision(model: nn.Module) -> str:
    """The precision ``model``'s trunk runs in at inference: bf16 where `set_precision` asked for it and its
    graphs run (on the CPU, not turned off), else fp32."""
    on_cpu = all(p.device.type == "cpu" for p in model.parameters())
    return "bf16" if in_bf16(model, "trunk") and getattr(model, "frozen_graphs", True) and on_cpu else "fp32"


def in_bf16(model: nn.Module, part: str) -> bool:
    """Whether ``part``'s graph runs in bf16 for ``model`` (`set_precision`)."""
    return PARTS[part].bf16 and getattr(model, "graph_precision", "fp32") == "bf16"


def trunk_maps(m: Any, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """The pyramid maps ``(p1, p2)`` of canonical frames ``x`` ``(N, 3, H, W)`` in [0, 1]: ``m`` has the
    trunk's submodules and the ``mean``/``std`` buffers (an `network.model.net.MVRackLay` or `_Part`)."""
    s1, f2, f3, f4, f5 = m.encoder((x - m.mean) / m.std)
    t5 = m.reduce(f5)
    return m.pyramid((s1, f2, f3, f4, t5), m.temporal(t5))


class _Part(nn.Module):
    """A model's part alone (its submodules and buffers shared) running ``fn``: the module that is traced."""

    def __init__(self, model: nn.Module, part: str, fn: Callable[..., Any]) -> None:
        super().__init__()
        modules, buffers = PARTS[part].modules, PARTS[part].buffers
        for name in modules:
            setattr(self, name, getattr(model, name))
        for name in buffers:
            self.register_buffer(name, getattr(model, name))
        self.fn = fn

    def forward(self, *xs: torch.Tensor) -> Any:
        return self.fn(self, *xs)


def applies(model: nn.Module, x: torch.Tensor) -> bool:
    """Whether a frozen graph gives ``model``'s function of input ``x`` (see the module docstring)."""
    return (
        getattr(model, "frozen_graphs", True)
        and not model.training
        and not torch.is_grad_enabled()
        and x.device.type == "cpu"
        and x.dtype == torch.float32
        and not torch.is_autocast_enabled("cpu")
    )


def _tensors(model: nn.Module, part: str) -> list[torch.Tensor]:
    """The part's parameters and buffers (the objects themselves: in-place updates keep them)."""
    modules, buffers = PARTS[part].modules, PARTS[part].buffers
    present = [getattr(model, name) for name in modules if getattr(model, name) is not None]
    return [t for module in present for t in module.state_dict(keep_vars=True).values()] + [
        getattr(model, name) for name in buffers
    ]


def _key(model: nn.Module, part: str, xs: tuple[torch.Tensor, ...], tensors: list[torch.Tensor]) -> tuple[Any, ...]:
    """What a graph was built for: the inputs' shapes, the part's modules, each weight's storage and version."""
    return (
        tuple(tuple(x.shape) for x in xs),
        tuple(id(getattr(model, name)) for name in PARTS[part][0]),
        *((t.data_ptr(), t._version) for t in tensors),
    )


def _build(model: nn.Module, part: str, fn: Callable[..., Any], xs: tuple[torch.Tensor, ...], bf16: bool) -> Any:
    if not bf16 and graph_runtime(model, part) == "onnx":
        try:
            context = f"{part} {fn.__module__}.{fn.__qualname__} {getattr(model, 'cfg', None)!r}"
            return ortgraph.OrtGraph(_Part(model, part, fn).eval(), xs, torch.get_num_threads(), context)
        except Exception as e:  # noqa: BLE001 - an export or session failure: torch's graph still works
            said = "its modules" if PARTS[part].onnx_only else "torch's graph"
            warnings.warn(f"the {part} part could not run in ONNX Runtime ({e}); running {said}", stacklevel=3)
    if PARTS[part].onnx_only:
        return None
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # tracing's notes on constants: the shapes are fixed by design
            module = _Part(model, part, fn).eval()
            if bf16:  # a copy: the model's own weights stay float32
                module, xs = copy.deepcopy(module).to(torch.bfloat16), _cast(xs, torch.bfloat16)
            if PARTS[part].channels_last:  # a copy: the model's own weights keep their format
                module = copy.deepcopy(module).to(memory_format=torch.channels_last)
                traced = torch.jit.trace(module, _channels_last(xs), check_trace=False)
                return torch.jit.freeze(traced)
            return torch.jit.optimize_for_inference(torch.jit.freeze(torch.jit.trace(module, xs, check_trace=False)))
    except (RuntimeError, TypeError) as e:  # an unusual build of torch: the module's own path still works
        warnings.warn(f"the frozen {part} graph could not be built ({e}); running the modules", stacklevel=3)
        return None


def run(model: nn.Module, part: str, fn: Callable[..., T], *xs: torch.Tensor) -> T:
    """``fn(model, *xs)``, through the part's frozen graph where that `applies`: ``fn`` reads only the part's
    submodules and buffers (`PARTS`) and returns tensors (or tuples of them); its Python control flow may
    depend on the inputs' shapes only (a graph is traced per set of shapes)."""
    if not applies(model, xs[0]) or (PARTS[part].onnx_only and graph_runtime(model, part) != "onnx"):
        return fn(model, *xs)
    graphs = _GRAPHS.setdefault(model, {})
    bf16 = in_bf16(model, part)
    # a session is made for a runtime and a thread count: either changed, another is made
    how = (graph_runtime(model, part), torch.get_num_threads())
    slot = (part, fn, tuple(tuple(x.shape) for x in xs), bf16, how)
    held = graphs.get(slot)
    if held is None or held[0] != _key(model, part, xs, held[1]):
        tensors = _tensors(model, part)
        held = (_key(model, part, xs, tensors), tensors, _build(model, part, fn, xs, bf16))
        graphs.pop(slot, None)
        same = [k for k in graphs if k[0] == part]
        if len(same) >= SHAPES_KEPT:
            del graphs[same[0]]
        graphs[slot] = held
    graph = held[2]
    if graph is None:
        return fn(model, *xs)
    if bf16:
        xs = _cast(xs, torch.bfloat16)
    if PARTS[part].channels_last and not isinstance(graph, ortgraph.OrtGraph):
        out = _contiguous(graph(*_channels_last(xs)))
    else:
        out = graph(*xs)
    return _cast(out, torch.float32) if bf16 else out


def _cast(out: Any, dtype: torch.dtype) -> Any:
    """A tensor or a tuple of them, the floating-point ones in ``dtype``."""
    if isinstance(out, tuple):
        return tuple(_cast(o, dtype) for o in out)
    return out.to(dtype) if out.is_floating_point() else out


def _channels_last(xs: tuple[torch.Tensor, ...]) -> tuple[torch.Tensor, ...]:
    return tuple(x.contiguous(memory_format=torch.channels_last) if x.ndim == 4 else x for x in xs)


def _contiguous(out: Any) -> Any:
    """A graph's outputs (a tensor or a tuple of them) in the default memory format."""
    return tuple(o.contiguous() for o in out) if isinstance(out, tuple) else out.contiguous()


def graphs_held(model: nn.Module) -> int:
    """How many graphs are kept for ``model`` (0: its parts have only run as modules)."""
    return len(_GRAPHS.get(model, {}))


def maps(model: nn.Module, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """`trunk_maps` of ``model``, through its frozen graph where that `applies`."""
    return run(model, "trunk", trunk_maps, x)
