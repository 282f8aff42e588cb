"""Pinhole intrinsics shared by the generator, the network and the pipeline."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from layouts.errors import LayoutError
from layouts.spec import LayoutSpec

#: the fields of view (degrees, each way) a pinhole camera may have: a focal length beyond them is a typo or a unit
#: mistake (1e308, 1e-300), not a lens
FOV_RANGE_DEG = (0.1, 179.0)


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole camera: focal lengths and principal point in pixels, image size in pixels.

    The camera frame is X right, Y down, Z forward (DESIGN.md).
    """

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int

    def __post_init__(self) -> None:
        for name in ("fx", "fy", "cx", "cy"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float, np.floating, np.integer)) or not math.isfinite(v):
                raise LayoutError(f"Intrinsics.{name} must be a finite number, got {v!r}")
            object.__setattr__(self, name, float(v))
        if self.fx <= 0 or self.fy <= 0:
            raise LayoutError(f"Intrinsics focal lengths must be positive, got fx={self.fx}, fy={self.fy}")
        for name in ("width", "height"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or not 1 <= v <= 16384:
                raise LayoutError(f"Intrinsics.{name} must be an integer in [1, 16384], got {v!r}")
            object.__setattr__(self, name, int(v))
        self._check_physical()

    def _check_physical(self) -> None:
        """The range check of a camera, wherever it comes from (a ``--camera`` file or option, a meta.json, a
        checkpoint's record, the API): each field of view within `FOV_RANGE_DEG` and the principal point inside
        the image; anything else describes no camera and only yields divisions by zero or empty views later."""
        low, high = FOV_RANGE_DEG
        for f, size, name, way in (("fx", self.width, "horizontal", "wide"), ("fy", self.height, "vertical", "high")):
            fov = math.degrees(2 * math.atan(size / (2 * getattr(self, f))))
            if not low <= fov <= high:
                raise LayoutError(
                    f"{f} = {getattr(self, f):g} gives a {name} field of view of {fov:.3g} deg for an image {size} "
                    f"pixels {way}; a camera's lies within [{low:g}, {high:g}] deg"
                )
        for c, size, way in (("cx", self.width, "wide"), ("cy", self.height, "high")):
            if not 0.0 <= getattr(self, c) <= size:
                raise LayoutError(f"{c} = {getattr(self, c):g} is outside the image ({size} pixels {way})")

    @classmethod
    def from_fov(cls, width: int, height: int, hfov_deg: float) -> Intrinsics:
        """Square pixels, centred principal point, horizontal field of view in degrees."""
        if not 1.0 <= hfov_deg <= 170.0:
            raise LayoutError(f"hfov_deg must be in [1, 170], got {hfov_deg}")
        fx = (width / 2) / math.tan(math.radians(hfov_deg) / 2)
        return cls(fx, fx, width / 2, height / 2, width, height)

    @property
    def hfov_deg(self) -> float:
        return math.degrees(2 * math.atan(self.width / (2 * self.fx)))

    @property
    def matrix(self) -> np.ndarray:
        return np.array([[self.fx, 0, self.cx], [0, self.fy, self.cy], [0, 0, 1]], dtype=np.float64)

    def scaled(self, width: int, height: int) -> Intrinsics:
        """The same camera with the image resized to ``width x height``."""
        sx, sy = width / self.width, height / self.height
        return Intrinsics(self.fx * sx, self.fy * sy, self.cx * sx, self.cy * sy, width, height)

    def project(self, points_cam: np.ndarray) -> np.ndarray:
        """Project ``(N, 3)`` camera-frame points to ``(N, 2)`` pixel coordinates (u right, v down)."""
        p = np.asarray(points_cam, dtype=np.float64)
        z = p[:, 2]
        return np.stack([self.fx * p[:, 0] / z + self.cx, self.fy * p[:, 1] / z + self.cy], axis=1)

    def level_depth(self, depth: np.ndarray, rotation: np.ndarray) -> np.ndarray:
        """A rotated camera's Z-depth image ``(H, W)`` (metres, 0 = no hit) as distances along the level
        camera's axis (world Z from the camera): what a level camera's depth compares with planes of
        constant Z. ``rotation``: the camera's frame in the level one's (`layouts.canonical.camera_rotation`)."""
        depth = np.asarray(depth, np.float32)
        if depth.shape != (self.height, self.width):
            raise LayoutError(f"depth image {depth.shape} does not match the camera's {self.height}x{self.width}")
        r = np.asarray(rotation, np.float64)[2]
        x = (np.arange(self.width) + 0.5 - self.cx) / self.fx
        y = (np.arange(self.height) + 0.5 - self.cy) / self.fy
        return depth * (r[0] * x[None, :] + r[1] * y[:, None] + r[2]).astype(np.float32)

    def visible_columns(self, spec: LayoutSpec, distance: float) -> np.ndarray:
        """Boolean ``(D,)``: layout columns whose centre is in view at ``distance`` metres ahead.

        Pass the camera-to-rack-front distance: a column counts as visible when the rack front
        at that X projects inside the image (conservative: the far side of a shelf sees more).
        """
        if not math.isfinite(distance) or distance <= 0:
            raise LayoutError(f"distance must be a positive finite number of metres, got {distance!r}")
        xs, _ = spec.cell_centres("top")
        u = self.fx * xs / distance + self.cx
        return (u >= 0) & (u < self.width)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: Any, source: str = "intrinsics") -> Intrinsics:
        if not isinstance(d, dict):
            raise LayoutError(f"{source}: intrinsics must be a JSON object with fx, fy, cx, cy, width, height")
        missing = [k for k in ("fx", "fy", "cx", "cy", "width", "height") if k not in d]
        if missing:
            raise LayoutError(f"{source}: intrinsics lack {missing}")
        try:
            return cls(**{k: d[k] for k in ("fx", "fy", "cx", "cy", "width", "height")})
        except LayoutError as e:
            raise LayoutError(f"{source}: {e}") from None
