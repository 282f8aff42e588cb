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

Variants (`VARIANTS`): ``mvracklay-disc-4`` (default), ``mvracklay-disc-8``, ``mvracklay-4``
(no discriminators) and ``racklay`` (single frame, no ConvLSTM).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, replace
from typing import Any

import torch
import torch.nn.functional as F
from torch import nn

from layouts import NUM_CLASSES, VIEWS, LayoutSpec
from layouts.canonical import CanonicalView
from layouts.errors import InputError
from network.heads.backedge import BackEdgeHead, pool_rows, row_net, rows_from_net
from network.heads.boxdepth import BOX_WIDTH, BoxDepthHead, window_rows
from network.heads.boxdepth import PARALLAX_CHANNELS as BOX_PARALLAX_CHANNELS
from network.heads.uprights import UprightHead, pool_columns
from network.inference import frozen
from network.model.convlstm import StackedConvLSTM, State
from network.model.fastops import avg_pool2, up2
from network.model.motion import camera_shift, motion_signature
from network.model.resnet import ResNet18Encoder

#: variant -> (sequence length, uses the ConvLSTM, uses discriminators)
VARIANTS: dict[str, tuple[int, bool, bool]] = {
    "mvracklay-disc-4": (4, True, True),
    "mvracklay-disc-8": (8, True, True),
    "mvracklay-4": (4, True, False),
    "racklay": (1, False, True),
}
DEFAULT_VARIANT = "mvracklay-disc-4"
#: the decoder design; records of other designs are refused with a line saying so
ARCH = "anchored"
#: model options of earlier versions that no shipped model used; a record may still name them, switched off
RETIRED_FLAGS = ("parallax", "geo_top", "box_row_profile")

IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)

#: the top view's band of image rows around a board: this far above the front window, and below the board (metres)
BAND_ABOVE = 0.15
BAND_BELOW = 0.30
#: row head decoding: probability threshold and the least distance between two boards (metres)
ROW_THRESHOLD = 0.5
MIN_BOARD_GAP = 0.35


