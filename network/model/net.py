"""The MVRackLay network: ResNet-18 encoder, stacked ConvLSTM, shelf-anchored top/front decoders, discriminators.

Input is a *canonical* image (`layouts.canonical.CanonicalView`): whatever the camera, pixels are
squares of ``x_extent / width`` metres on the rack front plane, centred on the optical axis, so
image column j covers the X interval of layout column j and a board at height Y sits on a row
fixed by Y alone. Data flow per frame:

    image -> ResNet-18 (1/2 ... 1/32 maps) -> a feature pyramid down to 1/2 -> a *row head*
    scores every canonical row for "the top edge of a visible shelf board's front" -> the lowest
    R boards anchor the R shelf slots -> per slot, features are sampled along the slot's own rows
    (bilinear): the front view's rows are heights above the board, so its window is a resampled
    strip of the image; the top view's rows are depths, mapped from a band of image rows around
    the board by a learned per-column transform -> per-slot coarse feature maps in *layout space*
    -> (sequence variants) a stacked ConvLSTM over the window's per-slot maps, its output added
    back through a zero-initialised convolution -> small convolutional heads -> ``R x 3`` class
    logits at D x D per view.

Anchoring every slot on its board makes the decoders' job the same wherever the shelf appears in
the image (camera height, shelf spacing and distance all vary): the part a plain decoder spends
most of its training on. Nothing mixes image columns except local convolutions, so X stays
aligned. During training the anchors come from the ground truth (with jitter); at inference from
the row head. A slot without an anchor is background.

The temporal block works in layout space: a slot's coarse top- and front-view maps of consecutive
frames differ by the camera's motion along the row. The motion is read from the canonical images
themselves (`network.model.motion`, no pose needed) and the ConvLSTM state is shifted by it before each
frame, so a memory cell stays on one piece of shelf (how deep a box is shows on its side faces or
top only from some viewpoints). It starts as an exact no-op, so a sequence model starts from
trained ``racklay`` weights.

Parts: `network.model.config` (`ModelConfig`, `VARIANTS`), `network.model.decoders` (pyramid, row head,
slot heads), `network.model.memory` (the slot memory), `network.model.discriminator`.
"""

from __future__ import annotations

from typing import Any

import torch
from torch import nn

from layouts import NUM_CLASSES, VIEWS
from layouts.errors import InputError
from network.heads.backedge import BackEdgeHead, pool_rows
from network.heads.boxdepth import PARALLAX_CHANNELS as BOX_PARALLAX_CHANNELS
from network.heads.boxdepth import BoxDepthHead
from network.heads.uprights import UprightHead, pool_columns
from network.model import frozen
from network.model.config import ModelConfig
from network.model.decoders import Pyramid, RowHead, SlotFeatures, SlotHeads, anchors_from_rows, conv_bn_relu
from network.model.memory import MemoryState, SlotMemory, shifted
from network.model.motion import motion_signature
from network.model.resnet import ResNet18Encoder

IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)


