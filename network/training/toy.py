"""A tiny in-memory sequence with exact ground truth, for tests and smoke checks without data.

A 1D "world" of racks (shelf), gaps (background) and boxes along X is seen by a camera moving
along X; each frame's layouts are the world's columns around the camera, and its image paints,
above a grey board line per shelf slot, each layout column's class as a colour band (plus
noise). The board lines sit where the frame records (``frame(i)["slots"]``) put them for its
60 degree camera at 2.6 m. It has the `waresynth.dataset.Sequence` members the network reads.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from layouts import BOX, SHELF, Intrinsics, LayoutSpec
from layouts.codecs import FrameLayouts

_COLOURS = np.array([[40, 40, 40], [70, 130, 220], [240, 160, 40]], np.float32)
_BOARD = np.array([160, 160, 160], np.float32)
_DISTANCE = 2.6
_CAM_Y = -1.0


class ToySequence:
    """``num_frames`` frames moving ``step_cols`` layout columns per frame (negative = leftwards)."""

    def __init__(
        self,
        spec: LayoutSpec,
        *,
        num_frames: int = 6,
        image_size: tuple[int, int] = (64, 64),
        step_cols: int = 2,
        seed: int = 0,
        name: str = "toy",
    ) -> None:
        rng = np.random.default_rng(seed)
        self.spec, self.num_frames, self.name = spec, num_frames, name
        self.root = Path(name)
        self.split = "train"
        self.step_cols = step_cols
        self.width, self.height = image_size
        d, r = spec.size, spec.num_slots
        length = d + abs(step_cols) * num_frames + 1
        world = np.zeros((r, length), np.uint8)
        x = 0
        while x < length:  # racks of 6-12 columns separated by gaps of 1-3
            w = int(rng.integers(max(2, d // 3), max(3, d // 2 + 1)))
            world[:, x : x + w] = SHELF
            for s in range(r):
                for _ in range(int(rng.integers(0, 3))):
                    b0 = x + int(rng.integers(0, max(1, w - 2)))
                    world[s, b0 : b0 + int(rng.integers(1, 4))] = BOX
            x += w + int(rng.integers(1, 4))
        self.world = world
        self.offset0 = 0 if step_cols >= 0 else length - d
        self.noise_seed = seed
        self.intrinsics = Intrinsics.from_fov(self.width, self.height, 60.0)

    def _cols(self, i: int) -> np.ndarray:
        return self.world[:, self.offset0 + i * self.step_cols : self.offset0 + i * self.step_cols + self.spec.size]

    def layouts(self, i: int) -> FrameLayouts:
        d = self.spec.size
        cols = self._cols(i)  # (R, D)
        top = np.zeros(self.spec.shape, np.uint8)
        front = np.zeros(self.spec.shape, np.uint8)
        top[:] = np.where(cols[:, None, :] > 0, SHELF, 0)
        front[:] = np.where(cols[:, None, :] > 0, SHELF, 0)
        box = cols == BOX
        top[:, d // 4 : 3 * d // 4, :][
            np.broadcast_to(box[:, None, :], (self.spec.num_slots, 3 * d // 4 - d // 4, d))
        ] = BOX
        front[:, d // 2 :, :][np.broadcast_to(box[:, None, :], (self.spec.num_slots, d - d // 2, d))] = BOX
        return FrameLayouts(top, front, np.ones(d, bool))

    def board_rows(self) -> list[int]:
        """Source image row of each slot's board line (slot 0 lowest)."""
        r, h = self.spec.num_slots, self.height
        return [int(round(h * (0.9 - k * 0.8 / r))) for k in range(r)]

    def rgb(self, i: int) -> np.ndarray:
        d, r = self.spec.size, self.spec.num_slots
        cols = self._cols(i)
        u = np.minimum((np.arange(self.width) * d) // self.width, d - 1)
        img = np.tile(_COLOURS[0], (self.height, self.width, 1))
        band = int(round(self.height * 0.8 / r))
        for k, v in enumerate(self.board_rows()):
            img[max(0, v - band + 2) : v] = _COLOURS[cols[k][u]][None]
            img[v : v + 2] = _BOARD
        noise = np.random.default_rng([self.noise_seed, i]).normal(0, 8, img.shape)
        return np.clip(img + noise, 0, 255).astype(np.uint8)

    def camera_positions(self) -> np.ndarray:
        px = self.spec.x_extent / self.spec.size
        x = (np.arange(self.num_frames) * self.step_cols) * px
        return np.stack([x, np.full_like(x, _CAM_Y), np.full_like(x, -_DISTANCE)], 1)

    def frame(self, i: int) -> dict[str, Any]:
        intr = self.intrinsics
        slots = [
            {"level": k, "board_top_y": _CAM_Y + (v - intr.cy) * _DISTANCE / intr.fy, "clear_height": 1.0}
            for k, v in enumerate(self.board_rows())
        ]
        return {
            "index": i,
            "camera_position": self.camera_positions()[i].tolist(),
            "distance": _DISTANCE,
            "slots": slots,
        }
