"""`LayoutSpec`: shelf slots, resolution and metric extents, and the one pixel<->metre mapping.

Geometry (see docs/conventions.md):

* Both views share the X axis: columns span ``x in [-x_extent/2, x_extent/2)`` around the
  shelf-centric origin (X = camera X), column 0 at the left (-X).
* Top view rows span ``z in (-z_extent/2, z_extent/2]`` about the rack's mid-depth;
  row 0 is the far side (+Z).
* Front view rows span the height above the shelf board ``h in (0, h_extent]``
  (``h = Y_board - Y`` since Y points down); row 0 is the top of the window.

Continuous pixel coordinates: pixel ``c`` covers ``[c, c+1)``, its centre is ``c + 0.5``.
Pixels may be anisotropic: each axis has its own metres-per-pixel.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, fields
from typing import Any

import numpy as np

from layouts.errors import LayoutError

VIEWS: tuple[str, str] = ("top", "front")

#: Bump when the meaning of the fields changes; older JSON is refused with a clear line.
SPEC_VERSION = 1


def check_view(view: str) -> str:
    """Return ``view`` if it is ``'top'`` or ``'front'``, else raise a one-line error."""
    if view not in VIEWS:
        raise LayoutError(f"view must be one of {VIEWS}, got {view!r}")
    return view


@dataclass(frozen=True)
class LayoutSpec:
    """What a layout array means: ``(num_slots, size, size)`` uint8 per view.

    Defaults match the default WareSynth camera (60 deg horizontal FOV at 2.3-2.9 m from the
    rack front): 3.0 m of row is the visible width at the rack front at 2.6 m.
    """

    num_slots: int = 3  #: R, shelf slots counted from the lowest visible shelf
    size: int = 128  #: D, pixels per side of every layout
    x_extent: float = 3.0  #: metres of rack row across the columns (both views)
    z_extent: float = 1.4  #: metres of depth across the top-view rows
    h_extent: float = 1.3  #: metres of height above the board across the front-view rows

    def __post_init__(self) -> None:
        for name in ("num_slots", "size"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1:
                raise LayoutError(f"LayoutSpec.{name} must be a positive integer, got {v!r}")
        if self.size > 4096:
            raise LayoutError(f"LayoutSpec.size must be <= 4096, got {self.size}")
        if self.num_slots > 16:
            raise LayoutError(f"LayoutSpec.num_slots must be <= 16, got {self.num_slots}")
        for name in ("x_extent", "z_extent", "h_extent"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float, np.floating, np.integer)):
                raise LayoutError(f"LayoutSpec.{name} must be a number, got {v!r}")
            if not math.isfinite(v) or v <= 0:
                raise LayoutError(f"LayoutSpec.{name} must be a positive finite number, got {v!r}")
            object.__setattr__(self, name, float(v))
        object.__setattr__(self, "num_slots", int(self.num_slots))
        object.__setattr__(self, "size", int(self.size))

    # ------------------------------------------------------------------ shapes
    @property
    def shape(self) -> tuple[int, int, int]:
        """Shape of one view's layout stack ``(R, D, D)``."""
        return (self.num_slots, self.size, self.size)

    def pixel_size(self, view: str) -> tuple[float, float]:
        """Metres per pixel ``(along X / columns, along the row axis)`` for ``view``."""
        check_view(view)
        row_extent = self.z_extent if view == "top" else self.h_extent
        return self.x_extent / self.size, row_extent / self.size

    def row_range(self, view: str) -> tuple[float, float]:
        """Metric range of the row axis: Z for top (about mid-depth), h above the board for front."""
        check_view(view)
        if view == "top":
            return -self.z_extent / 2, self.z_extent / 2
        return 0.0, self.h_extent

    @property
    def x_range(self) -> tuple[float, float]:
        """Metric range of the column axis (X about the camera)."""
        return -self.x_extent / 2, self.x_extent / 2

    # ------------------------------------------------- pixel <-> metre (the one place)
    def x_to_col(self, x: np.ndarray | float) -> np.ndarray:
        """Continuous column coordinate of metric X (pixel c covers [c, c+1))."""
        return (np.asarray(x, dtype=np.float64) + self.x_extent / 2) * (self.size / self.x_extent)

    def col_to_x(self, u: np.ndarray | float) -> np.ndarray:
        """Metric X of a continuous column coordinate (``c + 0.5`` is the centre of column c)."""
        return np.asarray(u, dtype=np.float64) * (self.x_extent / self.size) - self.x_extent / 2

    def a_to_row(self, view: str, a: np.ndarray | float) -> np.ndarray:
        """Continuous row coordinate of the row-axis metric value (Z for top, h for front)."""
        lo, hi = self.row_range(view)
        return (hi - np.asarray(a, dtype=np.float64)) * (self.size / (hi - lo))

    def row_to_a(self, view: str, v: np.ndarray | float) -> np.ndarray:
        """Row-axis metric value (Z for top, h above the board for front) of a row coordinate."""
        lo, hi = self.row_range(view)
        return hi - np.asarray(v, dtype=np.float64) * ((hi - lo) / self.size)

    def to_pixels(self, view: str, x: np.ndarray | float, a: np.ndarray | float):
        """Metric ``(x, a)`` -> continuous pixel ``(u, v)`` = (column, row)."""
        return self.x_to_col(x), self.a_to_row(view, a)

    def to_metres(self, view: str, u: np.ndarray | float, v: np.ndarray | float):
        """Continuous pixel ``(u, v)`` = (column, row) -> metric ``(x, a)``."""
        return self.col_to_x(u), self.row_to_a(view, v)

    def cell_centres(self, view: str) -> tuple[np.ndarray, np.ndarray]:
        """Metric centres of the columns (X) and rows (Z or h), each of length D."""
        c = np.arange(self.size) + 0.5
        return self.col_to_x(c), self.row_to_a(view, c)

    # ------------------------------------------------------------------ JSON
    def to_dict(self) -> dict[str, Any]:
        d: dict[str, Any] = {"version": SPEC_VERSION}
        d.update(asdict(self))
        return d

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), indent=2, sort_keys=True)

    @classmethod
    def from_dict(cls, d: Any, source: str = "LayoutSpec") -> LayoutSpec:
        """Build from a dict, refusing unknown keys or a different version (one-line error)."""
        if not isinstance(d, dict):
            raise LayoutError(f"{source}: layout spec must be a JSON object, got {type(d).__name__}")
        d = dict(d)
        version = d.pop("version", SPEC_VERSION)
        if version != SPEC_VERSION:
            raise LayoutError(f"{source}: layout spec version {version!r} is not supported (want {SPEC_VERSION})")
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(d) - known)
        if unknown:
            raise LayoutError(f"{source}: unknown layout spec keys {unknown}")
        try:
            return cls(**d)
        except LayoutError as e:
            raise LayoutError(f"{source}: {e}") from None

    @classmethod
    def from_json(cls, text: str, source: str = "LayoutSpec") -> LayoutSpec:
        from layouts.fileio import loads_json

        return cls.from_dict(loads_json(text, source), source)
