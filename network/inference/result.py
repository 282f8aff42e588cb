"""One frame's prediction, typed (`FramePrediction`), and the layouts it gives (`frame_layouts`).

`network.inference.predictor.Predictor`'s ``run`` / ``stream`` / ``window`` / ``predict`` yield a
`FramePrediction` per frame: the layouts' logits, the shelf slots, the depths read, the camera's step and, in
``maps``, the heads' maps the fits and studies read.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F

from layouts import VIEWS, LayoutSpec
from layouts.boxdepth import impose_box_backs
from layouts.rackdepth import impose_rack_depth

#: the outputs `FramePrediction` names; any other is one of its ``maps``
NAMED = ("top", "front", "anchors", "rows", "rack_depth", "box_back", "box_front", "camera_step",
         "camera_step_confidence")  # fmt: skip


@dataclass(frozen=True)
class FramePrediction:
    """What the network predicted for one frame."""

    top: torch.Tensor  #: top-view logits ``(R, 3, D, D)``, the model's box offset applied
    front: torch.Tensor  #: front-view logits ``(R, 3, D, D)``
    anchors: torch.Tensor | None = None  #: ``(R,)`` canonical board rows of the shelf slots (NaN: no slot)
    rack_depth: float = math.nan  #: metres imposed on the top view (given or read); NaN: as decoded
    box_back: np.ndarray | None = None  #: ``(R, D)`` each column's box back, metres behind the front (box-depth head)
    box_front: np.ndarray | None = None  #: ``(R, D)`` box fronts, for a head that reads them
    camera_step: float | None = None  #: metres the camera moved along the row since the frame before (images)
    camera_step_confidence: float | None = None  #: how far that step can be trusted, 0..1
    rows: torch.Tensor | None = None  #: the row head's board logits per canonical image row
    #: the other outputs by name: the maps the depth heads read (``back``, ``uprights``, ``box_window``,
    #: ``box_parallax``) and any a `Predictor` subclass adds
    maps: Mapping[str, torch.Tensor] = field(default_factory=dict)

    @classmethod
    def from_outputs(cls, out: dict[str, Any]) -> FramePrediction:
        """The typed form of one frame's raw outputs (`Predictor`'s passes)."""

        def num(key: str) -> float | None:
            return None if key not in out else float(out[key])

        def arr(key: str) -> np.ndarray | None:
            return None if out.get(key) is None else np.asarray(out[key])

        depth = num("rack_depth")
        return cls(
            top=out["top"],
            front=out["front"],
            anchors=out.get("anchors"),
            rack_depth=math.nan if depth is None else depth,
            box_back=arr("box_back"),
            box_front=arr("box_front"),
            camera_step=num("camera_step"),
            camera_step_confidence=num("camera_step_confidence"),
            rows=out.get("rows"),
            maps={k: v for k, v in out.items() if k not in NAMED},
        )

    def head_inputs(self) -> dict[str, Any]:
        """What the box-depth head reads of this frame, by name (`network.heads.boxdepth.frame_head_inputs`)."""
        return {"top": self.top, "front": self.front, "anchors": self.anchors, **self.maps}

    def layouts(self, spec: LayoutSpec) -> dict[str, np.ndarray]:
        """Both views' class-id stacks at ``spec.size`` (`frame_layouts`)."""
        out: dict[str, Any] = {"top": self.top, "front": self.front}
        if not math.isnan(self.rack_depth):
            out["rack_depth"] = self.rack_depth
        out.update({k: v for k, v in (("box_back", self.box_back), ("box_front", self.box_front)) if v is not None})
        return frame_layouts(out, spec)


def resize_logits(logits: torch.Tensor, size: int | None = None) -> torch.Tensor:
    """``(R, 3, D, D)`` logits at ``size x size`` (bilinear; unchanged when ``size`` is None or D)."""
    if size is not None and size != logits.shape[-1]:
        return F.interpolate(logits.float(), size=(size, size), mode="bilinear", align_corners=False)
    return logits


def logits_to_layout(logits: torch.Tensor, size: int | None = None) -> np.ndarray:
    """``(R, 3, D, D)`` logits -> ``(R, size, size)`` uint8 class ids (bilinear on logits when resizing)."""
    return resize_logits(logits, size).argmax(1).to(torch.uint8).cpu().numpy()


def frame_layouts(out: dict[str, torch.Tensor], spec: LayoutSpec) -> dict[str, Any]:
    """Both views' class-id stacks at ``spec.size`` from one frame's outputs, the top view redrawn
    at the output's ``"rack_depth"`` when it has one (`Predictor`; `layouts.rackdepth.impose_rack_depth`)
    and then, with ``"box_back"``, every box's back moved there (`layouts.boxdepth.impose_box_backs`; with
    ``"box_front"`` its front too)."""
    lay = {v: logits_to_layout(out[v], spec.size) for v in VIEWS}
    depth = out.get("rack_depth")
    if depth is not None and bool(torch.isfinite(torch.as_tensor(depth))):
        lay["top"] = impose_rack_depth(lay["top"], spec, float(depth))  # checks it fits the top view
        backs = out.get("box_back")
        if backs is not None:
            fronts = out.get("box_front")
            fronts = None if fronts is None else np.asarray(fronts)
            lay["top"] = impose_box_backs(
                lay["top"], lay["front"], spec, float(depth), np.asarray(backs), fronts=fronts
            )
    return lay
