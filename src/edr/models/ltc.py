"""LTC (Varol et al.): long-term temporal convolutions over a whole clip."""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import nn


class LTC(nn.Module):
    """Five 3x3x3 conv layers with max-pooling, two dropout FC layers, a classifier.

    (B, T, C, H, W) -> (B, num_classes). The paper's sizes are the defaults: widths
    64-128-256-256-256, FC 2048, for 60 frames of 58x58; the first pooling keeps time.
    """

    def __init__(
        self,
        in_channels: int,
        num_classes: int,
        frames: int = 60,
        height: int = 58,
        width: int = 58,
        widths: Sequence[int] = (64, 128, 256, 256, 256),
        fc: int = 2048,
        dropout: float = 0.5,
    ) -> None:
        super().__init__()
        layers: list[nn.Module] = []
        channels = in_channels
        for i, out in enumerate(widths):
            layers += [nn.Conv3d(channels, out, 3, padding=1), nn.ReLU(inplace=True)]
            layers.append(nn.MaxPool3d((1, 2, 2) if i == 0 else 2, ceil_mode=True))
            channels = out
        self.features = nn.Sequential(*layers)
        with torch.no_grad():
            flat = self.features(torch.zeros(1, in_channels, frames, height, width)).numel()
        self.classifier = nn.Sequential(
            nn.Flatten(),
            nn.Linear(flat, fc),
            nn.ReLU(inplace=True),
            nn.Dropout(dropout),
            nn.Linear(fc, fc),
            nn.ReLU(inplace=True),
            nn.Dropout(dropout),
            nn.Linear(fc, num_classes),
        )

    def forward(self, clip: torch.Tensor) -> torch.Tensor:
        x = clip.permute(0, 2, 1, 3, 4)  # (B, C, T, H, W)
        return self.classifier(self.features(x))
