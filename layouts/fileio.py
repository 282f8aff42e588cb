"""Atomic writes and safe loads: the only place files are written or numpy files read.

Writes go to a temporary file in the same folder, are flushed and fsync'ed, then renamed over
the target, so a crash never leaves a half-written file under the final name. Loads never
unpickle (``allow_pickle=False``) and turn any failure into a one-line ``LayoutError``.
"""

from __future__ import annotations

import io
import json
import math
import os
import tempfile
import zipfile
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np

from layouts.errors import LayoutError


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def user_cache_dir(*parts: str) -> Path | None:
    """``$XDG_CACHE_HOME/mvracklay/PARTS``, else ``~/.cache/mvracklay/PARTS``: where the toolkit keeps what it
    makes for itself outside a work tree (ONNX parts, recipe runs); None with no home folder to find."""
    try:
        base = os.environ.get("XDG_CACHE_HOME", "").strip() or Path.home() / ".cache"
    except RuntimeError:
        return None
    return Path(base).joinpath("mvracklay", *parts)


def atomic_write_bytes(path: str | os.PathLike, data: bytes, fsync: bool = False) -> None:
    """Write ``data`` to ``path`` atomically (temp file + rename in the same folder)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            if fsync:
                f.flush()
                os.fsync(f.fileno())
        os.chmod(tmp, 0o666 & ~_umask())  # mkstemp makes 0600; give the file normal permissions
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        raise


def atomic_write_text(path: str | os.PathLike, text: str, fsync: bool = False) -> None:
    atomic_write_bytes(path, text.encode("utf-8"), fsync=fsync)


def atomic_write_json(path: str | os.PathLike, obj: Any, fsync: bool = False) -> None:
    """JSON with sorted keys and a trailing newline, so equal objects give equal bytes."""
    atomic_write_text(path, json.dumps(obj, indent=2, sort_keys=True) + "\n", fsync=fsync)


def npy_bytes(arr: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, np.ascontiguousarray(arr), allow_pickle=False)
    return buf.getvalue()


def npz_bytes(compressed: bool = True, **arrays: np.ndarray) -> bytes:
    """Deterministic ``.npz`` bytes (fixed zip timestamps, so same arrays -> same bytes)."""
    buf = io.BytesIO()
    mode = zipfile.ZIP_DEFLATED if compressed else zipfile.ZIP_STORED
    with zipfile.ZipFile(buf, "w", compression=mode, compresslevel=1 if compressed else None) as zf:
        for name in sorted(arrays):
            info = zipfile.ZipInfo(f"{name}.npy", date_time=(1980, 1, 1, 0, 0, 0))
            info.compress_type = mode
            zf.writestr(info, npy_bytes(arrays[name]))
    return buf.getvalue()


def atomic_save_npy(path: str | os.PathLike, arr: np.ndarray) -> None:
    atomic_write_bytes(path, npy_bytes(arr))


def atomic_save_npz(path: str | os.PathLike, compressed: bool = True, **arrays: np.ndarray) -> None:
    atomic_write_bytes(path, npz_bytes(compressed, **arrays))


def nan_to_null(obj: Any) -> Any:
    """A copy of nested dicts/lists with NaN floats as None, so JSON stays standard (NaN = mean over nothing)."""
    if isinstance(obj, dict):
        return {k: nan_to_null(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [nan_to_null(v) for v in obj]
    if isinstance(obj, float) and obj != obj:
        return None
    return obj


def _not_numpy(path: Path, want: str) -> None:
    """Refuse, in words, a file that is not ``want`` (".npy array" or ".npz archive") before `np.load` reads it
    (it takes any bytes it does not know for a pickle): a folder, an empty file, the other NumPy format, text or
    other bytes. A real pickle is left to the loader, which refuses it as one."""
    if path.is_dir():
        raise LayoutError(f"{path}: is a folder, not a {want}")
    try:
        with open(path, "rb") as f:
            head = f.read(6)
    except FileNotFoundError:
        raise LayoutError(f"{path}: file not found") from None
    except OSError as e:
        raise LayoutError(f"{path}: cannot be read ({e.strerror or type(e).__name__})") from None
    found = (
        ".npz archive" if head.startswith((b"PK\x03\x04", b"PK\x05\x06")) else
        ".npy array" if head.startswith(b"\x93NUMPY") else
        want if head.startswith(b"\x80") else None
    )  # fmt: skip
    if not head:
        raise LayoutError(f"{path}: an empty file, not a {want}")
    if found is None:
        raise LayoutError(f"{path}: not a {want} (its first bytes are no NumPy format's)")
    if found != want:
        raise LayoutError(f"{path}: expected a {want}, found a {found}")


@contextmanager
def _numpy_errors(path: Path, want: str) -> Iterator[None]:
    """What `np.load` raises on ``path`` as one line naming the file (a pickle refused as one)."""
    try:
        yield
    except LayoutError:
        raise
    except FileNotFoundError:
        raise LayoutError(f"{path}: file not found") from None
    except ValueError as e:
        if "pickle" in str(e).lower():
            raise LayoutError(f"{path}: holds pickled objects, refused (only plain arrays are read)") from None
        raise LayoutError(f"{path}: not a readable {want} ({e})") from None
    except (OSError, EOFError, zipfile.BadZipFile, KeyError) as e:
        raise LayoutError(f"{path}: not a readable {want} ({e})") from None


def load_npy(path: str | os.PathLike) -> np.ndarray:
    """Load a ``.npy`` without pickle; any problem becomes one line naming the file."""
    path = Path(path)
    _not_numpy(path, ".npy array")
    with _numpy_errors(path, ".npy array"):
        arr = np.load(path, allow_pickle=False)
    if not isinstance(arr, np.ndarray):
        raise LayoutError(f"{path}: expected a .npy array, found an archive")
    return arr


def load_npz(path: str | os.PathLike, keys: tuple[str, ...] | None = None) -> dict[str, np.ndarray]:
    """Load an ``.npz`` without pickle into a dict; ``keys`` must all be present."""
    path = Path(path)
    _not_numpy(path, ".npz archive")
    with _numpy_errors(path, ".npz archive"), np.load(path, allow_pickle=False) as z:
        if not hasattr(z, "files"):
            raise LayoutError(f"{path}: expected an .npz archive, found a plain array")
        out = {k: z[k] for k in z.files}
    if keys:
        missing = [k for k in keys if k not in out]
        if missing:
            raise LayoutError(f"{path}: missing arrays {missing}")
    return out


def finite_float(text: str) -> float:
    """A number as written, refused when it lies beyond a float's range (``1e400`` would read as infinity)."""
    v = float(text)
    if not math.isfinite(v):
        raise ValueError(f"number {text[:20]} is out of range (beyond a float's)")
    return v


