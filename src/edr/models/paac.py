"""The PAAC actor-critic network, with a recurrent core that carries state across agent steps.

Trunk (Clemente et al. 2017): conv 16 8x8/4, conv 32 4x4/2 (ReLU) -> on 84x84 a 32x9x9 map.
Core: ``lstm`` (FC 256 then an LSTM of 256), ``ftlstm`` (a feature-tracking LSTM: every gate's
recurrent term is, per channel, a map from every location to every location of that channel,
as FT-RCN; no recurrent weight couples channels) or ``none`` (FC 256, the original PAAC).
``lenet_ftlstm`` is the authors' structure instead of PAAC's trunk: LeNet (conv 6 5x5, pool 2,
conv 16 5x5, pool 2) on each frame as it comes, the feature-tracking LSTM over its 16x18x18 maps,
then FC 512 (their ``NIPSNetwork``); it reads one frame per step, its LSTM holding the past.
Heads: policy logits and state value. The frames may be normalised first (``input_norm``).

The network steps any batch of envs with its recurrent state (``h``, ``c``), restarting from
zeros wherever ``is_init`` is set. Its input is the last frames stacked on the channel axis
(..., n*C, H, W), or those n frames as they are, oldest first: then the first convolution sums
each frame's convolution with its slice of the weights (:class:`FramesConv`), the same numbers
without the copy of every frame but the newest that stacking them takes at each agent step.
:class:`edr.rl.rollout.Actor` runs it over rollouts and :func:`edr.rl.loss.paac_loss`
differentiates what it output there.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Literal

import torch
from torch import nn
from torch.nn import functional

from edr.models.convnets import LeNet
from edr.models.precision import Precision, autocast
from edr.models.recurrent import feature_tracking_weights, track_features

Core = Literal["lstm", "ftlstm", "none", "lenet_ftlstm"]
Init = Literal["orthogonal", "fan_in"]
InputNorm = Literal["raw", "centred", "batchnorm"]
AUTHORS_WIDTHS = (6, 16)  # the authors' LeNet: conv_filters [[5, 5, C, 6], [5, 5, 6, 16]]
AUTHORS_HIDDEN = 512  # their FC after the LSTM


class FeatureTrackingLSTMCell(nn.Module):
    """LSTM over feature maps: input term a 1x1 conv (mixes channels), recurrent term per channel."""

    def __init__(self, channels: int, locations: int) -> None:
        super().__init__()
        self.channels, self.locations = channels, locations
        self.input_gates = nn.Conv1d(channels, 4 * channels, 1)  # i, f, g, o
        self.recurrent = feature_tracking_weights(4, channels, locations)

    def forward(
        self, x: torch.Tensor, state: tuple[torch.Tensor, torch.Tensor]
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """x (B, C, P), state (B, C*P) twice -> (h, c), each (B, C*P)."""
        b = x.shape[0]
        h, c = (s.view(b, self.channels, self.locations) for s in state)
        gates = self.input_gates(x).view(b, 4, self.channels, self.locations)
        gates = gates + track_features(h, self.recurrent)  # (B, 4, C, P)
        i, f, g, o = gates.unbind(1)
        c = torch.sigmoid(f) * c + torch.sigmoid(i) * torch.tanh(g)
        h = torch.sigmoid(o) * torch.tanh(c)
        return h.flatten(1), c.flatten(1)


class FramesConv(nn.Conv2d):
    """A convolution of n frames stacked on the channel axis, oldest first, taken as the n
    frames [(B, C, H, W)] * n: the sum of every frame's convolution with its slice of the
    weights, equal to the convolution of the stack (B, n*C, H, W) without building it."""

    def forward(
        self,
        frames: Sequence[torch.Tensor],
        weight: torch.Tensor | None = None,
        bias: torch.Tensor | None = None,
    ) -> torch.Tensor:  # -> (B, out, H', W')
        """``weight`` and ``bias`` (default: the layer's own) as :func:`fold_affine` gives them."""
        if self.in_channels % len(frames):
            raise ValueError(
                f"{self.in_channels} input channels do not split into {len(frames)} frames"
            )
        weight = self.weight if weight is None else weight
        bias = self.bias if bias is None else bias
        weights = weight.split(self.in_channels // len(frames), dim=1)
        out = functional.conv2d(frames[0], weights[0], bias, self.stride)
        for frame, weight in zip(frames[1:], weights[1:], strict=True):
            out = out + functional.conv2d(frame, weight, None, self.stride)
        return out


def fold_affine(
    conv: nn.Conv2d, scale: torch.Tensor, shift: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """``conv``'s weight and bias with a per-channel affine map of its input folded in: the
    input x * scale + shift (scale, shift (in_channels,)) convolved with the layer equals x
    convolved with these. Exact in arithmetic, as ``conv`` has no padding; gradients reach
    scale and shift without the gradient by the layer's input (84x84 a frame)."""
    if conv.padding not in ((0, 0), "valid"):
        raise ValueError(f"an affine map folds into an unpadded convolution, not {conv}")
    scale, shift = scale.view(1, -1, 1, 1), shift.view(1, -1, 1, 1)
    return conv.weight * scale, conv.bias + (conv.weight * shift).sum((1, 2, 3))


def batch_statistics(frame: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """frame (B, C, H, W) -> each channel's mean and biased variance (C,), from the sums of x
    and x^2 in float32 (the frames are bounded, so no cancellation to fear), read where a
    channels-last frame lies: (B*H*W, C), a view. A float16 or bfloat16 frame is summed as it
    is, in float32, without a float32 copy of it (its sum of squares through the norm, to
    ~1e-5 of the variance: the frame itself holds ~3 digits)."""
    x = frame.permute(0, 2, 3, 1).reshape(-1, frame.shape[1])  # (B*H*W, C)
    n = x.shape[0]
    mean = x.sum(0, dtype=torch.float32) / n
    if x.dtype == torch.float32:
        square = (x * x).sum(0) / n
    else:
        square = torch.linalg.vector_norm(x, dim=0, dtype=torch.float32).square() / n
    return mean, (square - mean * mean).clamp_min(0.0)


def _frame_key(frame: torch.Tensor) -> tuple:
    """What makes two tensors the same frame for :meth:`PAACNetwork._frame_statistics`."""
    return frame.data_ptr(), frame.shape, frame.stride(), frame.dtype, frame._version


class PAACNetwork(nn.Module):
    """(obs, h, c, is_init) -> (logits, value, h', c'); obs (..., C, 84, 84), C = ``in_channels``,
    or ``frames`` frames (..., C / frames, 84, 84), oldest first.

    ``input_norm``: ``raw`` frames as the env gives them, ``centred`` (minus 0.5), or
    ``batchnorm`` (each frame channel normalised by the batch's statistics in training mode,
    as the authors' code did with TensorFlow's ``batch_norm``, so acting normalises by its batch
    of envs; in eval mode, as evaluation plays, by the running statistics training kept).

    ``precision``: ``bfloat16`` runs the convolutions and matrix products under bfloat16
    autocast (:mod:`edr.models.precision`); the outputs, parameters and gradients stay float32.
    """

    def __init__(
        self,
        in_channels: int,
        num_actions: int,
        core: Core = "lstm",
        hidden: int = 256,
        init: Init = "orthogonal",
        input_norm: InputNorm = "raw",
        frames: int = 1,
        precision: Precision = "float32",
    ) -> None:
        super().__init__()
        self.precision = precision
        if in_channels % frames:
            raise ValueError(f"{in_channels} input channels do not split into {frames} frames")
        if core == "lenet_ftlstm" and frames != 1:
            raise ValueError(
                f"core=lenet_ftlstm reads one frame per step (its LSTM holds the past), got {frames}"
            )
        self.input_norm = input_norm
        if input_norm == "batchnorm":
            self.normalise = nn.BatchNorm2d(in_channels // frames)
        # the last call's frames' batch statistics, by _frame_key (_frame_statistics)
        self._last_statistics: dict[tuple, tuple[torch.Tensor, ...]] = {}
        self._last_frames: list[torch.Tensor] = []
        if core == "lenet_ftlstm":
            self.trunk: nn.Sequential = LeNet(in_channels, AUTHORS_WIDTHS)
        else:
            self.trunk = nn.Sequential(
                FramesConv(in_channels, 16, 8, stride=4),
                nn.ReLU(),
                nn.Conv2d(16, 32, 4, stride=2),
                nn.ReLU(),
            )
        self.trunk.to(memory_format=torch.channels_last)  # ~3x faster convolutions on CPU
        self.core_type = core
        with torch.no_grad(), autocast(precision):  # the trunk's own dtype (bfloat16 frames)
            probe = [torch.zeros(2, in_channels // frames, 84, 84)] * frames
            _, channels, h, w = self._maps(probe).shape
        self.channels, self.locations = channels, h * w
        if core in ("ftlstm", "lenet_ftlstm"):
            self.state_size = channels * h * w
            self.cell: nn.Module = FeatureTrackingLSTMCell(channels, h * w)
            features = self.state_size
            if core == "lenet_ftlstm":  # FC 512 on the LSTM's output
                self.embed = nn.Sequential(nn.Linear(features, AUTHORS_HIDDEN), nn.ReLU())
                features = AUTHORS_HIDDEN
        else:
            self.embed = nn.Sequential(nn.Flatten(), nn.Linear(channels * h * w, hidden), nn.ReLU())
            self.state_size = hidden if core == "lstm" else 1
            self.cell = nn.LSTMCell(hidden, hidden) if core == "lstm" else nn.Identity()
            features = hidden
        self.policy = nn.Linear(features, num_actions)
        self.value = nn.Linear(features, 1)
        self._init_weights(init)

    def _init_weights(self, init: Init) -> None:
        """``orthogonal``: orthogonal weights, zero biases (as OpenAI's A2C): gain sqrt(2)
        before a ReLU, 0.01 for the policy (it starts uniform, its logits not a random function
        of the frame) and 1 for the value. ``fan_in``: weights and biases uniform in
        +-1/sqrt(fan_in), as PAAC's and the paper's TensorFlow code. The recurrent cells keep
        their own initialisation."""
        relu_layers = [m for m in (*self.trunk, *getattr(self, "embed", ())) if m._parameters]
        for layer, gain in [*((m, math.sqrt(2)) for m in relu_layers), (self.policy, 0.01),
                            (self.value, 1.0)]:  # fmt: skip
            # via a contiguous tensor: the trunk's weights are channels-last
            weight, bias = torch.empty(layer.weight.shape), torch.zeros(layer.bias.shape)
            if init == "orthogonal":
                nn.init.orthogonal_(weight, gain)
            else:
                bound = 1 / math.sqrt(weight[0].numel())  # fan_in: inputs to one unit
                nn.init.uniform_(weight, -bound, bound)
                nn.init.uniform_(bias, -bound, bound)
            with torch.no_grad():
                layer.weight.copy_(weight)
                layer.bias.copy_(bias)

    def _maps(self, frames: list[torch.Tensor]) -> torch.Tensor:
        """The trunk's feature maps (B, F, h, w) of the frames [(B, C, 84, 84)] * n; observations
        may come as float16 or bfloat16, and go channels-last as the trunk."""
        if self.input_norm == "batchnorm":
            return self._normalised_maps(frames)
        frames = [self._as_input(f) for f in frames]
        if self.input_norm == "centred":
            frames = [f - 0.5 for f in frames]
        if self.core_type == "lenet_ftlstm":
            return self.trunk(frames[-1])  # (B, 16, 18, 18)
        return self.trunk(frames)  # (B, 32, 9, 9)

    def _normalised_maps(self, frames: list[torch.Tensor]) -> torch.Tensor:
        """:meth:`_maps` of the frames batch-normalised as ``self.normalise`` would, each by
        its own batch statistics (or the running ones in eval mode), with the whole
        normalisation folded into the first convolution (:func:`fold_affine`): the same function
        and gradients (the frames are constants), without conv1's gradient by its input nor a
        normalised copy of every frame; an update ~3x faster than the module's way."""
        bn = self.normalise
        statistics = self._frame_statistics(frames) if bn.training else None
        scales, shifts = [], []
        for k, frame in enumerate(frames):
            if statistics is not None:
                mean, var = statistics[k]
                self._track(mean, var, frame.numel() // frame.shape[1])
            else:
                mean, var = bn.running_mean, bn.running_var
            scale = bn.weight * torch.rsqrt(var + bn.eps)
            scales.append(scale)
            shifts.append(bn.bias - mean * scale)
        first, *rest = self.trunk
        frames = [self._as_input(f) for f in frames]
        if self.core_type == "lenet_ftlstm":
            weight, bias = fold_affine(first, scales[-1], shifts[-1])
            maps = functional.conv2d(frames[-1], weight, bias, first.stride)
        else:
            maps = first(frames, *fold_affine(first, torch.cat(scales), torch.cat(shifts)))
        for layer in rest:
            maps = layer(maps)
        return maps  # (B, 32, 9, 9); lenet_ftlstm (B, 16, 18, 18)

    def _as_input(self, frame: torch.Tensor) -> torch.Tensor:
        """A frame as the trunk convolves it: channels-last, in the dtype it computes in (float32,
        or bfloat16 under bfloat16 autocast, where a bfloat16 frame goes in as it is)."""
        dtype = torch.bfloat16 if self.precision == "bfloat16" else torch.float32
        return frame.to(dtype, memory_format=torch.channels_last)

    def _frame_statistics(self, frames: list[torch.Tensor]) -> list[tuple[torch.Tensor, ...]]:
        """Each frame's :func:`batch_statistics`. A frame the last call also saw takes the
        statistics that call computed (the same numbers): an env step moves the stack on by one
        frame, so 3 of 4 were seen. "Saw": the same memory, shape and strides, no torch write
        since (its version) and no gradient. A frame the env rewrites in place outside torch
        must have left the stack first, as the env's frame ring guarantees (``ObservationFrame``)."""
        last, kept, statistics = self._last_statistics, {}, []
        for frame in frames:
            if frame.requires_grad:  # its statistics carry a gradient: never shared
                statistics.append(batch_statistics(frame))
                continue
            key = _frame_key(frame)
            if key not in kept:
                kept[key] = last.get(key) or batch_statistics(frame)
            statistics.append(kept[key])
        self._last_statistics = kept
        self._last_frames = frames  # their memory stays theirs while the keys name it
        return statistics

    @torch.no_grad()
    def _track(self, mean: torch.Tensor, var: torch.Tensor, n: int) -> None:
        """Update the running statistics as BatchNorm2d does (momentum, unbiased variance)."""
        bn = self.normalise
        bn.num_batches_tracked.add_(1)
        bn.running_mean.lerp_(mean, bn.momentum)
        bn.running_var.lerp_(var * n / max(n - 1, 1), bn.momentum)

    def _step(
        self, frames: list[torch.Tensor], h: torch.Tensor, c: torch.Tensor
    ) -> tuple[torch.Tensor, ...]:
        maps = self._maps(frames)
        if self.core_type in ("ftlstm", "lenet_ftlstm"):
            h, c = self.cell(maps.flatten(2), (h, c))
            features = h if self.core_type == "ftlstm" else self.embed(h)
        elif self.core_type == "lstm":
            h, c = self.cell(self.embed(maps), (h, c))
            features = h
        else:
            features = self.embed(maps)
        return self.policy(features), self.value(features), h, c

    def forward(
        self,
        obs: torch.Tensor | Sequence[torch.Tensor],
        h: torch.Tensor,
        c: torch.Tensor,
        is_init: torch.Tensor,
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        """One step of any batch of envs: obs (..., C, H, W) or n frames (..., C / n, H, W),
        h and c (..., S), is_init (..., 1) -> logits (..., A), value (..., 1), h' and c' (..., S)."""
        frames = [obs] if isinstance(obs, torch.Tensor) else list(obs)
        batch = frames[0].shape[:-3]
        keep = (~is_init.reshape(-1, 1)).to(h.dtype)  # a new episode starts from zeros
        flat_h, flat_c = h.reshape(-1, h.shape[-1]) * keep, c.reshape(-1, c.shape[-1]) * keep
        with autocast(self.precision):
            out = self._step([f.reshape(-1, *f.shape[-3:]) for f in frames], flat_h, flat_c)
        return tuple(o.float().reshape(*batch, o.shape[-1]) for o in out)
