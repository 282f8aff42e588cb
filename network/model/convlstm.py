"""Stacked convolutional LSTM over per-frame feature maps, usable over a window or frame by frame.

`StackedConvLSTM.step` advances one frame carrying the state; windows and streaming both run
through it, so streaming inference (one encoder pass per frame) gives exactly the outputs of a
window over the same prefix. The model runs it over each shelf slot's layout-space
features (`network.model.memory.SlotMemory`).
"""

from __future__ import annotations

import torch
from torch import nn

State = list[tuple[torch.Tensor, torch.Tensor]]


class ConvLSTMCell(nn.Module):
    """One ConvLSTM layer: the four gates from one convolution over ``[x, h]``."""

    def __init__(self, cin: int, hidden: int, kernel: int = 3) -> None:
        super().__init__()
        self.hidden = hidden
        self.gates = nn.Conv2d(cin + hidden, 4 * hidden, kernel, padding=kernel // 2)
        with torch.no_grad():  # forget-gate bias 1: remember by default early in training
            self.gates.bias.zero_()
            self.gates.bias[hidden : 2 * hidden].fill_(1.0)

    def forward(
        self, x: torch.Tensor, state: tuple[torch.Tensor, torch.Tensor] | None
    ) -> tuple[torch.Tensor, torch.Tensor]:
        if state is None:
            z = x.new_zeros(x.shape[0], self.hidden, x.shape[2], x.shape[3])
            state = (z, z)
        h, c = state
        i, f, o, g = self.gates(torch.cat([x, h], 1)).chunk(4, 1)
        c = torch.sigmoid(f) * c + torch.sigmoid(i) * torch.tanh(g)
        h = torch.sigmoid(o) * torch.tanh(c)
        return h, c


class StackedConvLSTM(nn.Module):
    """``num_layers`` ConvLSTM cells, each feeding the next."""

    def __init__(self, cin: int, hidden: int, num_layers: int = 2, kernel: int = 3) -> None:
        super().__init__()
        self.cells = nn.ModuleList(ConvLSTMCell(cin if i == 0 else hidden, hidden, kernel) for i in range(num_layers))

    def step(self, x: torch.Tensor, state: State | None = None) -> tuple[torch.Tensor, State]:
        """Advance one frame ``(B, C, H, W)``; returns the top layer's output and the new state."""
        new: State = []
        for i, cell in enumerate(self.cells):
            h, c = cell(x, None if state is None else state[i])
            new.append((h, c))
            x = h
        return x, new
