"""Generated video that needs no download: the demo's default scene."""

from __future__ import annotations

import cv2
import numpy as np
import torch


def _texture(rng: np.random.Generator, height: int, width: int, blur: float) -> np.ndarray:
    noise = rng.random((height, width)).astype(np.float32)
    return cv2.GaussianBlur(noise, (0, 0), blur)


def synthetic_scene(
    frames: int = 48, height: int = 120, width: int = 160, seed: int = 0
) -> torch.Tensor:
    """A scene with the cases a temporal representation must tell apart, (T, 3, H, W) uint8.

    A textured background that stays still (no events expected), a bright square moving right
    (ON at its leading edge, OFF at its trailing edge), a dark disk moving down, and a patch
    whose brightness oscillates in place (ON and OFF in turn, no motion).
    """
    if frames < 1 or height < 16 or width < 16:
        raise ValueError(
            f"need frames >= 1 and a frame of at least 16x16, got {frames}x{height}x{width}"
        )
    rng = np.random.default_rng(seed)
    background = 70 + 60 * _texture(rng, height, width, blur=max(height, width) / 40)
    tint = np.array([1.0, 0.9, 0.8], np.float32)
    side = max(4, height // 6)
    radius = max(3, height // 10)
    yy, xx = np.mgrid[0:height, 0:width]
    out = np.empty((frames, 3, height, width), np.uint8)
    for t in range(frames):
        phase = t / max(frames - 1, 1)
        img = background.copy()
        x0 = int(phase * (width - side))
        y0 = height // 5
        img[y0 : y0 + side, x0 : x0 + side] = 220.0
        cy, cx = int(radius + phase * (height - 2 * radius - 1)), (2 * width) // 3
        img[(yy - cy) ** 2 + (xx - cx) ** 2 <= radius**2] = 25.0
        ph, pw = height - height // 4, width // 8
        img[ph : ph + side // 2, pw : pw + side // 2] = 128 + 90 * np.sin(2 * np.pi * t / 12)
        rgb = np.clip(img[None] * tint[:, None, None], 0, 255)
        out[t] = rgb.astype(np.uint8)
    return torch.from_numpy(out)
