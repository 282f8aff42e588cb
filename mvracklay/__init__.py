"""MVRackLay toolkit: the command-line application and end-to-end pipeline."""

import sys as _sys

__version__ = "0.1.0"

if "torch" not in _sys.modules:  # idle OpenMP threads sleep, unless set otherwise (mvracklay/threads.py)
    from mvracklay.threads import quiet_openmp as _quiet_openmp

    _quiet_openmp()
