"""Route and row maps -> building map, in one call:

>>> bmap = build_map(load_route("route.json"), maps)      # doctest: +SKIP
>>> bmap.save("building.json")                           # doctest: +SKIP

``maps``: each pass's row map (`stitching.warehouse_map.WarehouseMap`, as `stitching.pipeline.reconstruct` makes
it) by the pass's ``sequence``. Each pass is placed by its route pose, the passes of a face are registered where they
overlap (`stitching.building.place`) and all are fused into one map of every face (`stitching.building.fuse_passes`),
tuned by a `BuildingConfig`.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

from layouts.errors import InputError
from layouts.location_list import ListedLocation
from layouts.locations import DEFAULT_CODE
from stitching.building.config import BuildingConfig
from stitching.building.fuse_passes import fuse_building
from stitching.building.map import BuildingMap
from stitching.building.place import place_passes
from stitching.building.route import Route
from stitching.warehouse_map import WarehouseMap


def build_map(
    route: Route,
    maps: Mapping[str, WarehouseMap],
    config: BuildingConfig | None = None,
    *,
    code: str = DEFAULT_CODE,
    positions: int = 1,
    meta: dict | None = None,
    listed: Sequence[ListedLocation] | None = None,
    listed_source: str = "location list",
) -> BuildingMap:
    """The building map of ``route``'s passes from their row maps: placed, registered and fused. ``code`` /
    ``positions``: the location code format and positions per level; ``listed`` (a location list read from
    ``listed_source``): the codes, bays and spans instead (`stitching.building.fuse_passes`); ``meta``: kept in
    the map as it is."""
    config = config or BuildingConfig()
    if not isinstance(config, BuildingConfig):
        raise InputError(f"config must be a BuildingConfig, got {type(config).__name__}")
    lacking = [p.sequence for p in route.passes if p.sequence not in maps]
    if lacking:
        raise InputError(f"{route.source}: no row map for pass {lacking[0]!r}")
    placed = place_passes(route, maps, config.place)
    return fuse_building(route, placed, code, positions, meta, listed, listed_source, config.fuse)
