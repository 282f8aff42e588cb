"""The slot memory: a stacked ConvLSTM over each slot's layout-space maps, moved with the camera.

`SlotMemory` runs over the frames of a window (or one step per frame when streaming, `MemoryState`);
`shift_columns` moves its state by the camera's step along the row (`network.model.motion`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import torch
import torch.nn.functional as F
from torch import nn

from layouts.canonical import CanonicalView
from layouts.errors import InputError
from network.fastops import avg_pool2
from network.model.convlstm import StackedConvLSTM, State
from network.model.decoders import SlotFeatures, up
from network.model.motion import camera_shift


@dataclass
class MemoryState:
    """What streaming carries from frame to frame: the ConvLSTM state and the last frame's motion signature."""

    lstm: State
    motion: torch.Tensor | None


class SlotMemory(nn.Module):
    """The temporal block: a stacked ConvLSTM over each slot's coarse maps (both views), in layout space.

    Per slot and frame, the top- and front-view coarse maps ``(2 dw, D/2, D/2)`` are pooled 2x (cells
    of ``x_extent / (D/4)``, ~19 cm) and fed to the ConvLSTM in frame order; its output, upsampled, is
    added back through a zero-initialised 1x1 convolution, so a fresh memory leaves the single-frame
    network's outputs unchanged. The layout frame moves with the camera, so with ``align`` the state
    is shifted by the camera motion read from the images (`network.model.motion`) before each frame: a
    memory cell then stays on the same piece of shelf, and what an earlier viewpoint showed (a box's
    side face, its top) is where the current frame needs it. Without ``align`` the 3x3 gates must
    learn to follow the motion themselves.
    """

    def __init__(self, channels: int, hidden: int, layers: int, view: CanonicalView | None = None) -> None:
        super().__init__()
        self.channels = channels
        self.view = view  #: None: no alignment
        self.lstm = StackedConvLSTM(2 * channels, hidden, layers)
        self.out = nn.Conv2d(hidden, 2 * channels, 1)
        nn.init.zeros_(self.out.weight)
        nn.init.zeros_(self.out.bias)

    def _refine(self, f: SlotFeatures, h: torch.Tensor) -> SlotFeatures:
        corr = up(self.out(h))
        return replace(f, top=f.top + corr[:, : self.channels], front=f.front + corr[:, self.channels :])

    @staticmethod
    def _pooled(f: SlotFeatures) -> torch.Tensor:
        return avg_pool2(torch.cat([f.top, f.front], 1))

    def _align(
        self, state: State, prev: torch.Tensor | None, cur: SlotFeatures, dx: torch.Tensor | None = None
    ) -> State:
        """The state moved with the camera from the frame of motion signature ``prev`` to ``cur``'s
        (or by the given camera steps ``dx``, ``(N,)`` metres)."""
        if self.view is None:
            return state
        if dx is None:
            if prev is None or cur.motion is None:
                raise InputError("the aligned slot memory needs each frame's motion signature")
            dx = camera_shift(prev, cur.motion, self.view)  # (N,) metres
        slots = cur.valid.shape[1]
        return [
            (shift_columns(h, dx, self.view.x_extent, slots), shift_columns(c, dx, self.view.x_extent, slots))
            for h, c in state
        ]

    def align_grid(self, state: MemoryState, cur: SlotFeatures, dx: torch.Tensor | None = None) -> torch.Tensor | None:
        """The `shift_grid` that moves ``state`` (every map of it: they share one shape) to ``cur``'s frame, as
        `step` moves it (None: an unaligned memory)."""
        if self.view is None:
            return None
        if dx is None:
            if state.motion is None or cur.motion is None:
                raise InputError("the aligned slot memory needs each frame's motion signature")
            dx = camera_shift(state.motion, cur.motion, self.view)  # (N,) metres
        return shift_grid(state.lstm[0][0], dx, self.view.x_extent, cur.valid.shape[1])

    def step(
        self, f: SlotFeatures, state: MemoryState | None, motion: torch.Tensor | None = None
    ) -> tuple[SlotFeatures, MemoryState]:
        """One frame's slot features ``(B*R, ...)``; the state is per (batch, slot). ``motion``:
        the camera's step since the state's frame, ``(B,)`` metres, instead of the image estimate."""
        lstm = None if state is None else self._align(state.lstm, state.motion, f, motion)
        h, lstm = self.lstm.step(self._pooled(f), lstm)
        return self._refine(f, h), MemoryState(lstm, f.motion)

    def window(self, feats: list[SlotFeatures]) -> list[SlotFeatures]:
        """A window's frames in order (each ``(B*R, ...)``), refined by a fresh memory."""
        out, state = [], None
        for f in feats:
            g, state = self.step(f, state)
            out.append(g)
        return out


def shift_columns(x: torch.Tensor, dx: torch.Tensor, x_extent: float, slots: int) -> torch.Tensor:
    """Layout-space maps ``(N*R, C, h, w)`` (``w`` columns over ``x_extent``) after the camera moved by ``dx`` ``(N,)``.

    The layout frame moves with the camera, so a world point at column x moves to x - dx: the new
    map at x is the old one at x + dx (bilinear; cells that come into view start at zero).
    """
    return shifted(x, shift_grid(x, dx, x_extent, slots))


def shift_grid(x: torch.Tensor, dx: torch.Tensor, x_extent: float, slots: int) -> torch.Tensor:
    """The sampling grid of `shift_columns` for maps shaped like ``x`` (`shifted` applies it)."""
    n = x.shape[0]
    off = (2.0 * dx / x_extent).to(x.dtype).repeat_interleave(slots)  # normalised grid units
    theta = x.new_zeros(n, 2, 3)
    theta[:, 0, 0] = 1.0
    theta[:, 1, 1] = 1.0
    theta[:, 0, 2] = off
    return F.affine_grid(theta, list(x.shape), align_corners=False)


def shifted(x: torch.Tensor, grid: torch.Tensor) -> torch.Tensor:
    """Maps ``x`` moved by a `shift_grid` (bilinear; cells that come into view start at zero)."""
    return F.grid_sample(x, grid, mode="bilinear", padding_mode="zeros", align_corners=False)
