"""Whole recognition models: representation (when computed on the fly) then backbone."""

from __future__ import annotations

from collections.abc import Callable

import torch
from torch import nn


class ConvRecurrent(nn.Module):
    """A per-frame ConvNet then a recurrent head: (B, T, C, H, W) -> (B, num_classes)."""

    def __init__(
        self,
        in_channels: int,
        num_classes: int,
        features: Callable[[int], nn.Module],
        head: Callable[..., nn.Module],
        frames: int = 60,
        height: int = 58,
        width: int = 58,
    ) -> None:
        super().__init__()
        self.features = features(in_channels)
        with torch.no_grad():
            _, f, h, w = self.features(torch.zeros(1, in_channels, height, width)).shape
        self.head = head(channels=f, height=h, width=w, num_classes=num_classes)

    def forward(self, clip: torch.Tensor) -> torch.Tensor:
        b, t = clip.shape[:2]
        maps = self.features(clip.flatten(0, 1))  # (B*T, F, h, w)
        return self.head(maps.view(b, t, *maps.shape[1:]))


class RecognitionModel(nn.Module):
    """``representation`` (None when the data already hold it), then ``input_norm`` if given,
    then ``backbone``.

    Keeping an on-the-fly representation inside the model lets a learnable EDR train with it.
    ``input_norm`` (:func:`input_norm`) standardises each channel of the backbone's input.
    """

    def __init__(
        self,
        representation: nn.Module | None,
        backbone: nn.Module,
        input_norm: nn.Module | None = None,
    ) -> None:
        super().__init__()
        self.representation = representation
        self.input_norm = input_norm
        self.backbone = backbone

    def forward(self, clip: torch.Tensor) -> torch.Tensor:
        x = self.representation(clip) if self.representation is not None else clip
        if self.input_norm is not None:  # (B, T, C, H, W) -> (B, C, T, H, W) and back
            x = self.input_norm(x.transpose(1, 2)).transpose(1, 2)
        return self.backbone(x)


def input_norm(channels: int) -> nn.Module:
    """Each of ``channels`` input channels to zero mean and unit variance: the batch's statistics
    in training, their running averages in testing, no learned scale or shift. What makes a
    representation that is non-negative and sparse (EDR's ON and OFF) reach the backbone centred
    and at the scale of any other."""
    return nn.BatchNorm3d(channels, affine=False)


@torch.no_grad()
def activation_sparsity(model: RecognitionModel, clips: torch.Tensor) -> dict[str, float]:
    """Fraction of exact zeros in the representation and after every ReLU, for ``clips``."""
    zeros: dict[str, list[float]] = {}

    def record(name: str) -> Callable:
        def hook(_module: nn.Module, _inputs: tuple, output: torch.Tensor) -> None:
            zeros.setdefault(name, []).append((output == 0).float().mean().item())

        return hook

    handles = [
        m.register_forward_hook(record(n))
        for n, m in model.named_modules()
        if isinstance(m, nn.ReLU)
    ]
    if model.representation is not None:
        handles.append(model.representation.register_forward_hook(record("representation")))
    try:
        model(clips)
    finally:
        for handle in handles:
            handle.remove()
    return {name: sum(v) / len(v) for name, v in zeros.items()}
