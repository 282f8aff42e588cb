"""MVRackLay toolkit: the command-line application and end-to-end pipeline."""

import sys as _sys

__version__ = "0.1.0"

if "torch" not in _sys.modules:  # idle OpenMP threads sleep, unless set otherwise (mvracklay/threads.py)
    from mvracklay.threads import quiet_openmp as _quiet_openmp

    _quiet_openmp()

__all__ = ["reconstruct", "reconstruct_live", "live_updates", "free_space", "WarehouseMap", "Intrinsics", "InputError"]


def __getattr__(name: str):
    """The Python API, imported on first use (``import mvracklay`` and the CLI's ``--help`` stay light)."""
    if name == "reconstruct":
        from mvracklay.api import reconstruct

        return reconstruct
    if name in ("reconstruct_live", "live_updates"):
        from mvracklay import api

        return getattr(api, name)
    if name == "free_space":
        from stitching.free_space import free_space

        return free_space
    if name == "WarehouseMap":
        from stitching.warehouse_map import WarehouseMap

        return WarehouseMap
    if name == "Intrinsics":
        from layouts import Intrinsics

        return Intrinsics
    if name == "InputError":
        from layouts.errors import InputError

        return InputError
    raise AttributeError(f"module 'mvracklay' has no attribute {name!r}")
