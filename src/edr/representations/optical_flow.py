"""Dense optical flow rows of Table 2 (OpenCV): Farneback and TV-L1 (Brox: ``brox.py``, torch).

Each maps a clip to the flow between consecutive frames, (B, T, C, H, W) -> (B, T-1, 2, H, W),
channels (dx, dy) in pixels per frame, computed on 8-bit gray frames (float input is taken on
the 0..255 scale, rounded and clipped).
"""

from __future__ import annotations

import cv2
import numpy as np
import torch

from edr.checks.config import Fraction, PositiveFloat, PositiveInt, check_arguments
from edr.representations.base import FlowRepresentation, check_clip, to_gray


def gray_uint8(frames: torch.Tensor) -> np.ndarray:
    """(B, T, C, H, W) uint8 or float on 0..255 -> (B, T, H, W) uint8 luma."""
    if frames.dtype == torch.uint8 and frames.shape[2] == 1:
        return frames[:, :, 0].contiguous().numpy()
    gray = to_gray(frames.detach().cpu(), channel_dim=2)[:, :, 0]
    return gray.round().clamp(0, 255).to(torch.uint8).numpy()


class OpticalFlow(FlowRepresentation):
    """Base of the pairwise flows: subclasses give ``_pair(prev, next) -> (H, W, 2)``."""

    def forward(self, frames: torch.Tensor) -> torch.Tensor:
        check_clip(frames, min_frames=2, name="frames")
        gray = gray_uint8(frames)  # (B, T, H, W)
        b, t, h, w = gray.shape
        flow = np.empty((b, t - 1, 2, h, w), np.float32)
        for i in range(b):
            for j in range(t - 1):
                flow[i, j] = self._pair(gray[i, j], gray[i, j + 1]).transpose(2, 0, 1)
        return torch.from_numpy(flow).to(frames.device)

    def _pair(self, prev: np.ndarray, nxt: np.ndarray) -> np.ndarray:
        raise NotImplementedError


class Farneback(OpticalFlow):
    """Gunnar Farneback's polynomial-expansion flow, ``cv2.calcOpticalFlowFarneback``."""

    def __init__(
        self,
        pyr_scale: Fraction = 0.5,
        levels: PositiveInt = 3,
        winsize: PositiveInt = 15,
        iterations: PositiveInt = 3,
        poly_n: PositiveInt = 5,
        poly_sigma: PositiveFloat = 1.2,
    ) -> None:
        super().__init__()
        check_arguments(self, locals())
        self.params = (pyr_scale, levels, winsize, iterations, poly_n, poly_sigma, 0)

    def _pair(self, prev: np.ndarray, nxt: np.ndarray) -> np.ndarray:
        return cv2.calcOpticalFlowFarneback(prev, nxt, None, *self.params)


class TVL1(OpticalFlow):
    """Dual TV-L1 flow (Zach et al.), ``cv2.optflow.DualTVL1OpticalFlow`` from opencv-contrib."""

    def __init__(
        self,
        tau: PositiveFloat = 0.25,
        lambda_: PositiveFloat = 0.15,
        scales: PositiveInt = 5,
        warps: PositiveInt = 5,
    ) -> None:
        super().__init__()
        check_arguments(self, locals())
        if not hasattr(cv2, "optflow"):
            raise RuntimeError(
                "TV-L1 needs cv2.optflow, which only opencv-contrib-python-headless ships; "
                "uninstall opencv-python(-headless) and install the contrib wheel"
            )
        self.params = {"tau": tau, "lambda_": lambda_, "nscales": scales, "warps": warps}
        self._tvl1 = cv2.optflow.DualTVL1OpticalFlow_create(**self.params)

    def _pair(self, prev: np.ndarray, nxt: np.ndarray) -> np.ndarray:
        return self._tvl1.calc(prev, nxt, None)
