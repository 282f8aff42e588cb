"""The trunk (encoder, 1/32 blocks, pyramid) as a frozen TorchScript graph for CPU inference.

Per frame the trunk is most of the network's arithmetic. Traced once for an input shape, frozen (the
weights become constants, batch norms folded into the convolutions) and optimised for inference
(`torch.jit.optimize_for_inference`: oneDNN layouts kept between convolutions), it runs faster on CPUs
(measured: the encoder alone at 256x256 on 2 threads, 16.5 ms a frame as modules, 9.9 as the graph;
docs/network.md *Inference speed*), with outputs within float rounding of the modules' (~1e-6).

`maps` uses the graph only where it gives the same function: the model in eval mode, no gradients,
float32 on the CPU, no autocast. A graph is kept per model (weakly: it goes with the model) and rebuilt
when the input shape or any trunk weight changes (weights are tracked by storage and version, which
every in-place update, an optimiser step or ``load_state_dict``, bumps), so training with
validation passes between its steps never reads stale weights. ``model.frozen_trunk = False`` turns it
off for a model.
"""

from __future__ import annotations

import warnings
from typing import Any
from weakref import WeakKeyDictionary

import torch
from torch import nn

#: the submodules the trunk runs, in order
TRUNK = ("encoder", "reduce", "temporal", "pyramid")
#: graphs kept per model, one per input shape (a windowed pass and a stream alternate two), the oldest dropped
SHAPES_KEPT = 4
#: per model, per input shape: the key its graph was built for, the trunk's tensors, the graph (None: it failed)
Held = tuple[tuple[Any, ...], list[torch.Tensor], torch.jit.ScriptModule | None]
_GRAPHS: WeakKeyDictionary[nn.Module, dict[tuple[int, ...], Held]] = WeakKeyDictionary()


def trunk_maps(m: Any, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """The pyramid maps ``(p1, p2)`` of canonical frames ``x`` ``(N, 3, H, W)`` in [0, 1]: ``m`` has the
    `TRUNK` submodules and the ``mean``/``std`` buffers (an `network.model.MVRackLay` or `_Trunk`)."""
    s1, f2, f3, f4, f5 = m.encoder((x - m.mean) / m.std)
    t5 = m.reduce(f5)
    return m.pyramid((s1, f2, f3, f4, t5), m.temporal(t5))


class _Trunk(nn.Module):
    """A model's trunk alone (its submodules shared), the module that is traced."""

    def __init__(self, model: nn.Module) -> None:
        super().__init__()
        for name in TRUNK:
            setattr(self, name, getattr(model, name))
        self.register_buffer("mean", model.mean)
        self.register_buffer("std", model.std)

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        return trunk_maps(self, x)


def applies(model: nn.Module, x: torch.Tensor) -> bool:
    """Whether the frozen graph gives ``model``'s maps of ``x`` (see the module docstring)."""
    return (
        getattr(model, "frozen_trunk", True)
        and not model.training
        and not torch.is_grad_enabled()
        and x.device.type == "cpu"
        and x.dtype == torch.float32
        and not torch.is_autocast_enabled("cpu")
    )


def _tensors(model: nn.Module) -> list[torch.Tensor]:
    """The trunk's parameters and buffers (the objects themselves: in-place updates keep them)."""
    return [t for name in TRUNK for t in getattr(model, name).state_dict(keep_vars=True).values()]


def _key(model: nn.Module, x: torch.Tensor, tensors: list[torch.Tensor]) -> tuple[Any, ...]:
    """What a graph was built for: the input's shape, the trunk's modules, each weight's storage and version."""
    return (
        tuple(x.shape),
        tuple(id(getattr(model, name)) for name in TRUNK),
        *((t.data_ptr(), t._version) for t in tensors),
    )


def _build(model: nn.Module, x: torch.Tensor) -> torch.jit.ScriptModule | None:
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # tracing's notes on constants: the shape is fixed by design
            traced = torch.jit.trace(_Trunk(model).eval(), x, check_trace=False)
            return torch.jit.optimize_for_inference(torch.jit.freeze(traced))
    except (RuntimeError, TypeError) as e:  # an unusual build of torch: the module's own path still works
        warnings.warn(f"the frozen trunk graph could not be built ({e}); running the modules", stacklevel=3)
        return None


def maps(model: nn.Module, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """`trunk_maps` of ``model``, through its frozen graph where that `applies`."""
    if not applies(model, x):
        return trunk_maps(model, x)
    graphs = _GRAPHS.setdefault(model, {})
    shape = tuple(x.shape)
    held = graphs.get(shape)
    if held is None or held[0] != _key(model, x, held[1]):
        tensors = _tensors(model)
        held = (_key(model, x, tensors), tensors, _build(model, x))
        graphs.pop(shape, None)
        if len(graphs) >= SHAPES_KEPT:
            del graphs[next(iter(graphs))]
        graphs[shape] = held
    graph = held[2]
    return trunk_maps(model, x) if graph is None else graph(x)
