"""ResNet-18 context encoder in plain torch, with torchvision's parameter names.

The names (``conv1``, ``bn1``, ``layer1.0.conv1``, ``layer2.0.downsample.0`` ...) match
torchvision's ``resnet18`` so a local ImageNet state dict loads with `load_imagenet_weights`;
nothing is downloaded. ``width`` scales the channel counts for cheap CPU training (ImageNet
weights need the standard width 64).
"""

from __future__ import annotations

import os
from pathlib import Path

import torch
from torch import nn

from layouts.errors import InputError


class BasicBlock(nn.Module):
    """Two 3x3 convolutions with a residual connection (torchvision's BasicBlock)."""

    def __init__(self, cin: int, cout: int, stride: int = 1) -> None:
        super().__init__()
        self.conv1 = nn.Conv2d(cin, cout, 3, stride, 1, bias=False)
        self.bn1 = nn.BatchNorm2d(cout)
        self.relu = nn.ReLU(inplace=True)
        self.conv2 = nn.Conv2d(cout, cout, 3, 1, 1, bias=False)
        self.bn2 = nn.BatchNorm2d(cout)
        self.downsample: nn.Module | None = None
        if stride != 1 or cin != cout:
            self.downsample = nn.Sequential(nn.Conv2d(cin, cout, 1, stride, bias=False), nn.BatchNorm2d(cout))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        idt = x if self.downsample is None else self.downsample(x)
        out = self.relu(self.bn1(self.conv1(x)))
        out = self.bn2(self.conv2(out))
        return self.relu(out + idt)


class ResNet18Encoder(nn.Module):
    """ResNet-18 without the classifier: returns the 1/2 (stem), 1/4, 1/8, 1/16 and 1/32 feature maps."""

    def __init__(self, width: int = 64) -> None:
        super().__init__()
        if not isinstance(width, int) or width < 4:
            raise InputError(f"encoder width must be an integer >= 4, got {width!r}")
        self.width = width
        w = [width, width * 2, width * 4, width * 8]
        self.conv1 = nn.Conv2d(3, width, 7, 2, 3, bias=False)
        self.bn1 = nn.BatchNorm2d(width)
        self.relu = nn.ReLU(inplace=True)
        self.maxpool = nn.MaxPool2d(3, 2, 1)
        self.layer1 = nn.Sequential(BasicBlock(w[0], w[0]), BasicBlock(w[0], w[0]))
        self.layer2 = nn.Sequential(BasicBlock(w[0], w[1], 2), BasicBlock(w[1], w[1]))
        self.layer3 = nn.Sequential(BasicBlock(w[1], w[2], 2), BasicBlock(w[2], w[2]))
        self.layer4 = nn.Sequential(BasicBlock(w[2], w[3], 2), BasicBlock(w[3], w[3]))
        self.channels = tuple(w)
        for m in self.modules():
            if isinstance(m, nn.Conv2d):
                nn.init.kaiming_normal_(m.weight, mode="fan_out", nonlinearity="relu")
            elif isinstance(m, nn.BatchNorm2d):
                nn.init.ones_(m.weight)
                nn.init.zeros_(m.bias)

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, ...]:
        """Feature maps at 1/2 (the stem, ``width`` channels), 1/4, 1/8, 1/16 and 1/32 of the input."""
        c1 = self.relu(self.bn1(self.conv1(x)))
        c2 = self.layer1(self.maxpool(c1))
        c3 = self.layer2(c2)
        c4 = self.layer3(c3)
        c5 = self.layer4(c4)
        return c1, c2, c3, c4, c5


def load_imagenet_weights(encoder: ResNet18Encoder, path: str | os.PathLike) -> None:
    """Load a local torchvision ``resnet18`` state dict into ``encoder`` (``fc.*`` ignored).

    Strict on the encoder's keys and shapes: a missing or unexpected key, or a shape that
    differs (e.g. a non-standard width), is one `InputError` naming the file.
    """
    from network.checkpoint import torch_load

    path = Path(path)
    state = torch_load(path, "ImageNet weights")
    if isinstance(state, dict) and "state_dict" in state and isinstance(state["state_dict"], dict):
        state = state["state_dict"]
    if not isinstance(state, dict) or not all(isinstance(v, torch.Tensor) for v in state.values()):
        raise InputError(f"{path}: expected a state dict of tensors (torchvision resnet18)")
    state = {k.removeprefix("module."): v for k, v in state.items() if not k.removeprefix("module.").startswith("fc.")}
    own = encoder.state_dict()
    missing = sorted(set(own) - set(state))
    extra = sorted(set(state) - set(own))
    if missing or extra:
        raise InputError(
            f"{path}: not a resnet18 state dict: {len(missing)} missing keys {missing[:3]}, "
            f"{len(extra)} unexpected keys {extra[:3]}"
        )
    bad = [k for k in own if own[k].shape != state[k].shape]
    if bad:
        k = bad[0]
        raise InputError(
            f"{path}: shape of {k} is {tuple(state[k].shape)}, the encoder wants {tuple(own[k].shape)} "
            f"(ImageNet weights need encoder width 64)"
        )
    encoder.load_state_dict({k: state[k].to(own[k].dtype) for k in own}, strict=True)
