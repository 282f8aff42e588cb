"""Layout class ids, names and display colours: the single definition used everywhere."""

import numpy as np

BACKGROUND = 0  #: no shelf there
SHELF = 1  #: free shelf surface (top view) / free face up to the next board (front view)
BOX = 2  #: occupied by a box
NUM_CLASSES = 3

CLASS_NAMES: dict[int, str] = {BACKGROUND: "background", SHELF: "shelf", BOX: "box"}

#: RGB colours for previews, Rerun annotation contexts and glTF materials.
CLASS_COLOURS: dict[int, tuple[int, int, int]] = {
    BACKGROUND: (30, 30, 30),
    SHELF: (70, 130, 220),
    BOX: (240, 160, 40),
}


def colourise(ids: np.ndarray, colours: dict[int, tuple[int, int, int]] = CLASS_COLOURS) -> np.ndarray:
    """Map a uint8 id array of any shape to RGB (shape + (3,)) with ``colours`` (layout classes by default)."""
    lut = np.zeros((256, 3), np.uint8)
    for cid, rgb in colours.items():
        lut[cid] = rgb
    return lut[np.asarray(ids, dtype=np.uint8)]