class MVRackLay(nn.Module):
    """Encoder + pyramid + row head + shelf-anchored decoders + (sequence variants) the slot memory.

    `forward` takes a window ``(B, T, 3, H, W)`` of canonical float images in [0, 1] (and, in
    training, the ground-truth anchors ``(B, T, R)``) and returns ``{"top", "front": (B, T, R, 3, D,
    D) logits, "rows": (B, T, H) row-head logits, "anchors": (B, T, R)}`` (and, with the back-edge
    head, ``"back": (B, T, H)`` its logits). `step` is the
    streaming form: one frame in, its outputs and the carried memory state out; `frame_features`
    and `decode_window` let a caller cache per-frame work across overlapping windows.
    """

    def __init__(self, cfg: ModelConfig) -> None:
        super().__init__()
        self.cfg = cfg
        self.encoder = ResNet18Encoder(cfg.encoder_width)
        c2, c3, c4, c5 = self.encoder.channels
        self.reduce = conv_bn_relu(c5, cfg.hidden, 1)
        self.temporal = conv_bn_relu(cfg.hidden, cfg.hidden)  # the single-frame 1/32 block
        self.pyramid = Pyramid(cfg, c2, c2, c3, c4)  # the stem has the width of layer1
        fine, coarse = self.pyramid.channels
        self.rows = RowHead(fine, coarse, cfg.input_height)
        self.back = BackEdgeHead(2 * (fine + coarse), cfg.input_height) if cfg.back_edges else None
        self.uprights = UprightHead(2 * (fine + coarse), cfg.input_width) if cfg.uprights else None
        #: fitted on the frozen network (`network.training.fit_box_depth`); inputs: `network.heads.boxdepth.head_inputs`
        c2d = fine + NUM_CLASSES + (BOX_PARALLAX_CHANNELS if cfg.box_parallax else 0)
        self.box_depth = (
            BoxDepthHead(
                c2d,
                cfg.spec.size + 2,
                width=cfg.box_width,
                front=cfg.box_front,
            )  # fmt: skip
            if cfg.box_depth
            else None
        )
        self.slots = SlotHeads(cfg, fine, coarse)
        self.memory = (
            SlotMemory(cfg.decoder_width, cfg.memory_hidden, cfg.lstm_layers, cfg.view if cfg.align_memory else None)
            if cfg.use_lstm
            else None
        )
        #: per view, subtracted from the box logit by `network.inference.predictor.Predictor` (`network.training.calibrate`;
        #: not part of the weights: a checkpoint's record carries it)
        self.box_logit_offset: dict[str, float] = {v: 0.0 for v in VIEWS}
        #: metres added to every rack depth the reader reads (`network.training.calibrate.fit_rack_depth_offset`;
        #: a checkpoint's record carries it)
        self.rack_depth_offset = 0.0
        #: at inference on the CPU the trunk, the slot maps and the box-depth head run as frozen graphs
        #: (`network.model.frozen`); False: always the modules
        self.frozen_graphs = True
        #: the trunk graph's precision, fp32 or bf16 (`network.model.frozen.set_precision`)
        self.graph_precision = "fp32"
        #: the runtime of those graphs, torch, onnx or auto (`network.model.frozen.set_runtime`); commands load
        #: models in `network.model.ortgraph.default_runtime`
        self.graph_runtime = "torch"
        self.register_buffer("mean", torch.tensor(IMAGENET_MEAN).view(1, 3, 1, 1), persistent=False)
        self.register_buffer("std", torch.tensor(IMAGENET_STD).view(1, 3, 1, 1), persistent=False)

    def _check(self, x: torch.Tensor) -> None:
        h, w = x.shape[-2:]
        if (h, w) != (self.cfg.input_height, self.cfg.input_width):
            raise InputError(f"model expects images of {self.cfg.input_width}x{self.cfg.input_height}, got {w}x{h}")

    def maps(self, images: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The pyramid maps ``(p1, p2)`` (1/2 and 1/4 scale) of frames ``(N, 3, H, W)``; at inference on the CPU
        through the trunk's frozen graph (`network.model.frozen`; ``self.frozen_graphs = False`` turns them off)."""
        self._check(images)
        return frozen.maps(self, images)

    def pooled_rows(self, images: torch.Tensor) -> torch.Tensor:
        """The row heads' input for frames ``(N, 3, H, W)``: `network.heads.backedge.pool_rows` of the pyramid."""
        return pool_rows(*self.maps(images))

    def frame_features(
        self,
        images: torch.Tensor,
        anchors: torch.Tensor | None = None,
        signature: torch.Tensor | None = None,
    ) -> tuple[SlotFeatures, torch.Tensor, torch.Tensor]:
        """Per-frame work for frames ``(N, 3, H, W)``: slot features, row logits ``(N, H)``, anchors ``(N, R)``
        (the given ones, else the row head's). ``signature``: the frames' `motion_signature` where the caller has
        read it already (the aligned memory needs it; else it is read here)."""
        p1, p2 = self.maps(images)
        heads = frozen.run(self, "rows", row_heads, p1, p2)
        heads = list(heads) if isinstance(heads, tuple) else [heads]  # a session of one output gives a tensor
        rows = heads.pop(0)
        if anchors is None:
            anchors = anchors_from_rows(rows, self.cfg.view, self.cfg.spec.num_slots)
        sig = None
        if self.memory is not None and self.memory.view is not None:
            sig = motion_signature(images) if signature is None else signature
        fn = slot_maps_windows if self.box_depth is not None else slot_maps
        maps = frozen.run(self, "slots", fn, p1, p2, anchors)
        feats = SlotFeatures(*maps[:3], torch.isfinite(anchors), motion=sig)
        if self.back is not None:
            feats.back = heads.pop(0)
        if self.uprights is not None:
            feats.uprights = heads.pop(0)
        if self.box_depth is not None:
            feats.window = maps[3]
        return feats, rows, anchors

    def box_logits(self, win: torch.Tensor, extra: torch.Tensor) -> torch.Tensor:
        """The box-depth head's logits on `network.heads.boxdepth.head_inputs` (at inference on the CPU through
        its frozen graph, `network.model.frozen`)."""
        if self.box_depth is None:
            raise InputError("this model has no box-depth head (the fit-box-depth stage of a training recipe adds one)")
        return frozen.run(self, "box_depth", _box_head, win, extra)

    def decode_window(self, window: list[SlotFeatures]) -> list[dict[str, torch.Tensor]]:
        """Logits of each frame of a window (slot features in frame order), fused by the slot memory."""
        if self.memory is not None:
            window = self.memory.window(window)
        return [self.slots.finish(f) for f in window]

    def forward(self, images: torch.Tensor, anchors: torch.Tensor | None = None) -> dict[str, torch.Tensor]:
        """Logits of a window ``(B, T, 3, H, W)``, every frame's (slot memory over the window in order)."""
        if images.ndim != 5:
            raise InputError(f"expected a window (B, T, 3, H, W), got shape {tuple(images.shape)}")
        b, t = images.shape[:2]
        if anchors is not None and tuple(anchors.shape) != (b, t, self.cfg.spec.num_slots):
            raise InputError(f"anchors must have shape {(b, t, self.cfg.spec.num_slots)}, got {tuple(anchors.shape)}")
        # frames ordered (time, batch) so each time step is one contiguous block
        x = images.transpose(0, 1).flatten(0, 1)
        a = None if anchors is None else anchors.transpose(0, 1).flatten(0, 1)
        feats, rows, a = self.frame_features(x, a)
        outs = self.decode_window([feats.select(t, i) for i in range(t)])
        res = {v: torch.stack([o[v] for o in outs], 1) for v in VIEWS}
        extra = {"rows": rows, "anchors": a, "back": feats.back, "uprights": feats.uprights, "box_window": feats.window}
        # frame-major (T*B, ...) -> (B, T, ...), as the views are stacked
        res.update({k: x.unflatten(0, (t, b)).transpose(0, 1) for k, x in extra.items() if x is not None})
        return res

    def step(
        self,
        image: torch.Tensor,
        state: MemoryState | None = None,
        anchors: torch.Tensor | None = None,
        motion: torch.Tensor | None = None,
        signature: torch.Tensor | None = None,
    ) -> tuple[dict[str, torch.Tensor], MemoryState | None]:
        """Streaming: one frame ``(B, 3, H, W)`` (anchors ``(B, R)`` or the row head's); outputs and the new state.

        ``motion`` ``(B,)``: the camera's step along the row since the previous frame, metres (+ =
        toward +X), from another source (odometry, ground truth); by default the aligned memory
        reads it from the images. ``signature``: the image's `motion_signature`, where the caller has it.
        """
        if motion is not None:
            motion = torch.as_tensor(motion, dtype=torch.float32, device=image.device).reshape(-1)
            if motion.shape[0] != image.shape[0] or not torch.isfinite(motion).all():
                raise InputError(f"motion must hold one finite step (metres) per image, got {motion.tolist()}")
        feats, rows, anchors = self.frame_features(image, anchors, signature)
        if self.memory is not None and self.memory.view is not None and frozen.graph_runtime(self, "decode") == "onnx":
            out, state = self._decode(feats, state, motion)
        else:
            if self.memory is not None:
                feats, state = self.memory.step(feats, state, motion)
            out = self.slots.finish(feats)
        out["rows"] = rows
        out["anchors"] = anchors
        out.update(head_outputs(feats))
        return out, state

    def _decode(
        self, feats: SlotFeatures, state: MemoryState | None, motion: torch.Tensor | None
    ) -> tuple[dict[str, torch.Tensor], MemoryState]:
        """`step`'s aligned memory step and logits as one part (`decode_step`), which `network.model.frozen` runs in
        ONNX Runtime where the model's graphs do: the same function as the modules'."""
        assert self.memory is not None
        xs = (feats.top, feats.front, feats.fine, feats.valid)
        if state is not None:
            grid = self.memory.align_grid(state, feats, motion)
            xs = (*xs, grid, *(t for hc in state.lstm for t in hc))
        top, front, *lstm = frozen.run(self, "decode", decode_step, *xs)
        return {"top": top, "front": front}, MemoryState(list(zip(lstm[0::2], lstm[1::2])), feats.motion)


def decode_step(m: Any, top: torch.Tensor, front: torch.Tensor, fine: torch.Tensor, valid: torch.Tensor,
                *carried: torch.Tensor) -> tuple[torch.Tensor, ...]:  # fmt: skip
    """One frame of the aligned slot memory and the slot heads' logits, on tensors: the coarse maps, fine samples
    and anchor mask of `SlotFeatures`, then (after a first frame) the state's `network.model.memory.shift_grid` and
    its ``h, c`` per layer. Returns the top and front logits and the new ``h, c`` per layer."""
    f = SlotFeatures(top, front, fine, valid)
    lstm = None
    if carried:
        grid, held = carried[0], carried[1:]
        lstm = [(shifted(h, grid), shifted(c, grid)) for h, c in zip(held[0::2], held[1::2])]
    h, lstm = m.memory.lstm.step(m.memory._pooled(f), lstm)
    out = m.slots.finish(m.memory._refine(f, h))
    return (out["top"], out["front"], *(t for hc in lstm for t in hc))


def row_heads(m: Any, p1: torch.Tensor, p2: torch.Tensor) -> tuple[torch.Tensor, ...]:
    """The row heads on the pyramid maps: the board rows' logits, then those of the back edges and the uprights
    (of the heads the model has): the part of a frame that `network.model.frozen` runs as ``rows``."""
    pooled = pool_rows(p1, p2)
    out = [m.rows.from_pooled(pooled)]
    if m.back is not None:
        out.append(m.back(pooled))
    if m.uprights is not None:
        out.append(m.uprights(pool_columns(p1, p2)))
    return tuple(out)


def slot_maps(m: Any, p1: torch.Tensor, p2: torch.Tensor, anchors: torch.Tensor) -> tuple[torch.Tensor, ...]:
    """`SlotHeads.coarse` of ``m.slots`` as tensors ``(top, front, fine)``: the slot heads' part of a frame
    that `network.model.frozen` runs as a graph."""
    f = m.slots.coarse(p1, p2, anchors)
    return f.top, f.front, f.fine


def slot_maps_windows(m: Any, p1: torch.Tensor, p2: torch.Tensor, anchors: torch.Tensor) -> tuple[torch.Tensor, ...]:
    """`slot_maps` and the box-depth head's windows (`SlotHeads.window`)."""
    return (*slot_maps(m, p1, p2, anchors), m.slots.window(p1, anchors))


def _box_head(m: Any, win: torch.Tensor, extra: torch.Tensor) -> torch.Tensor:
    return m.box_depth(win, extra)


def head_outputs(feats: SlotFeatures) -> dict[str, torch.Tensor]:
    """The depth heads' per-frame outputs a model gives beside the layouts: ``"back"``, ``"uprights"``,
    ``"box_window"`` (those of the heads it has)."""
    named = {"back": feats.back, "uprights": feats.uprights, "box_window": feats.window}
    return {k: v for k, v in named.items() if v is not None}
