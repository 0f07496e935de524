"""The one interface every temporal representation shares, and the input checks they all use.

A representation takes a clip ``(B, T, C, H, W)`` (uint8 or float intensities, C = 1 gray or
3 RGB) and returns ``(B, T_out, C_out, H, W)`` float32, with ``C_out = out_channels(C)`` and
``T_out = out_frames(T)``.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Mapping
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
import torch
from torch import nn

# The brightest intensity (uint8 video's): what the ranges of EDR's and the DVS simulator's
# settings are worked out for.
FULL_SCALE = 255.0
# ITU-R BT.601 luma weights, the ones OpenCV's RGB2GRAY uses.
GRAY_WEIGHTS = (0.299, 0.587, 0.114)


@dataclass(frozen=True)
class Features:
    """What a representation does, the properties the paper's Figure 2b compares."""

    temporal_receptive_field: str  # the frames an output depends on
    smoothing: str  # what filters noise, or "no"
    thresholding: str  # whether small changes give exactly zero (sparse output)
    on_off: str  # separate channels for increases and decreases
    direction: str  # whether it says which way things move
    learnable: str  # whether its parameters can train with the network


class Representation(nn.Module):
    """Base class: clip in, channels out. Subclasses implement ``forward`` and the two sizes."""

    # Too slow to run per batch: tasks compute it once per video and cache it (as the paper did).
    precompute: bool = False
    # Output channels that change sign when the clip is mirrored left-right (a flow's dx).
    hflip_negate: tuple[int, ...] = ()
    features: ClassVar[Features]  # declared by every representation (Figure 2b's table)

    def cache_key(self) -> str:
        """A stable digest of the class, its settings and its tensors, to key cached outputs."""
        payload = {
            "class": f"{type(self).__module__}.{type(self).__qualname__}",
            "settings": _plain(self),
            "tensors": {k: v.tolist() for k, v in sorted(self.state_dict().items())},
        }
        text = json.dumps(payload, sort_keys=True, default=repr)
        return f"{type(self).__name__.lower()}_{hashlib.sha1(text.encode()).hexdigest()[:12]}"

    def out_channels(self, in_channels: int) -> int:
        """Channels of the output for a clip with ``in_channels`` channels."""
        raise NotImplementedError

    def out_frames(self, frames: int) -> int:
        """Frames of the output for a clip of ``frames`` frames (differences lose one)."""
        return frames

    def min_frames(self) -> int:
        """The fewest input frames that give one output frame (a difference needs two)."""
        return 2 - self.out_frames(1)

    def preview(self, out_t: torch.Tensor) -> np.ndarray:
        """One output frame (C_out, H, W) -> an (H, W, 3) picture in [0, 1] for people to look at.

        Default: the channel mean as gray, 0.5 = zero, scaled by its largest magnitude.
        """
        signed = out_t.detach().float().mean(0).cpu().numpy()
        scale = max(float(np.abs(signed).max()), 1e-8)
        return np.repeat((0.5 + 0.5 * signed / scale)[..., None], 3, axis=2)


class FlowRepresentation(Representation):
    """A motion field between consecutive frames: (B, T, C, H, W) -> (B, T-1, 2, H, W), (dx, dy)."""

    precompute = True
    hflip_negate = (0,)
    features = Features("2 frames", "spatial (the flow's regulariser)", "no", "no", "yes", "no")

    def out_channels(self, in_channels: int) -> int:
        return 2

    def out_frames(self, frames: int) -> int:
        return frames - 1

    def preview(self, out_t: torch.Tensor) -> np.ndarray:
        return flow_picture(out_t.detach().float().cpu().numpy())


def _plain(value: object, depth: int = 0) -> object:
    """Public settings of an object as JSON-able values (nested objects one level down)."""
    if isinstance(value, str | int | float | bool) or value is None:
        return value
    if isinstance(value, list | tuple):
        return [_plain(v, depth) for v in value]
    if isinstance(value, dict):
        return {str(k): _plain(v, depth) for k, v in value.items()}
    if hasattr(value, "__dict__") and depth < 2:
        return {
            k: _plain(v, depth + 1) for k, v in sorted(vars(value).items()) if not k.startswith("_")
        }
    return type(value).__name__


def on_off_picture(on: np.ndarray, off: np.ndarray) -> np.ndarray:
    """ON (H, W) in green, OFF (H, W) in red, on black, each scaled by its own maximum."""
    picture = np.zeros((*on.shape, 3), np.float32)
    picture[..., 1] = on / max(float(on.max()), 1e-8)
    picture[..., 0] = off / max(float(off.max()), 1e-8)
    return picture


