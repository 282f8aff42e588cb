"""How a frame image is read as RGB: the one place that turns an opened image of any mode into uint8 RGB, or
refuses it in one line (so that no reader misreads 16-bit, palette, alpha or CMYK frames)."""

from __future__ import annotations

import os

import numpy as np
from PIL import Image

from layouts.errors import InputError

#: image modes read as 8-bit RGB as they are (YCbCr: a JPEG's; "1": black and white)
_AS_RGB = frozenset({"RGB", "L", "P", "1", "YCbCr"})
#: 16-bit greyscale modes (a 16-bit PNG's); "I" counts as one when the file is a PNG
_GREY16 = frozenset({"I;16", "I;16L", "I;16B", "I;16N"})


def rgb8(im: Image.Image, source: str | os.PathLike) -> np.ndarray:
    """An opened image as uint8 ``(H, W, 3)`` RGB, read faithfully or refused in one line naming ``source``.

    8-bit RGB, greyscale, palette and black-and-white images are converted as Pillow does. 16-bit greyscale
    (a 16-bit PNG) is scaled to 8 bits as ``round(v / 257)`` (65535 -> 255, and an 8-bit image saved as
    16-bit, ``v * 257``, reads back as it was); 16-bit RGB PNGs reach here as 8-bit (Pillow keeps each
    channel's high byte). Alpha (RGBA, LA, PA, a palette's transparency) is dropped when every pixel is
    opaque, and refused otherwise (what lies behind a transparent pixel is unknown). CMYK, float and other
    modes are refused: converting them needs a colour profile we do not have."""
    mode = im.mode
    if mode in _GREY16 or (mode == "I" and (im.format or "").upper() == "PNG"):
        v = np.asarray(im).astype(np.float64)
        if v.size and (v.min() < 0 or v.max() > 65535):
            raise InputError(f"{source}: {mode} image with values outside 0..65535; give 8-bit RGB frames")
        grey = np.rint(v / 257.0).astype(np.uint8)
        return np.repeat(grey[..., None], 3, axis=2)
    if mode == "P" and "transparency" in im.info:
        im, mode = im.convert("RGBA"), "RGBA"
    if mode in ("RGBA", "LA", "PA", "RGBa", "La"):
        alpha = np.asarray(im.getchannel("A"))
        if alpha.size and alpha.min() < 255:
            raise InputError(
                f"{source}: has transparent pixels ({mode}); give opaque frames (RGB, or alpha 255 everywhere)"
            )
        return np.asarray(im.convert("RGB"))
    if mode not in _AS_RGB:
        raise InputError(f"{source}: {mode} image, not read faithfully as RGB; convert the frames to 8-bit RGB")
    return np.asarray(im if mode == "RGB" else im.convert("RGB"))
