"""The layouts contract: spec, class ids, pixel<->metre conversion, rasterising, codecs, metrics.

Every other component (waresynth, network, stitching) agrees on what is defined here
and nowhere else. See docs/conventions.md.
"""

from layouts.camera import Intrinsics
from layouts.classes import BACKGROUND, BOX, CLASS_COLOURS, CLASS_NAMES, NUM_CLASSES, SHELF
from layouts.errors import InputError, LayoutError
from layouts.spec import VIEWS, LayoutSpec

__all__ = [
    "BACKGROUND",
    "BOX",
    "CLASS_COLOURS",
    "CLASS_NAMES",
    "NUM_CLASSES",
    "SHELF",
    "VIEWS",
    "Intrinsics",
    "InputError",
    "LayoutError",
    "LayoutSpec",
]
