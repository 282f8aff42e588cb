"""What a model is: `ModelConfig` (variant, canonical input size, layout spec, widths, heads) and `VARIANTS`.

A checkpoint's record carries the config (`ModelConfig.to_dict`); `ModelConfig.from_dict` reads records of
earlier versions too (options they name that this version no longer has, `RETIRED_FLAGS`, load when off).
Variants: ``mvracklay-disc-4`` (default), ``mvracklay-disc-8``, ``mvracklay-4`` (no discriminators) and
``racklay`` (single frame, no ConvLSTM).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, replace
from typing import Any

from layouts import LayoutSpec
from layouts.canonical import CanonicalView
from layouts.errors import InputError
from network.heads.boxdepth import BOX_WIDTH

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