def flow_picture(flow: np.ndarray) -> np.ndarray:
    """Flow (2, H, W) -> the usual colour wheel: hue = direction, brightness = speed."""
    import cv2

    magnitude, angle = cv2.cartToPolar(flow[0].astype(np.float32), flow[1].astype(np.float32))
    hsv = np.zeros((*flow.shape[1:], 3), np.float32)
    hsv[..., 0] = np.degrees(angle)  # OpenCV's float HSV takes hue in degrees
    hsv[..., 1] = 1.0
    hsv[..., 2] = magnitude / max(float(magnitude.max()), 1e-8)
    return cv2.cvtColor(hsv, cv2.COLOR_HSV2RGB)


def check_enough_frames(
    frames: int, representations: Mapping[str, Representation], key: str = "task.frames"
) -> None:
    """``ConfigError`` naming ``key`` unless a clip of ``frames`` frames gives every one of
    ``representations`` an output frame (a difference needs two)."""
    from edr.checks.config import ConfigError

    for name, representation in representations.items():
        if representation.out_frames(frames) < 1:
            raise ConfigError(
                f"{key}={frames}: expected at least {representation.min_frames()}, the frames "
                f"{name} ({type(representation).__name__}) needs for one output frame"
            )


def check_clip(
    clip: torch.Tensor, *, min_frames: int = 1, name: str = "clip",
    dtype: torch.dtype = torch.float32,
) -> None:  # fmt: skip
    """Raise ``ValueError`` unless ``clip`` is a (B, T, C, H, W) clip of legal intensities, each
    one that ``dtype`` (what the representation computes in) holds."""
    _check_tensor(clip, "(B, T, C, H, W)", name, dtype)
    if clip.shape[1] < min_frames:
        raise ValueError(f"{name} has T={clip.shape[1]} frames; at least {min_frames} are needed")


def check_frame(
    frame: torch.Tensor, *, name: str = "frame", dtype: torch.dtype = torch.float32
) -> None:
    """Raise ``ValueError`` unless ``frame`` is a (B, C, H, W) frame of legal intensities."""
    _check_tensor(frame, "(B, C, H, W)", name, dtype)


def _check_tensor(x: torch.Tensor, layout: str, name: str, dtype: torch.dtype) -> None:
    """Rank, channel count (the dim named C in ``layout``), dtype and values of ``x``."""
    if not isinstance(x, torch.Tensor):
        raise ValueError(f"{name} must be a torch.Tensor, got {type(x).__name__}")
    dims = layout.strip("()").split(", ")
    if x.dim() != len(dims):
        raise ValueError(f"{name} must have shape {layout}, got {tuple(x.shape)} (rank {x.dim()})")
    _check_channels_and_values(x, channel_dim=dims.index("C"), name=name, dtype=dtype)


def _check_channels_and_values(
    x: torch.Tensor, *, channel_dim: int, name: str, dtype: torch.dtype
) -> None:
    if x.shape[channel_dim] not in (1, 3):
        raise ValueError(
            f"{name} must have 1 (gray) or 3 (RGB) channels in dim {channel_dim}, "
            f"got {x.shape[channel_dim]}"
        )
    if x.numel() == 0:
        raise ValueError(f"{name} is empty: shape {tuple(x.shape)}")
    if x.device.type == "meta":
        raise ValueError(f"{name} is on the meta device: it has no values to compute on")
    if x.dtype == torch.uint8:
        return
    if not x.is_floating_point():
        raise ValueError(f"{name} must be uint8 or floating point, got {x.dtype}")
    # One pass finds both ends; NaN anywhere makes both NaN.
    low, high = torch.aminmax(x.detach())
    if torch.isnan(low) or torch.isnan(high):
        raise ValueError(f"{name} contains NaN")
    if torch.isinf(low) or torch.isinf(high):
        raise ValueError(f"{name} contains inf; intensities must be finite")
    if low < 0:
        raise ValueError(f"{name} has negative intensities (min {low.item():.4g}); expected >= 0")
    largest = torch.finfo(dtype).max
    if x.dtype.itemsize > dtype.itemsize and high > largest:
        raise ValueError(
            f"{name} has intensities up to {high.item():.4g}, past the largest "
            f"{str(dtype).removeprefix('torch.')} ({largest:.3g}) this representation computes in"
        )


def to_float(x: torch.Tensor) -> torch.Tensor:
    """uint8, float16, bfloat16 -> float32 on the same scale; float32 and float64 stay as they are
    (a representation returns float32 whatever it computed in; see each class)."""
    return x if x.dtype in (torch.float32, torch.float64) else x.float()


def to_gray(x: torch.Tensor, channel_dim: int) -> torch.Tensor:
    """RGB -> luma along ``channel_dim`` (kept, size 1); 1-channel input is returned as float."""
    x = to_float(x)
    if x.shape[channel_dim] == 1:
        return x
    r, g, b = x.unbind(channel_dim)
    w_r, w_g, w_b = GRAY_WEIGHTS
    return (w_r * r + w_g * g + w_b * b).unsqueeze(channel_dim)
