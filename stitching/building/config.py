"""The building's tuning in one place, as `stitching.pipeline.StitchConfig` holds the row stitcher's: how passes
are placed and registered on their faces (`PlaceConfig`, `stitching.building.place`) and how they are fused into
bays, levels, boxes and locations (`FuseConfig`, `stitching.building.fuse_passes`)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields

from layouts.errors import InputError


def _check_numbers(cfg: object) -> None:
    """Every field of ``cfg`` a finite number >= 0 (one line naming the class and the field otherwise)."""
    for f in fields(cfg):  # type: ignore[arg-type]
        v = getattr(cfg, f.name)
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0:
            raise InputError(f"{type(cfg).__name__}.{f.name} must be a finite number >= 0, got {v!r}")


@dataclass(frozen=True)
class PlaceConfig:
    """Placing a pass by its route pose and registering the passes of a face where they overlap."""

    max_heading_off: float = 45.0  #: degrees a pass's heading may be off its face's (90 for R, -90 for L)
    max_shift: float = 1.2  #: metres an overlap's shift is searched within
    match_tol: float = 0.08  #: metres two features count as the same after a shift
    margin: float = 0.3  #: metres of each pass's view edge left out of an overlap (boxes seen there may be cut)
    min_matches: int = 3  #: features an overlap's shift must lay on each other to count
    outlier: float = 0.15  #: metres an overlap's shift may disagree with the solution before it is dropped
    route_sigma: float = 0.3  #: metres the route's pose is trusted to (0.05 at least)
    anchor_sigma: float = 0.05  #: metres a face end seen past is trusted to
    edge_sigma: float = 0.03  #: metres an overlap of one matching feature is trusted to (more: sqrt(matches) closer)

    def __post_init__(self) -> None:
        _check_numbers(self)


@dataclass(frozen=True)
class FuseConfig:
    """Fusing a face's registered passes: one rack per bay, one shelf per location, each box once."""

    same_rack: float = 0.5  #: overlap / shorter length above which two passes' racks are one bay
    same_box: float = 0.5  #: X overlap / narrower width above which two passes' boxes are one
    #: X overlap / narrower width above which a box reaching into a better seen one is dropped (boxes stand side by
    #: side on a level, never into each other: such a box is a copy placed off, or a piece of its neighbour)
    ghost: float = 0.3
    long_bay: float = 1.8  #: a bay this many times the face's typical length is bays run together
    split_margin: float = 0.4  #: metres a gap must lie inside another pass's rack to cut it there
    default_clear: float = 0.8  #: clear height (m) of a level nobody saw and the plan does not give
    whole_view: float = 0.95  #: share of a location a pass must hold in view for its count of it to be compared

    def __post_init__(self) -> None:
        _check_numbers(self)


@dataclass(frozen=True)
class BuildingConfig:
    """All building settings in one place (`stitching.building.pipeline.build_map`)."""

    place: PlaceConfig = field(default_factory=PlaceConfig)
    fuse: FuseConfig = field(default_factory=FuseConfig)

    def __post_init__(self) -> None:
        for name, kind in (("place", PlaceConfig), ("fuse", FuseConfig)):
            if not isinstance(getattr(self, name), kind):
                raise InputError(
                    f"BuildingConfig.{name} must be a {kind.__name__}, got {type(getattr(self, name)).__name__}"
                )
