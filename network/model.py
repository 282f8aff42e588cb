"""The MVRackLay network: ResNet-18 encoder, stacked ConvLSTM, top/front decoders, discriminators.

Data flow per frame: image -> ResNet-18 (1/8, 1/16, 1/32 feature maps) -> the 1/32 map goes
through the stacked ConvLSTM (carrying context across the window) -> per view, a *column
transform* collapses each feature column's vertical axis into a new vertical axis (a learned
1x1 convolution over channels x rows, shared by all columns) -> an upsampling decoder with skip
connections from the 1/16 and 1/8 maps -> ``R x 3`` class logits at ``D x D``. Image columns
stay aligned with layout X throughout (nothing mixes columns except local convolutions), which
is what lets it train quickly; the vertical mapping (image rows -> depth or height above a
shelf board) is learned per view. With ``fine_skip`` (the default for new models) a fourth
column transform brings in the 1/4 map, which sharpens box edges along X. With
``temporal_residual`` (also the default) the ConvLSTM adds a zero-initialised correction to the
single-frame block, so a sequence model can start from trained ``racklay`` weights.

Variants (`VARIANTS`): ``mvracklay-disc-4`` (default), ``mvracklay-disc-8``, ``mvracklay-4``
(no discriminators) and ``racklay`` (single frame, a plain convolution in place of the ConvLSTM).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, replace
from typing import Any

import torch
import torch.nn.functional as F
from torch import nn

from layouts import NUM_CLASSES, VIEWS, LayoutSpec
from layouts.errors import InputError
from network.convlstm import ResidualConvLSTM, StackedConvLSTM, State
from network.resnet import ResNet18Encoder

#: variant -> (sequence length, uses the ConvLSTM, uses discriminators)
VARIANTS: dict[str, tuple[int, bool, bool]] = {
    "mvracklay-disc-4": (4, True, True),
    "mvracklay-disc-8": (8, True, True),
    "mvracklay-4": (4, True, False),
    "racklay": (1, False, True),
}
DEFAULT_VARIANT = "mvracklay-disc-4"

IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)


@dataclass(frozen=True)
class ModelConfig:
    """Everything needed to rebuild a model: variant, input size, layout spec and widths."""

    variant: str = DEFAULT_VARIANT
    input_width: int = 128
    input_height: int = 128
    spec: LayoutSpec = field(default_factory=lambda: LayoutSpec(size=64))
    encoder_width: int = 32  #: ResNet-18 base width (64 = standard, needed for ImageNet weights)
    hidden: int = 128  #: ConvLSTM channels
    lstm_layers: int = 2
    decoder_width: int = 32
    fine_skip: bool = True  #: also feed the 1/4 encoder map to the decoders (sharper box edges)
    temporal_residual: bool = True  #: ConvLSTM as a zero-initialised correction to the single-frame block

    def __post_init__(self) -> None:
        if self.variant not in VARIANTS:
            raise InputError(f"unknown variant {self.variant!r}; choose from {sorted(VARIANTS)}")
        for name in ("input_width", "input_height"):
            v = getattr(self, name)
            if not isinstance(v, int) or v < 32 or v % 32:
                raise InputError(f"{name} must be a positive multiple of 32, got {v!r}")
        for name in ("encoder_width", "hidden", "lstm_layers", "decoder_width"):
            v = getattr(self, name)
            if not isinstance(v, int) or v < 1:
                raise InputError(f"{name} must be a positive integer, got {v!r}")
        for name in ("fine_skip", "temporal_residual"):
            if not isinstance(getattr(self, name), bool):
                raise InputError(f"{name} must be true or false, got {getattr(self, name)!r}")
        if not isinstance(self.spec, LayoutSpec):
            raise InputError(f"spec must be a LayoutSpec, got {type(self.spec).__name__}")
        if not self.use_lstm:  # no ConvLSTM, nothing to be residual: one spelling, so configs compare equal
            object.__setattr__(self, "temporal_residual", False)

    @property
    def seq_len(self) -> int:
        return VARIANTS[self.variant][0]

    @property
    def use_lstm(self) -> bool:
        return VARIANTS[self.variant][1]

    @property
    def use_disc(self) -> bool:
        return VARIANTS[self.variant][2]

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["spec"] = self.spec.to_dict()
        return d

    @classmethod
    def from_dict(cls, d: Any, source: str = "model config") -> ModelConfig:
        if not isinstance(d, dict):
            raise InputError(f"{source}: model config must be a JSON object")
        d = dict(d)
        known = set(cls.__dataclass_fields__)
        unknown = sorted(set(d) - known)
        if unknown:
            raise InputError(f"{source}: unknown model config keys {unknown}")
        if "spec" in d:
            d["spec"] = LayoutSpec.from_dict(d["spec"], f"{source} (spec)")
        d.setdefault("fine_skip", False)  # records written before the 1/4 skip existed
        d.setdefault("temporal_residual", False)  # ... and before the residual ConvLSTM
        try:
            return cls(**d)
        except (TypeError, InputError) as e:
            raise InputError(f"{source}: {e}") from None

    def with_variant(self, variant: str) -> ModelConfig:
        return replace(self, variant=variant)


def _conv_bn_relu(cin: int, cout: int, k: int = 3) -> nn.Sequential:
    return nn.Sequential(nn.Conv2d(cin, cout, k, padding=k // 2, bias=False), nn.BatchNorm2d(cout), nn.ReLU(True))


class ColumnTransform(nn.Module):
    """``(N, C, h, w) -> (N, cout, rows, w)``: per image column, channels x rows -> cout x rows'.

    A 1x1 convolution on the column-stacked features: every column gets the same learned
    mapping from image rows to layout rows, and columns never mix (X stays aligned).
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