@dataclass(frozen=True)
class ModelConfig:
    """Everything needed to rebuild a model: variant, canonical input size, layout spec and widths."""

    variant: str = DEFAULT_VARIANT
    input_width: int = 128
    input_height: int = 128
    spec: LayoutSpec = field(default_factory=lambda: LayoutSpec(size=64))
    encoder_width: int = 32  #: ResNet-18 base width (64 = standard, needed for ImageNet weights)
    hidden: int = 128  #: channels of the reduced 1/32 map
    lstm_layers: int = 2  #: ConvLSTM layers of the slot memory (sequence variants)
    memory_hidden: int = 32  #: ConvLSTM channels of the slot memory
    decoder_width: int = 32
    align_memory: bool = (
        True  #: shift the slot memory by the camera motion read from the images (`network.model.motion`)
    )
    back_edges: bool = (
        False  #: a head finds the boards' back edges, from which the rack depth is read (`network.heads.backedge`)
    )
    uprights: bool = (
        False  #: a head marks front and rear uprights, which also give the rack depth (`network.heads.uprights`)
    )
    box_depth: bool = False  #: a head reads each box's depth, carried along the row (`network.heads.boxdepth`)
    box_parallax: bool = (
        False  #: that head also reads plane-sweep costs against earlier frames (`network.heads.boxdepth`)
    )
    box_width: int = BOX_WIDTH  #: that head's channels (`network.heads.boxdepth.BoxDepthHead`)
    box_front: bool = False  #: that head also reads each box's front (`network.heads.boxdepth.FRONT_BINS`)
    arch: str = ARCH

    def __post_init__(self) -> None:
        if self.variant not in VARIANTS:
            raise InputError(f"unknown variant {self.variant!r}; choose from {sorted(VARIANTS)}")
        if self.arch != ARCH:
            raise InputError(f"decoder design {self.arch!r} is not supported by this version (it builds {ARCH!r})")
        for name in ("input_width", "input_height"):
            v = getattr(self, name)
            if not isinstance(v, int) or isinstance(v, bool) or v < 32 or v % 32:
                raise InputError(f"{name} must be a positive multiple of 32, got {v!r}")
        for name in ("encoder_width", "hidden", "lstm_layers", "memory_hidden", "decoder_width", "box_width"):
            v = getattr(self, name)
            if not isinstance(v, int) or isinstance(v, bool) or v < 1:
                raise InputError(f"{name} must be a positive integer, got {v!r}")
        if not isinstance(self.align_memory, bool):
            raise InputError(f"align_memory must be true or false, got {self.align_memory!r}")
        for name in ("back_edges", "uprights", "box_depth", "box_parallax", "box_front"):
            if not isinstance(getattr(self, name), bool):
                raise InputError(f"{name} must be true or false, got {getattr(self, name)!r}")
        for name in ("box_parallax", "box_front"):
            if getattr(self, name) and not self.box_depth:
                raise InputError(f"{name} is part of the box-depth head; it needs box_depth")
        if not self.use_lstm:  # no memory to align: one value, so records from before the flag still match
            object.__setattr__(self, "align_memory", True)
        if self.decoder_width < 4:
            raise InputError(f"decoder_width must be >= 4, got {self.decoder_width}")
        if not isinstance(self.spec, LayoutSpec):
            raise InputError(f"spec must be a LayoutSpec, got {type(self.spec).__name__}")
        if self.spec.size < 8 or self.spec.size % 4:
            raise InputError(f"layout size D must be a multiple of 4 (>= 8) for the model, got {self.spec.size}")

    @property
    def seq_len(self) -> int:
        return VARIANTS[self.variant][0]

    @property
    def use_lstm(self) -> bool:
        return VARIANTS[self.variant][1]

    @property
    def use_disc(self) -> bool:
        return VARIANTS[self.variant][2]

    @property
    def view(self) -> CanonicalView:
        """The canonical image geometry the model reads: input size over the layouts' X extent."""
        return CanonicalView(self.input_width, self.input_height, self.spec.x_extent)

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["spec"] = self.spec.to_dict()
        return d

    @classmethod
    def from_dict(cls, d: Any, source: str = "model config") -> ModelConfig:
        if not isinstance(d, dict):
            raise InputError(f"{source}: model config must be a JSON object")
        d = dict(d)
        if d.get("arch") != ARCH:
            raise InputError(
                f"{source}: written for an earlier decoder design ({d.get('arch', 'column transform')!r}); "
                f"this version builds {ARCH!r}: retrain, or use the weights shipped with this version"
            )
        if "temporal_residual" in d:  # written when the ConvLSTM sat on the 1/32 encoder map
            if VARIANTS.get(d.get("variant"), (1, False, False))[1]:
                raise InputError(
                    f"{source}: written for the earlier ConvLSTM on the 1/32 encoder map; this version fuses "
                    "frames in layout space (the slot memory): retrain, or warm-start from a racklay checkpoint"
                )
            del d["temporal_residual"]  # single-frame models are unchanged
        d.setdefault("align_memory", False)  # written before the memory was aligned: it never was
        for name in RETIRED_FLAGS:  # options of earlier versions: records name them, off
            if d.pop(name, False) is not False:
                raise InputError(f"{source}: {name!r} is on, an option this version no longer has: retrain without it")
        known = set(cls.__dataclass_fields__)
        unknown = sorted(set(d) - known)
        if unknown:
            raise InputError(f"{source}: unknown model config keys {unknown}")
        if "spec" in d:
            d["spec"] = LayoutSpec.from_dict(d["spec"], f"{source} (spec)")
        try:
            return cls(**d)
        except (TypeError, InputError) as e:
            raise InputError(f"{source}: {e}") from None

    def with_variant(self, variant: str) -> ModelConfig:
        return replace(self, variant=variant)


