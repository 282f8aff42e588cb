"""Semantic class ids of WareSynth's per-pixel label images (``semantic/NNNNNN.png``).

``RACK`` is the steel structure of the mapped row (uprights and top beams), ``SHELF`` its
boards, ``BOX`` boxes on its boards. Background racks, their boxes and floor props are
``CLUTTER``: they are scenery, not part of the row being mapped.
"""

from __future__ import annotations

import numpy as np

from layouts.classes import colourise

VOID = 0  #: no surface hit (beyond the walls)
FLOOR = 1
WALL = 2
RACK = 3  #: uprights and beams of the mapped row
SHELF = 4  #: shelf boards of the mapped row
BOX = 5  #: boxes on the mapped row's shelves
CLUTTER = 6  #: background racks, their loads and floor props
NUM_SEMANTIC = 7

SEMANTIC_NAMES: dict[int, str] = {
    VOID: "void",
    FLOOR: "floor",
    WALL: "wall",
    RACK: "rack",
    SHELF: "shelf",
    BOX: "box",
    CLUTTER: "clutter",
}

#: Display colours (RGB) for previews.
SEMANTIC_COLOURS: dict[int, tuple[int, int, int]] = {
    VOID: (0, 0, 0),
    FLOOR: (128, 128, 128),
    WALL: (90, 60, 140),
    RACK: (40, 90, 230),
    SHELF: (60, 200, 220),
    BOX: (240, 160, 40),
    CLUTTER: (120, 200, 80),
}


def colourise_semantic(sem: np.ndarray) -> np.ndarray:
    """Map a semantic id image (H, W) to uint8 RGB (H, W, 3) for display."""
    return colourise(sem, SEMANTIC_COLOURS)
