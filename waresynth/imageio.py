"""PNG encode/decode for the dataset's images (deterministic bytes, low compression for speed)."""

from __future__ import annotations

import os
import struct
import zlib
from pathlib import Path

import numpy as np
from PIL import Image, UnidentifiedImageError

from layouts.errors import InputError
from layouts.fileio import atomic_write_bytes
from layouts.images import rgb8

PNG_COMPRESS_LEVEL = 1
_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def _chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)


def png_bytes(arr: np.ndarray) -> bytes:
    """PNG bytes of a uint8 (H, W) / (H, W, 3) or uint16 (H, W) array.

    A small dedicated encoder: every row uses PNG's "Up" filter and zlib level 1 with run-length
    matching, which is several times faster than a general encoder at similar size. No
    metadata chunks, so the same array always gives the same bytes.
    """
    if arr.dtype == np.uint8 and arr.ndim == 3 and arr.shape[2] == 3:
        colour_type, depth, rows = 2, 8, arr.reshape(arr.shape[0], -1)
    elif arr.dtype == np.uint8 and arr.ndim == 2:
        colour_type, depth, rows = 0, 8, arr
    elif arr.dtype == np.uint16 and arr.ndim == 2:
        colour_type, depth, rows = 0, 16, arr.astype(">u2").view(np.uint8).reshape(arr.shape[0], -1)
    else:
        raise ValueError(f"png_bytes: unsupported array {arr.dtype} {arr.shape}")
    h, w = arr.shape[:2]
    if h == 0 or w == 0:
        raise ValueError("png_bytes: empty image")
    buf = np.empty((h, rows.shape[1] + 1), np.uint8)
    buf[:, 0] = 2  # Up filter
    buf[0, 1:] = rows[0]
    np.subtract(rows[1:], rows[:-1], out=buf[1:, 1:])
    comp = zlib.compressobj(PNG_COMPRESS_LEVEL, zlib.DEFLATED, 15, 9, zlib.Z_RLE)
    data = comp.compress(buf.tobytes()) + comp.flush()
    ihdr = struct.pack(">IIBBBBB", w, h, depth, colour_type, 0, 0, 0)
    return _SIGNATURE + _chunk(b"IHDR", ihdr) + _chunk(b"IDAT", data) + _chunk(b"IEND", b"")


def write_png(path: str | os.PathLike, arr: np.ndarray) -> None:
    atomic_write_bytes(path, png_bytes(arr))


def read_png(path: str | os.PathLike, dtype: type, channels: int | None = None) -> np.ndarray:
    """Read a PNG as ``dtype``; a missing or unreadable file (or wrong kind) gives one line naming it."""
    path = Path(path)
    try:
        with Image.open(path) as im:
            im.load()
            arr = rgb8(im, path) if dtype == np.uint8 and channels == 3 else np.asarray(im)
    except FileNotFoundError:
        raise InputError(f"{path}: file not found") from None
    except (UnidentifiedImageError, OSError, SyntaxError) as e:
        raise InputError(f"{path}: not a readable PNG ({e})") from None
    if arr.dtype != dtype:
        if dtype == np.uint16 and arr.dtype in (np.int32, np.uint8):
            arr = arr.astype(np.uint16)
        else:
            raise InputError(f"{path}: expected a {np.dtype(dtype).name} image, found {arr.dtype}")
    if channels is None and arr.ndim != 2:
        raise InputError(f"{path}: expected a single-channel image, found shape {arr.shape}")
    return arr


def read_rgb(path: str | os.PathLike) -> np.ndarray:
    """Any image file Pillow reads (PNG, JPEG, ...) as uint8 ``(H, W, 3)``; one-line `InputError` naming
    the file when it is missing or unreadable."""
    from PIL import Image, UnidentifiedImageError

    from layouts.errors import InputError

    try:
        with Image.open(path) as im:
            return rgb8(im, path)
    except FileNotFoundError:
        raise InputError(f"{path}: file not found") from None
    except (UnidentifiedImageError, OSError) as e:
        raise InputError(f"{path}: not a readable image ({e})") from None
