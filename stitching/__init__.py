"""Stitching: per-frame layouts -> 2D detections -> 3D cuboids per shelf -> shift and merge -> global map.

Takes layouts from any source (ground truth, the network, files on disk); imports only `layouts`.
Outputs a `WarehouseMap` (JSON), a ``.glb`` (`stitching.export_gltf`), a Rerun recording
(`stitching.rerun_log`) and free-space answers (`stitching.free_space`). See docs/stitching.md.
"""

from importlib import import_module

#: where each name of `__all__` lives, imported on first use (a free-space query reads a map without loading
#: the image-processing code)
_WHERE = {
    **dict.fromkeys(
        ("Reconstruction", "StitchConfig", "Stitcher", "folder_frames", "reconstruct", "stitch_folder"), "pipeline"
    ),
    **dict.fromkeys(("MapBox", "MapRack", "MapShelf", "StepRecord", "WarehouseMap"), "warehouse_map"),
}


def __getattr__(name: str):
    if name in _WHERE:
        return getattr(import_module(f"stitching.{_WHERE[name]}"), name)
    raise AttributeError(f"module 'stitching' has no attribute {name!r}")


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
    "stitch_folder",
]
