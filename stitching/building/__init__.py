"""The building: many passes' row maps (`stitching.pipeline`) -> one map of every rack face with a location code
per slot, its inventory, the changes between two scans, where a box fits.

`stitching.building.pipeline.build_map` places each pass by its route (`route`, `place`), registers the passes of a
face where they overlap and fuses them (`fuse_passes`) into a `map.BuildingMap`, tuned by a `config.BuildingConfig`.
Stands on the row stitcher and `layouts`; the row stitcher never imports it. See docs/buildings.md.
"""