def _parsed(load: Callable[..., Any], text: str, source: str, kind: str, malformed: type[Exception], said: str) -> Any:
    """``load(text)`` with finite floats only (`finite_float`): malformed text (``said``, ``{e}`` the parser's
    words), nesting too deep to read or a number out of range each one line naming ``source``."""
    try:
        return load(text, parse_float=finite_float)
    except malformed as e:
        raise LayoutError(f"{source}: {said.format(e=e)}") from None
    except RecursionError:
        raise LayoutError(f"{source}: not readable {kind} (nested too deep)") from None
    except ValueError as e:  # a number out of range, or an integer of more digits than Python converts
        raise LayoutError(f"{source}: not readable {kind} ({e})") from None


def loads_json(text: str, source: str) -> Any:
    """Parse JSON a user gave (a map, a camera, a config, a meta.json): malformed text, nesting too deep to
    read, or a number beyond a float's range (1e400) each become one line naming ``source``. The literals
    ``NaN`` / ``Infinity`` (Python's own JSON writes them) parse; each format's schema says where they may be."""
    return _parsed(json.loads, text, source, "JSON", json.JSONDecodeError, "not valid JSON ({e})")


def loads_toml(text: str, source: str) -> dict[str, Any]:
    """Parse TOML a user gave (a recipe, a config): one line naming ``source`` for malformed text, nesting too
    deep, or a number that is not finite (``inf``, ``nan``, ``1e400``)."""
    import tomllib

    return _parsed(tomllib.loads, text, source, "TOML", tomllib.TOMLDecodeError, "not TOML: {e}")


def load_json(path: str | os.PathLike) -> Any:
    """Read JSON (`loads_json`); a missing, unreadable or malformed file becomes one line naming the file."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise LayoutError(f"{path}: file not found") from None
    except UnicodeDecodeError as e:
        raise LayoutError(f"{path}: not valid JSON ({e})") from None
    except OSError as e:
        raise LayoutError(f"{path}: cannot read ({e.strerror})") from None
    return loads_json(text, str(path))