#: Encoder features of a batch of frames: the 1/4, 1/8 and 1/16 maps and the reduced 1/32 map.
Features = tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]


class ViewDecoder(nn.Module):
    """One view's decoder: column transforms of three (four with ``fine_skip``) scales, upsampling,
    ``R x 3`` logits at D x D."""

    def __init__(self, cfg: ModelConfig, c2: int, c3: int, c4: int) -> None:
        super().__init__()
        h, w = cfg.input_height, cfg.input_width
        w5 = w // 32
        dw = cfg.decoder_width
        self.t5 = ColumnTransform(cfg.hidden, h // 32, 4 * dw, w5)
        self.t4 = ColumnTransform(c4, h // 16, 2 * dw, 2 * w5)
        self.t3 = ColumnTransform(c3, h // 8, dw, 4 * w5)
        fine = max(dw // 2, 1)
        self.t2 = ColumnTransform(c2, h // 4, fine, 8 * w5) if cfg.fine_skip else None
        self.b4 = _conv_bn_relu(6 * dw, 2 * dw)
        self.b3 = _conv_bn_relu(3 * dw, dw)
        self.b2 = _conv_bn_relu(dw + (fine if cfg.fine_skip else 0), dw)
        self.b1 = _conv_bn_relu(dw, dw)
        self.out = nn.Conv2d(dw, cfg.spec.num_slots * NUM_CLASSES, 1)
        self.size = cfg.spec.size
        self.slots = cfg.spec.num_slots

    def forward(self, feats: Features) -> torch.Tensor:
        f2, f3, f4, f5 = feats
        up = lambda t: F.interpolate(t, scale_factor=2.0, mode="nearest")  # noqa: E731
        x = self.t5(f5)
        x = self.b4(torch.cat([up(x), self.t4(f4)], 1))
        x = self.b3(torch.cat([up(x), self.t3(f3)], 1))
        x = up(x)
        if self.t2 is not None:
            x = torch.cat([x, self.t2(f2)], 1)
        x = self.b1(up(self.b2(x)))
        x = self.out(x)
        if x.shape[-1] != self.size or x.shape[-2] != self.size:
            x = F.interpolate(x, size=(self.size, self.size), mode="bilinear", align_corners=False)
        return x.reshape(x.shape[0], self.slots, NUM_CLASSES, self.size, self.size)


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
    """Encoder + (Conv)LSTM temporal block + one decoder per view.

    `forward` takes a window ``(B, T, 3, H, W)`` of float images in [0, 1] and returns
    ``{"top": (B, T, R, 3, D, D), "front": ...}`` logits for every frame of the window.
    `step` is the streaming form: one frame in, its logits and the carried state out.
    """

    def __init__(self, cfg: ModelConfig) -> None:
        super().__init__()
        self.cfg = cfg
        self.encoder = ResNet18Encoder(cfg.encoder_width)
        c2, c3, c4, c5 = self.encoder.channels
        self.reduce = _conv_bn_relu(c5, cfg.hidden, 1)
        if cfg.use_lstm and cfg.temporal_residual:
            pre = _conv_bn_relu(cfg.hidden, cfg.hidden)
            self.temporal: nn.Module = ResidualConvLSTM(pre, cfg.hidden, cfg.lstm_layers)
        elif cfg.use_lstm:
            self.temporal = StackedConvLSTM(cfg.hidden, cfg.hidden, cfg.lstm_layers)
        else:
            self.temporal = _conv_bn_relu(cfg.hidden, cfg.hidden)
        self.decoders = nn.ModuleDict({v: ViewDecoder(cfg, c2, c3, c4) for v in VIEWS})
        self.register_buffer("mean", torch.tensor(IMAGENET_MEAN).view(1, 3, 1, 1), persistent=False)
        self.register_buffer("std", torch.tensor(IMAGENET_STD).view(1, 3, 1, 1), persistent=False)

    def _check(self, x: torch.Tensor) -> None:
        h, w = x.shape[-2:]
        if (h, w) != (self.cfg.input_height, self.cfg.input_width):
            raise InputError(f"model expects images of {self.cfg.input_width}x{self.cfg.input_height}, got {w}x{h}")

    def encode(self, x: torch.Tensor) -> Features:
        """Encoder features of frames ``(N, 3, H, W)``: (1/4, 1/8, 1/16, reduced 1/32)."""
        self._check(x)
        f2, f3, f4, f5 = self.encoder((x - self.mean) / self.std)
        return f2, f3, f4, self.reduce(f5)

    def decode(self, feats: Features) -> dict[str, torch.Tensor]:
        """Per-view logits from encoder features whose 1/32 map has passed the temporal block."""
        return {v: self.decoders[v](feats) for v in VIEWS}

    def temporal_window(self, f5: torch.Tensor) -> torch.Tensor:
        """The temporal block over a window ``(B, T, C, h, w)`` of reduced 1/32 maps, same shape out."""
        if self.cfg.use_lstm:
            return self.temporal(f5)[0]
        return self.temporal(f5.flatten(0, 1)).unflatten(0, f5.shape[:2])

    def forward(self, images: torch.Tensor) -> dict[str, torch.Tensor]:
        if images.ndim != 5:
            raise InputError(f"expected a window (B, T, 3, H, W), got shape {tuple(images.shape)}")
        b, t = images.shape[:2]
        f2, f3, f4, f5 = self.encode(images.flatten(0, 1))
        f5 = self.temporal_window(f5.unflatten(0, (b, t))).flatten(0, 1)
        out = self.decode((f2, f3, f4, f5))
        return {v: o.unflatten(0, (b, t)) for v, o in out.items()}

    def step(self, image: torch.Tensor, state: State | None = None) -> tuple[dict[str, torch.Tensor], State | None]:
        """Streaming: one frame ``(B, 3, H, W)``; returns ``{view: (B, R, 3, D, D)}`` and the new state."""
        f2, f3, f4, f5 = self.encode(image)
        if self.cfg.use_lstm:
            f5, state = self.temporal.step(f5, state)
        else:
            f5 = self.temporal(f5)
        return self.decode((f2, f3, f4, f5)), state


def build_discriminators(cfg: ModelConfig) -> nn.ModuleDict | None:
    """One patch discriminator per view, or None for variants without them."""
    if not cfg.use_disc:
        return None
    return nn.ModuleDict({v: PatchDiscriminator(cfg.spec.num_slots) for v in VIEWS})