def _conv_bn_relu(cin: int, cout: int, k: int = 3) -> nn.Sequential:
    return nn.Sequential(nn.Conv2d(cin, cout, k, padding=k // 2, bias=False), nn.BatchNorm2d(cout), nn.ReLU(True))


def _up(x: torch.Tensor, like: torch.Tensor | None = None) -> torch.Tensor:
    if like is not None:
        return F.interpolate(x, size=like.shape[-2:], mode="nearest")
    return up2(x)


class ColumnTransform(nn.Module):
    """``(N, C, h, w) -> (N, cout, rows, w)``: per image column, channels x rows -> cout x rows'.

    A 1x1 convolution on the column-stacked features: every column gets the same learned
    mapping from (slot-anchored) image rows to layout rows, and columns never mix (X stays aligned).
    """

    def __init__(self, cin: int, hin: int, cout: int, rows: int) -> None:
        super().__init__()
        self.cout, self.rows = cout, rows
        self.proj = nn.Sequential(
            nn.Conv2d(cin * hin, cout * rows, 1, bias=False), nn.BatchNorm2d(cout * rows), nn.ReLU(True)
        )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        n, c, h, w = x.shape
        y = self.proj(x.reshape(n, c * h, 1, w))
        return y.reshape(n, self.cout, self.rows, w)


#: Encoder features of a batch of frames: the 1/2 (stem), 1/4, 1/8, 1/16 maps and the reduced 1/32 map.
Features = tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]


@dataclass
class SlotFeatures:
    """Per-slot features of N frames (slots flattened into the batch: ``N*R``) before the output heads."""

    top: torch.Tensor  #: (N*R, dw, D/2, D/2) coarse top-view map
    front: torch.Tensor  #: (N*R, dw, D/2, D/2) coarse front-view map
    fine: torch.Tensor  #: (N*R, c1, D, D) fine front-window samples of the 1/2 map
    valid: torch.Tensor  #: (N, R) bool: the slot has an anchor
    motion: torch.Tensor | None = None  #: (N, 2, H, W) `network.model.motion.motion_signature` of the images
    back: torch.Tensor | None = (
        None  #: (N, H) back-edge logits (`network.heads.backedge.BackEdgeHead`), if the model has the head
    )
    window: torch.Tensor | None = (
        None  #: (N, R, c1, rows, W) front windows of the 1/2 map, for `network.heads.boxdepth`
    )
    uprights: torch.Tensor | None = (
        None  #: (N, 2, W) upright logits (`network.heads.uprights.UprightHead`), with the head
    )

    def select(self, n: int, i: int) -> SlotFeatures:
        """Frame ``i`` of ``n`` consecutive frames' features flattened as (frame, batch) -> that frame's."""

        def pick(t: torch.Tensor | None) -> torch.Tensor | None:
            return None if t is None else t.unflatten(0, (n, -1))[i]

        return SlotFeatures(**{k: pick(getattr(self, k)) for k in SLOT_FEATURES})

    def cat(self, other: SlotFeatures) -> SlotFeatures:
        """These frames' features followed by ``other``'s (both flattened as (frame, batch))."""

        def both(k: str) -> torch.Tensor | None:
            a, b = getattr(self, k), getattr(other, k)
            return None if a is None or b is None else torch.cat([a, b])

        return SlotFeatures(**{k: both(k) for k in SLOT_FEATURES})


#: `SlotFeatures`' fields, in order
SLOT_FEATURES = ("top", "front", "fine", "valid", "motion", "back", "window", "uprights")


class Pyramid(nn.Module):
    """Top-down feature pyramid from the 1/32 map (after its single-frame block) to a 1/4 map (``2 dw`` channels) and a 1/2 map."""

    def __init__(self, cfg: ModelConfig, c1: int, c2: int, c3: int, c4: int) -> None:
        super().__init__()
        f = 2 * cfg.decoder_width
        self.lat5 = _conv_bn_relu(cfg.hidden, f, 1)
        self.lat4 = _conv_bn_relu(c4, f, 1)
        self.lat3 = _conv_bn_relu(c3, f, 1)
        self.lat2 = _conv_bn_relu(c2, f, 1)
        self.m4 = _conv_bn_relu(f, f)
        self.m3 = _conv_bn_relu(f, f)
        self.m2 = _conv_bn_relu(f, f)
        self.fine_in = _conv_bn_relu(f, self.fine_channels(cfg), 1)
        self.m1 = _conv_bn_relu(self.fine_channels(cfg) + c1, self.fine_channels(cfg))
        self.channels = (self.fine_channels(cfg), f)

    @staticmethod
    def fine_channels(cfg: ModelConfig) -> int:
        return max(cfg.decoder_width // 2, 4)

    def forward(self, feats: Features, t5: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        s1, f2, f3, f4, _ = feats
        p = self.lat5(t5)
        p = self.m4(_up(p, f4) + self.lat4(f4))
        p = self.m3(_up(p, f3) + self.lat3(f3))
        p2 = self.m2(_up(p, f2) + self.lat2(f2))
        p1 = self.m1(torch.cat([_up(self.fine_in(p2), s1), s1], 1))
        return p1, p2


class RowHead(nn.Module):
    """Logits ``(N, H)`` over canonical rows: does the top edge of a visible shelf board's front lie here?

    Boards are horizontal in the canonical image (the camera does not roll), so the evidence is
    pooled across columns (mean and max, `network.heads.backedge.pool_rows`) and reasoned about along the rows.
    """

    def __init__(self, c1: int, c2: int, height: int) -> None:
        super().__init__()
        self.height = height
        self.net = row_net(2 * (c1 + c2))

    def from_pooled(self, pooled: torch.Tensor) -> torch.Tensor:
        """Logits from `pool_rows` features (shared with the back-edge head)."""
        return rows_from_net(self.net(pooled), self.height)

    def forward(self, p1: torch.Tensor, p2: torch.Tensor) -> torch.Tensor:
        return self.from_pooled(pool_rows(p1, p2))


def anchors_from_rows(
    logits: torch.Tensor, view: CanonicalView, slots: int, threshold: float = ROW_THRESHOLD
) -> torch.Tensor:
    """Decode row-head logits ``(N, H)`` into slot anchors ``(N, R)``: continuous canonical rows, NaN = no slot.

    Peaks above ``threshold`` at least `MIN_BOARD_GAP` apart (strongest first), each refined to
    the probability-weighted centre of its +-2 rows; the lowest R (largest rows) become slots 0..R-1.
    """
    p = torch.sigmoid(logits.detach().float()).cpu()
    out = torch.full((p.shape[0], slots), float("nan"))
    for i in range(p.shape[0]):
        for s, c in enumerate(board_peaks(p[i], view, threshold)[:slots]):
            out[i, s] = c
    return out.to(logits.device)


def board_peaks(prob: torch.Tensor, view: CanonicalView, threshold: float = ROW_THRESHOLD) -> list[float]:
    """Continuous canonical rows of the boards in one frame's row-head probabilities ``(H,)``, lowest first.

    Peaks above ``threshold`` at least `MIN_BOARD_GAP` apart (strongest first), each refined to the
    probability-weighted centre of its +-2 rows.
    """
    p = prob.detach().float().cpu().reshape(-1)
    h = p.shape[0]
    gap = MIN_BOARD_GAP / view.metres_per_pixel
    left = F.pad(p, (1, 0), value=-1.0)[:-1]
    right = F.pad(p, (0, 1), value=-1.0)[1:]
    peak = (p >= left) & (p > right) & (p > threshold)
    idx = torch.arange(h, dtype=torch.float32)
    cand = torch.nonzero(peak).flatten().tolist()
    cand.sort(key=lambda r: -float(p[r]))
    kept: list[float] = []
    for r in cand:
        lo, hi = max(0, r - 2), min(h, r + 3)
        w = p[lo:hi]
        c = float((w * idx[lo:hi]).sum() / w.sum()) + 0.5
        if all(abs(c - k) >= gap for k in kept):
            kept.append(c)
    return sorted(kept, reverse=True)


class SlotHeads(nn.Module):
    """Both views of every shelf slot from pyramid features sampled along the slot's anchor row."""

    def __init__(self, cfg: ModelConfig, c1: int, c2: int) -> None:
        super().__init__()
        spec, view = cfg.spec, cfg.view
        self.view, self.spec = view, spec
        d, dw = spec.size, cfg.decoder_width
        self.dc = d // 2
        self.band_rows = self._band_rows(4)  # ~1.3 samples per 1/4-map row
        cs = dw
        self.reduce = _conv_bn_relu(c2, cs, 1)
        self.col = ColumnTransform(cs, self.band_rows, dw, self.dc)
        self.front_c = nn.Sequential(_conv_bn_relu(cs + 1, dw), _conv_bn_relu(dw, dw))
        self.top_c = nn.Sequential(_conv_bn_relu(dw + 1, dw), _conv_bn_relu(dw, dw))
        half = max(dw // 2, 4)
        self.front_f = nn.Sequential(_conv_bn_relu(dw + c1, half), nn.Conv2d(half, NUM_CLASSES, 1))
        self.top_f = nn.Sequential(_conv_bn_relu(dw + c1, half), nn.Conv2d(half, NUM_CLASSES, 1))
        # front-window heights (row 0 = top) and the top view's band, as offsets in canonical rows
        self.register_buffer("front_coarse", self._heights(self.dc), persistent=False)
        self.register_buffer("front_fine", self._heights(d), persistent=False)
        self.register_buffer("band", self._band(self.band_rows), persistent=False)

    def _band_rows(self, stride: int) -> int:
        """Rows sampled on the top view's band from a map of ``stride`` canonical pixels per row (~1.3 each)."""
        band = self.spec.h_extent + BAND_ABOVE + BAND_BELOW
        return max(4, math.ceil(1.3 * band / (stride * self.view.metres_per_pixel)))

    def _band(self, rows: int) -> torch.Tensor:
        """The top view's band (`BAND_ABOVE` over the front window to `BAND_BELOW` under the board) as
        ``rows`` offsets in canonical rows from the anchor."""
        band = self.spec.h_extent + BAND_ABOVE + BAND_BELOW
        k = torch.arange(rows, dtype=torch.float32)
        return (-(self.spec.h_extent + BAND_ABOVE) + (k + 0.5) / rows * band) / self.view.metres_per_pixel

    def _heights(self, n: int) -> torch.Tensor:
        h = (n - torch.arange(n, dtype=torch.float32) - 0.5) / n * self.spec.h_extent
        return -h / self.view.metres_per_pixel

    def _sample(self, fmap: torch.Tensor, anchors: torch.Tensor, offsets: torch.Tensor, cols: int) -> torch.Tensor:
        """``(N, C, h, w)`` sampled at rows ``anchor + offset`` x ``cols`` even columns -> ``(N*R, C, rows, cols)``."""
        n, r = anchors.shape
        rows = offsets.numel()
        y = (anchors[:, :, None] + offsets[None, None, :]) * (2.0 / self.view.height) - 1.0  # (N, R, rows)
        x = (torch.arange(cols, device=fmap.device, dtype=fmap.dtype) + 0.5) * (2.0 / cols) - 1.0
        grid = torch.stack(
            [x.view(1, 1, 1, cols).expand(n, r, rows, cols), y[..., None].expand(n, r, rows, cols)], -1
        ).reshape(n, r * rows, cols, 2)
        s = F.grid_sample(fmap, grid.to(fmap.dtype), mode="bilinear", padding_mode="zeros", align_corners=False)
        c = fmap.shape[1]
        return s.view(n, c, r, rows, cols).transpose(1, 2).reshape(n * r, c, rows, cols)

    def coarse(self, p1: torch.Tensor, p2: torch.Tensor, anchors: torch.Tensor) -> SlotFeatures:
        """Per-slot coarse layout-space maps of both views (and the fine samples) of a batch of frames."""
        n, r = anchors.shape
        d, dc = self.spec.size, self.dc
        valid = torch.isfinite(anchors)
        a = torch.where(valid, anchors, torch.full_like(anchors, self.view.height / 2)).to(p2.dtype)
        elev = (a.reshape(n * r, 1, 1, 1) - self.view.height / 2) * (self.view.metres_per_pixel / 1.5)
        q = self.reduce(p2)
        fc = self._sample(q, a, self.front_coarse, dc)
        fc = self.front_c(torch.cat([fc, elev.expand(-1, 1, dc, dc)], 1))
        tb = self.col(self._sample(q, a, self.band, dc))
        tc = self.top_c(torch.cat([tb, elev.expand(-1, 1, dc, dc)], 1))
        ff = self._sample(p1, a, self.front_fine, d)  # (N*R, c1, D, D)
        return SlotFeatures(tc, fc, ff, valid)

    def window(self, p1: torch.Tensor, anchors: torch.Tensor) -> torch.Tensor:
        """The 1/2 map ``(N, c1, H/2, W/2)`` over each slot's front window, every column of it:
        ``(N, R, c1, rows, W/2)`` (rows: the front view's in groups, `network.heads.boxdepth.WINDOW_ROWS`; a slot
        without an anchor samples the image's middle)."""
        n, r = anchors.shape
        a = torch.where(torch.isfinite(anchors), anchors, torch.full_like(anchors, self.view.height / 2))
        rows = window_rows(self.spec.size)
        offs = self.front_fine.view(rows, -1).mean(1)
        return self._sample(p1, a, offs, p1.shape[-1]).unflatten(0, (n, r))

    def finish(self, f: SlotFeatures) -> dict[str, torch.Tensor]:
        """``R x 3`` logits of both views from (possibly memory-refined) slot features."""
        n, r = f.valid.shape
        d = self.spec.size
        front = self.front_f(torch.cat([_up(f.front), f.fine], 1))
        edges = f.fine.amax(2, keepdim=True).expand(-1, -1, d, -1)  # the front face's X evidence, along depth
        top = self.top_f(torch.cat([_up(f.top), edges], 1))
        out = {}
        bg = torch.tensor([8.0] + [-8.0] * (NUM_CLASSES - 1), device=front.device, dtype=front.dtype)
        for name, o in (("top", top), ("front", front)):
            o = o.view(n, r, NUM_CLASSES, d, d)
            out[name] = torch.where(f.valid[:, :, None, None, None], o, bg.view(1, 1, -1, 1, 1))
        return out

    def forward(self, p1: torch.Tensor, p2: torch.Tensor, anchors: torch.Tensor) -> dict[str, torch.Tensor]:
        return self.finish(self.coarse(p1, p2, anchors))


@dataclass
class MemoryState:
    """What streaming carries from frame to frame: the ConvLSTM state and the last frame's motion signature."""

    lstm: State
    motion: torch.Tensor | None


class SlotMemory(nn.Module):
    """The temporal block: a stacked ConvLSTM over each slot's coarse maps (both views), in layout space.

    Per slot and frame, the top- and front-view coarse maps ``(2 dw, D/2, D/2)`` are pooled 2x (cells
    of ``x_extent / (D/4)``, ~19 cm) and fed to the ConvLSTM in frame order; its output, upsampled, is
    added back through a zero-initialised 1x1 convolution, so a fresh memory leaves the single-frame
    network's outputs unchanged. The layout frame moves with the camera, so with ``align`` the state
    is shifted by the camera motion read from the images (`network.model.motion`) before each frame: a
    memory cell then stays on the same piece of shelf, and what an earlier viewpoint showed (a box's
    side face, its top) is where the current frame needs it. Without ``align`` the 3x3 gates must
    learn to follow the motion themselves.
    """

    def __init__(self, channels: int, hidden: int, layers: int, view: CanonicalView | None = None) -> None:
        super().__init__()
        self.channels = channels
        self.view = view  #: None: no alignment
        self.lstm = StackedConvLSTM(2 * channels, hidden, layers)
        self.out = nn.Conv2d(hidden, 2 * channels, 1)
        nn.init.zeros_(self.out.weight)
        nn.init.zeros_(self.out.bias)

    def _refine(self, f: SlotFeatures, h: torch.Tensor) -> SlotFeatures:
        corr = _up(self.out(h))
        return replace(f, top=f.top + corr[:, : self.channels], front=f.front + corr[:, self.channels :])

    @staticmethod
    def _pooled(f: SlotFeatures) -> torch.Tensor:
        return avg_pool2(torch.cat([f.top, f.front], 1))

    def _align(
        self, state: State, prev: torch.Tensor | None, cur: SlotFeatures, dx: torch.Tensor | None = None
    ) -> State:
        """The state moved with the camera from the frame of motion signature ``prev`` to ``cur``'s
        (or by the given camera steps ``dx``, ``(N,)`` metres)."""
        if self.view is None:
            return state
        if dx is None:
            if prev is None or cur.motion is None:
                raise InputError("the aligned slot memory needs each frame's motion signature")
            dx = camera_shift(prev, cur.motion, self.view)  # (N,) metres
        slots = cur.valid.shape[1]
        return [
            (shift_columns(h, dx, self.view.x_extent, slots), shift_columns(c, dx, self.view.x_extent, slots))
            for h, c in state
        ]

    def step(
        self, f: SlotFeatures, state: MemoryState | None, motion: torch.Tensor | None = None
    ) -> tuple[SlotFeatures, MemoryState]:
        """One frame's slot features ``(B*R, ...)``; the state is per (batch, slot). ``motion``:
        the camera's step since the state's frame, ``(B,)`` metres, instead of the image estimate."""
        lstm = None if state is None else self._align(state.lstm, state.motion, f, motion)
        h, lstm = self.lstm.step(self._pooled(f), lstm)
        return self._refine(f, h), MemoryState(lstm, f.motion)

    def window(self, feats: list[SlotFeatures]) -> list[SlotFeatures]:
        """A window's frames in order (each ``(B*R, ...)``), refined by a fresh memory."""
        out, state = [], None
        for f in feats:
            g, state = self.step(f, state)
            out.append(g)
        return out


def shift_columns(x: torch.Tensor, dx: torch.Tensor, x_extent: float, slots: int) -> torch.Tensor:
    """Layout-space maps ``(N*R, C, h, w)`` (``w`` columns over ``x_extent``) after the camera moved by ``dx`` ``(N,)``.

    The layout frame moves with the camera, so a world point at column x moves to x - dx: the new
    map at x is the old one at x + dx (bilinear; cells that come into view start at zero).
    """
    n = x.shape[0]
    off = (2.0 * dx / x_extent).to(x.dtype).repeat_interleave(slots)  # normalised grid units
    theta = x.new_zeros(n, 2, 3)
    theta[:, 0, 0] = 1.0
    theta[:, 1, 1] = 1.0
    theta[:, 0, 2] = off
    grid = F.affine_grid(theta, list(x.shape), align_corners=False)
    return F.grid_sample(x, grid, mode="bilinear", padding_mode="zeros", align_corners=False)


class PatchDiscriminator(nn.Module):
    """LSGAN patch discriminator on one view's per-slot class probabilities ``(N, R, 3, D, D)``."""

    def __init__(self, slots: int, width: int = 32) -> None:
        super().__init__()
        c = slots * NUM_CLASSES
        self.net = nn.Sequential(
            nn.Conv2d(c, width, 4, 2, 1),
            nn.LeakyReLU(0.2, True),
            nn.Conv2d(width, 2 * width, 4, 2, 1),
            nn.BatchNorm2d(2 * width),
            nn.LeakyReLU(0.2, True),
            nn.Conv2d(2 * width, 4 * width, 4, 2, 1),
            nn.BatchNorm2d(4 * width),
            nn.LeakyReLU(0.2, True),
            nn.Conv2d(4 * width, 1, 3, 1, 1),
        )

    def forward(self, probs: torch.Tensor) -> torch.Tensor:
        return self.net(probs.flatten(1, 2))


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
        self.reduce = _conv_bn_relu(c5, cfg.hidden, 1)
        self.temporal = _conv_bn_relu(cfg.hidden, cfg.hidden)  # the single-frame 1/32 block
        self.pyramid = Pyramid(cfg, c2, c2, c3, c4)  # the stem has the width of layer1
        fine, coarse = self.pyramid.channels
        self.rows = RowHead(fine, coarse, cfg.input_height)
        self.back = BackEdgeHead(2 * (fine + coarse), cfg.input_height) if cfg.back_edges else None
        self.uprights = UprightHead(2 * (fine + coarse), cfg.input_width) if cfg.uprights else None
        #: fitted on the frozen network (`network.training.fit_boxdepth`); inputs: `network.heads.boxdepth.head_inputs`
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
        #: (`network.inference.frozen`); False: always the modules
        self.frozen_graphs = True
        #: the trunk graph's precision, fp32 or bf16 (`network.inference.frozen.set_precision`)
        self.graph_precision = "fp32"
        self.register_buffer("mean", torch.tensor(IMAGENET_MEAN).view(1, 3, 1, 1), persistent=False)
        self.register_buffer("std", torch.tensor(IMAGENET_STD).view(1, 3, 1, 1), persistent=False)

    def _check(self, x: torch.Tensor) -> None:
        h, w = x.shape[-2:]
        if (h, w) != (self.cfg.input_height, self.cfg.input_width):
            raise InputError(f"model expects images of {self.cfg.input_width}x{self.cfg.input_height}, got {w}x{h}")

    def maps(self, images: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The pyramid maps ``(p1, p2)`` (1/2 and 1/4 scale) of frames ``(N, 3, H, W)``; at inference on the CPU
        through the trunk's frozen graph (`network.inference.frozen`; ``self.frozen_graphs = False`` turns them off)."""
        self._check(images)
        return frozen.maps(self, images)

    def pooled_rows(self, images: torch.Tensor) -> torch.Tensor:
        """The row heads' input for frames ``(N, 3, H, W)``: `network.heads.backedge.pool_rows` of the pyramid."""
        return pool_rows(*self.maps(images))

    def frame_features(
        self,
        images: torch.Tensor,
        anchors: torch.Tensor | None = None,
    ) -> tuple[SlotFeatures, torch.Tensor, torch.Tensor]:
        """Per-frame work for frames ``(N, 3, H, W)``: slot features, row logits ``(N, H)``, anchors ``(N, R)``
        (the given ones, else the row head's)."""
        p1, p2 = self.maps(images)
        pooled = pool_rows(p1, p2)
        rows = self.rows.from_pooled(pooled)
        if anchors is None:
            anchors = anchors_from_rows(rows, self.cfg.view, self.cfg.spec.num_slots)
        sig = motion_signature(images) if self.memory is not None and self.memory.view is not None else None
        fn = slot_maps_windows if self.box_depth is not None else slot_maps
        maps = frozen.run(self, "slots", fn, p1, p2, anchors)
        feats = SlotFeatures(*maps[:3], torch.isfinite(anchors), motion=sig)
        if self.back is not None:
            feats.back = self.back(pooled)
        if self.uprights is not None:
            feats.uprights = self.uprights(pool_columns(p1, p2))
        if self.box_depth is not None:
            feats.window = maps[3]
        return feats, rows, anchors

    def box_logits(self, win: torch.Tensor, extra: torch.Tensor) -> torch.Tensor:
        """The box-depth head's logits on `network.heads.boxdepth.head_inputs` (at inference on the CPU through
        its frozen graph, `network.inference.frozen`)."""
        if self.box_depth is None:
            raise InputError("this model has no box-depth head (mvracklay fit-box-depth adds one)")
        return frozen.run(self, "box_depth", _box_head, win, extra)

    def decode_window(self, window: list[SlotFeatures], skip: int = 0) -> list[dict[str, torch.Tensor]]:
        """Logits of each frame of a window (slot features in frame order) but the ``skip`` first,
        fused by the slot memory (which runs over all of them)."""
        if self.memory is not None:
            window = self.memory.window(window)
        return [self.slots.finish(f) for f in window[skip:]]

    def forward(
        self,
        images: torch.Tensor,
        anchors: torch.Tensor | None = None,
        grad_frames: int | None = None,
    ) -> dict[str, torch.Tensor]:
        """Logits of a window ``(B, T, 3, H, W)``, every frame's (slot memory over the window in order).

        ``grad_frames`` k < T: the T - k first frames only warm the slot memory up: their per-frame
        work (encoder to slot features) runs without gradients and the outputs (logits, rows,
        anchors) are the k last frames'. The memory's gradients still reach back over all T frames,
        so what an early frame shows can pay at a late one, at a fraction of a long window's cost.
        """
        if images.ndim != 5:
            raise InputError(f"expected a window (B, T, 3, H, W), got shape {tuple(images.shape)}")
        b, t = images.shape[:2]
        if anchors is not None and tuple(anchors.shape) != (b, t, self.cfg.spec.num_slots):
            raise InputError(f"anchors must have shape {(b, t, self.cfg.spec.num_slots)}, got {tuple(anchors.shape)}")
        if grad_frames is not None and not 1 <= grad_frames <= t:
            raise InputError(f"grad_frames must be in 1..{t} (the window's frames), got {grad_frames}")
        # frames ordered (time, batch) so each time step is one contiguous block
        x = images.transpose(0, 1).flatten(0, 1)
        a = None if anchors is None else anchors.transpose(0, 1).flatten(0, 1)
        skip = t - grad_frames if grad_frames is not None else 0  # warm-up frames: no gradients, no outputs
        warm = b * skip

        def part(sl: slice) -> tuple[SlotFeatures, torch.Tensor, torch.Tensor]:
            return self.frame_features(x[sl], None if a is None else a[sl])

        if warm:
            with torch.no_grad():
                f0, r0, a0 = part(slice(0, warm))
            f1, r1, a1 = part(slice(warm, None))
            feats, rows, a = f0.cat(f1), torch.cat([r0, r1]), torch.cat([a0, a1])
        else:
            feats, rows, a = part(slice(None))
        outs = self.decode_window([feats.select(t, i) for i in range(t)], skip)
        res = {v: torch.stack([o[v] for o in outs], 1) for v in VIEWS}
        extra = {"rows": rows, "anchors": a, "back": feats.back, "uprights": feats.uprights, "box_window": feats.window}
        # frame-major (T*B, ...) -> (B, T - skip, ...), as the views are stacked
        res.update({k: x.unflatten(0, (t, b)).transpose(0, 1)[:, skip:] for k, x in extra.items() if x is not None})
        return res

    def step(
        self,
        image: torch.Tensor,
        state: MemoryState | None = None,
        anchors: torch.Tensor | None = None,
        motion: torch.Tensor | None = None,
    ) -> tuple[dict[str, torch.Tensor], MemoryState | None]:
        """Streaming: one frame ``(B, 3, H, W)`` (anchors ``(B, R)`` or the row head's); outputs and the new state.

        ``motion`` ``(B,)``: the camera's step along the row since the previous frame, metres (+ =
        toward +X), from another source (odometry, ground truth); by default the aligned memory
        reads it from the images.
        """
        if motion is not None:
            motion = torch.as_tensor(motion, dtype=torch.float32, device=image.device).reshape(-1)
            if motion.shape[0] != image.shape[0] or not torch.isfinite(motion).all():
                raise InputError(f"motion must hold one finite step (metres) per image, got {motion.tolist()}")
        feats, rows, anchors = self.frame_features(image, anchors)
        if self.memory is not None:
            feats, state = self.memory.step(feats, state, motion)
        out = self.slots.finish(feats)
        out["rows"] = rows
        out["anchors"] = anchors
        out.update(head_outputs(feats))
        return out, state


def slot_maps(m: Any, p1: torch.Tensor, p2: torch.Tensor, anchors: torch.Tensor) -> tuple[torch.Tensor, ...]:
    """`SlotHeads.coarse` of ``m.slots`` as tensors ``(top, front, fine)``: the slot heads' part of a frame
    that `network.inference.frozen` runs as a graph."""
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


def build_discriminators(cfg: ModelConfig) -> nn.ModuleDict | None:
    """One patch discriminator per view, or None for variants without them."""
    if not cfg.use_disc:
        return None
    return nn.ModuleDict({v: PatchDiscriminator(cfg.spec.num_slots) for v in VIEWS})
