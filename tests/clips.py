"""Small clips the tests build: a translating texture and a per-frame ramp."""

from __future__ import annotations

import cv2
import numpy as np
import torch


def translating_clip(
    frames: int = 5, height: int = 48, width: int = 64, dx: int = 2, dy: int = 0
) -> torch.Tensor:
    """(1, T, 3, H, W) uint8: a smooth random texture moving by (dx, dy) pixels per frame."""
    rng = np.random.default_rng(0)
    pad = 4 * max(abs(dx), abs(dy)) * frames + 8
    big = rng.integers(0, 256, (height + 2 * pad, width + 2 * pad)).astype(np.uint8)
    big = cv2.GaussianBlur(big, (0, 0), 2.5)
    big = cv2.normalize(big, None, 0, 255, cv2.NORM_MINMAX)
    # Content moving by +dx means frame t shows the texture shifted: crop starts at pad - t*dx.
    clip = np.stack(
        [
            big[pad - t * dy : pad - t * dy + height, pad - t * dx : pad - t * dx + width]
            for t in range(frames)
        ]
    )
    return torch.from_numpy(np.repeat(clip[:, None], 3, axis=1)).unsqueeze(0)


def ramp_clip(
    values: list[float], height: int = 4, width: int = 5, channels: int = 1
) -> torch.Tensor:
    """(1, T, C, H, W) float32: every pixel takes ``values[t]`` at frame t."""
    v = torch.tensor(values, dtype=torch.float32).view(1, -1, 1, 1, 1)
    return v.expand(1, len(values), channels, height, width).contiguous()
