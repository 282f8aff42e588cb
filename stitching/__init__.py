"""Stitching: per-frame layouts -> 2D detections -> 3D cuboids per shelf -> shift and merge -> global map.

Takes layouts from any source (ground truth, the network, files on disk); imports only `layouts`.
Outputs a `WarehouseMap` (JSON), a ``.glb`` (`stitching.export_gltf`), a Rerun recording
(`stitching.rerun_log`) and free-space answers (`stitching.free_space`). See docs/stitching.md.
"""

from stitching.pipeline import Reconstruction, StitchConfig, Stitcher, folder_frames, reconstruct
from stitching.warehouse_map import MapBox, MapRack, MapShelf, StepRecord, WarehouseMap

__all__ = [
    "MapBox",
    "MapRack",
    "MapShelf",
    "Reconstruction",
    "StepRecord",
    "StitchConfig",
    "Stitcher",
    "WarehouseMap",
    "folder_frames",
    "reconstruct",
]
