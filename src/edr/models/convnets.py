"""Per-frame feature extractors: LeNet and Network-in-Network. (N, C, H, W) -> (N, F, h, w)."""

from __future__ import annotations

from collections.abc import Sequence

from torch import nn


class LeNet(nn.Sequential):
    """Two 5x5 conv + ReLU + 2x2 max-pool stages (LeCun et al. 1998), widths 20 and 50."""

    def __init__(self, in_channels: int, widths: Sequence[int] = (20, 50)) -> None:
        layers: list[nn.Module] = []
        channels = in_channels
        for out in widths:
            layers += [nn.Conv2d(channels, out, 5), nn.ReLU(inplace=True), nn.MaxPool2d(2)]
            channels = out
        super().__init__(*layers)
        self.out_channels = channels


class NiN(nn.Sequential):
    """Network in Network (Lin et al. 2014): mlpconv blocks (k x k conv, two 1x1 convs, ReLUs),
    3x3/2 max-pooling after all but the last block."""

    def __init__(
        self,
        in_channels: int,
        widths: Sequence[int] = (96, 192, 192),
        kernels: Sequence[int] = (5, 5, 3),
    ) -> None:
        layers: list[nn.Module] = []
        channels = in_channels
        for i, (out, k) in enumerate(zip(widths, kernels, strict=True)):
            layers += [
                nn.Conv2d(channels, out, k, padding=k // 2),
                nn.ReLU(inplace=True),
                nn.Conv2d(out, out, 1),
                nn.ReLU(inplace=True),
                nn.Conv2d(out, out, 1),
                nn.ReLU(inplace=True),
            ]
            if i < len(widths) - 1:
                layers.append(nn.MaxPool2d(3, stride=2, ceil_mode=True))
            channels = out
        super().__init__(*layers)
        self.out_channels = channels
