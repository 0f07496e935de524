"""Frame-based rows of Table 2: raw frames (FDR) and frame differences (GrayDiff, RGBDiff)."""

from __future__ import annotations

from typing import Literal

import numpy as np
import torch

from edr.checks.config import PositiveFloat, check_arguments
from edr.representations import buffers, kernels
from edr.representations.base import Features, Representation, check_clip, to_float, to_gray


class FDR(Representation):
    """Frame-driven representation: the frames themselves, RGB or gray, times ``scale``, less
    ``offset``: 0.5 centres 0..1 frames on zero, as a ConvNet's mean subtraction does. The paper
    does not say; measured on generated KTH (``make demo``'s LeNet + FT-RCN, seed 0, 24 epochs):
    centred, 28-34 % of conv2's units dead and 50 % test accuracy by epoch 12; uncentred, 60-82 %
    dead and 23 % (results/learning/README.md). ``offset=0`` gives the frames as they are.

    (B, T, C, H, W) -> (B, T, C', H, W), C' = 1 if ``color="gray"`` else C.
    """

    features = Features("1 frame", "no", "no", "no", "no", "no")

    def __init__(
        self,
        color: Literal["keep", "gray"] = "keep",
        scale: PositiveFloat = 1 / 255,
        offset: float = 0.5,
    ) -> None:
        super().__init__()
        check_arguments(self, locals())
        self.color, self.scale, self.offset = color, float(scale), float(offset)

    def out_channels(self, in_channels: int) -> int:
        return 1 if self.color == "gray" else in_channels

    def preview(self, out_t: torch.Tensor) -> np.ndarray:
        image = out_t.detach().float().cpu().permute(1, 2, 0).numpy() + self.offset
        image = image / max(float(image.max()), 1e-8)
        return np.repeat(image, 3, axis=2) if image.shape[2] == 1 else image

    def forward(self, frames: torch.Tensor) -> torch.Tensor:
        check_clip(frames, name="frames")
        x = to_gray(frames, channel_dim=2) if self.color == "gray" else to_float(frames)
        return (x * self.scale - self.offset).float()


class GrayDiff(Representation):
    """Differences of consecutive gray frames: (B, T, C, H, W) -> (B, T-1, 1, H, W).

    ``scale`` maps the 0..255 range of uint8 video to -1..1. Under ``torch.no_grad()`` on the
    CPU (uint8 or float32) it runs a fused numba kernel, as fast as EDR's, for a fair race.
    """

    features = Features("2 frames", "no", "no", "no (one signed channel)", "no", "no")

    def __init__(self, scale: PositiveFloat = 1 / 255, fast: bool = True) -> None:
        super().__init__()
        check_arguments(self, locals())
        self.scale, self.fast = float(scale), fast

    def out_channels(self, in_channels: int) -> int:
        return 1

    def out_frames(self, frames: int) -> int:
        return frames - 1

    def forward(self, frames: torch.Tensor, out: torch.Tensor | None = None) -> torch.Tensor:
        """(B, T, C, H, W) -> (B, T-1, 1, H, W) float32, into ``out`` when given."""
        check_clip(frames, min_frames=2, name="frames")
        b, t, c, h, w = frames.shape
        shape = (b, t - 1, 1, h, w)
        fusable = frames.device.type == "cpu" and frames.dtype in (torch.uint8, torch.float32)
        fused = self.fast and fusable and not (torch.is_grad_enabled() and frames.requires_grad)
        if fused and (out is None or buffers.writable(out)):
            target = buffers.output(out, shape, torch.float32, frames.device)
            kernels.launch(
                kernels.gray_diff_kernel,
                b * t * h * w,
                frames.contiguous().view(b, t, c, h * w).numpy(),
                np.float32(self.scale),
                target.view(b, t - 1, 1, h * w).numpy(),
            )
            return target
        gray = to_gray(frames, channel_dim=2)  # (B, T, 1, H, W)
        diff = (self.scale * (gray[:, 1:] - gray[:, :-1])).float()
        return (
            diff if out is None else buffers.output(out, shape, diff.dtype, diff.device).copy_(diff)
        )


class RGBDiff(Representation):
    """Differences of consecutive frames per colour channel: -> (B, T-1, C, H, W)."""

    features = Features("2 frames", "no", "no", "no (signed channels)", "no", "no")

    def __init__(self, scale: PositiveFloat = 1 / 255) -> None:
        super().__init__()
        check_arguments(self, locals())
        self.scale = float(scale)

    def out_channels(self, in_channels: int) -> int:
        return in_channels

    def out_frames(self, frames: int) -> int:
        return frames - 1

    def forward(self, frames: torch.Tensor) -> torch.Tensor:
        check_clip(frames, min_frames=2, name="frames")
        x = to_float(frames)
        return (self.scale * (x[:, 1:] - x[:, :-1])).float()
