"""The streaming torchrl transform of the Atari observation: its frame, FDR and EDR's events
written in one pass.

It carries one state per env across agent steps and restarts it exactly where an env resets: on
a partial reset only the envs whose ``_reset`` flag is set restart from their new first input;
the others keep their state and their last output. EDR's EMA therefore runs across steps (the
authors' code restarted it at every step). The frames are not stacked here: the network's
window of the last frames is :class:`edr.rl.rollout.Actor`'s.
"""

from __future__ import annotations

from collections.abc import Sequence
from contextlib import nullcontext
from typing import Any, Literal

import numpy as np
import torch
from tensordict import TensorDictBase
from torch.autograd.graph import increment_version
from torchrl.data import Composite, Unbounded
from torchrl.envs.transforms import Transform
from torchrl.envs.transforms.utils import _get_reset

from edr.representations import EDR, EDRState, kernels
from edr.representations.base import to_float, to_gray
from edr.representations.edr import KernelArgs
from edr.rl.phases import PhaseClock


class _PerEnvStream(Transform):
    """Image keys (..., 3 image dims) -> one image under ``out_keys[0]``, with a state per env.

    Subclasses read their input (``_input``) and say how envs start (``_restart``) and how every
    env moves on by one step (``_advance``), on batches flattened to N = all batch dims.
    """

    def __init__(self, in_keys: Sequence[str], out_keys: Sequence[str]) -> None:
        super().__init__(in_keys=list(in_keys), out_keys=list(out_keys))
        if len(self.out_keys) != 1:
            raise ValueError(f"{type(self).__name__} writes one out_key, got {self.out_keys}")
        self._last: torch.Tensor | None = None  # (N, ...) the latest output
        self.clock: PhaseClock | None = None  # set by a training loop that times its phases

    @property
    def reset_key(self) -> str:
        """The env's partial-reset flag (``_reset`` for a plain or batched env)."""
        return self.parent.reset_keys[0] if self.parent is not None else "_reset"

    def _input(self, tensordict: TensorDictBase) -> Any:
        """What ``_restart`` and ``_advance`` read, from the tensordict; rows flattened to N."""
        raise NotImplementedError

    def _restart(self, x: Any, rows: torch.Tensor | None) -> torch.Tensor:
        """Start the envs ``rows`` (all when None) from input ``x``; their first outputs."""
        raise NotImplementedError

    def _advance(self, x: Any) -> torch.Tensor:
        """Every env one step on with input ``x``; the new outputs (N, ...)."""
        raise NotImplementedError

    def _fresh(self, tensordict: TensorDictBase) -> bool:
        """Whether there is no state yet for this tensordict's envs."""
        return self._last is None or self._last.shape[0] != tensordict.batch_size.numel()

    def _emit(self, tensordict: TensorDictBase, out: torch.Tensor) -> TensorDictBase:
        tensordict.set(self.out_keys[0], out.reshape(*tensordict.batch_size, *out.shape[1:]))
        return tensordict

    @torch.no_grad()
    def _call(self, next_tensordict: TensorDictBase) -> TensorDictBase:
        with self.clock.phase("observation") if self.clock else nullcontext():
            x = self._input(next_tensordict)
            fresh = self._fresh(next_tensordict)
            self._last = self._restart(x, None) if fresh else self._advance(x)
        return self._emit(next_tensordict, self._last)

    @torch.no_grad()
    def _reset(
        self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase
    ) -> TensorDictBase:
        x = self._input(tensordict_reset)
        mask = _get_reset(self.reset_key, tensordict).reshape(-1)
        if self._fresh(tensordict_reset) or mask.all():
            self._last = self._restart(x, None)
        elif mask.any():
            rows = mask.nonzero().squeeze(1)
            last = self._last.clone()  # earlier outputs may live on in collected data
            last[rows] = self._restart(x, rows)
            self._last = last
        return self._emit(tensordict_reset, self._last)

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        raise NotImplementedError(
            f"{type(self).__name__} is stateful and streams through an env's steps and resets; "
            "for stored clips use edr.representations.EDR (or ClipTransform) on (B, T, C, H, W)"
        )


class _Ring:
    """``k`` output buffers handed out in turn (None: a new tensor each time), so that a stream
    writes its step into memory it owns; each is overwritten ``k`` steps after it was handed out."""

    def __init__(self, k: int | None) -> None:
        if k is not None and k < 2:
            raise ValueError(f"a ring needs 2 buffers or more (None: none), got {k}")
        self.k = k
        self._buffers: list[torch.Tensor] = []
        self._turn = 0  # the buffer handed out last

    def next(self, like: torch.Tensor) -> torch.Tensor:
        """An unwritten tensor like ``like`` (its shape, dtype and memory format)."""
        if self.k is None:
            return torch.empty_like(like)
        if self._buffers and self._buffers[0].shape != like.shape:  # another batch
            self._buffers = []
        self._turn = (self._turn + 1) % self.k
        if self._turn >= len(self._buffers):
            self._turn = len(self._buffers)
            self._buffers.append(torch.empty_like(like))
        return self._buffers[self._turn]


class ObservationFrame(_PerEnvStream):
    """Pixels (..., H, W, 3) uint8, as envs give them -> one observation frame (..., C, H, W)
    float32 (or ``dtype``), channels-last in memory (as the PAAC trunk convolves it): FDR
    (``fdr``: the RGB pixels / 255, their luma / 255, or none) then EDR's events (``edr``; its
    EMA runs per env), written in one pass over the pixels by ``kernels.frame_kernel``, on the
    calling thread, each pixel's channels stored together.

    Pixels other than uint8, or an EDR the kernel cannot run (``fast=False``, learnable,
    float64), take torch's path, to the same numbers. ``dtype=torch.float16`` halves the bytes
    each step hands on (the frame is computed in float32, then rounded; the network converts it
    back); ``torch.bfloat16`` is what a network computing in bfloat16 takes as it is. ``keep_parts`` also writes ``fdr`` and ``edr``: views of the frame's channels.

    ``ring=k`` writes the frames into ``k`` buffers in turn instead of a new tensor each step
    (the page faults of a fresh tensor each step), so a frame is overwritten ``k`` steps after it
    was emitted: whoever holds frames longer must copy them. Autograd guards a network that saved
    one: its backward then fails ("modified by an inplace operation") rather than use the wrong
    frame.
    """

    def __init__(
        self,
        fdr: Literal["rgb", "gray", "none"] = "rgb",
        edr: EDR | None = None,
        in_key: str = "pixels",
        out_key: str = "observation",
        keep_parts: bool = False,
        ring: int | None = None,
        dtype: torch.dtype = torch.float32,
    ) -> None:
        super().__init__([in_key], [out_key])
        if dtype not in (torch.float32, torch.float16, torch.bfloat16):
            raise ValueError(f"the frame's dtype must be float32, float16 or bfloat16, got {dtype}")
        if fdr not in ("rgb", "gray", "none"):
            raise ValueError(f"fdr must be rgb, gray or none, got {fdr!r}")
        if fdr == "none" and edr is None:
            raise ValueError("the observation needs FDR, EDR or both")
        self.fdr, self.edr, self.keep_parts, self.dtype = fdr, edr, keep_parts, dtype
        self._ring = _Ring(ring)
        self._ema: torch.Tensor | None = None  # (N, C', K, H * W) EDR's state

    def _channels(self, pixel_channels: int) -> tuple[int, int]:
        """(FDR's, EDR's) channels for pixels of ``pixel_channels``."""
        fdr = {"rgb": pixel_channels, "gray": 1, "none": 0}[self.fdr]
        return fdr, self.edr.out_channels(pixel_channels) if self.edr is not None else 0

    def _input(self, tensordict: TensorDictBase) -> torch.Tensor:
        """-> pixels (N, C, H, W), a view (planar where the env's memory is)."""
        pixels = tensordict.get(self.in_keys[0]).movedim(-1, -3)
        return pixels.reshape(-1, *pixels.shape[-3:])

    def _frame(self, x: torch.Tensor, ema: torch.Tensor, restart: np.ndarray) -> torch.Tensor:
        """Frames (N, C, H, W) of pixels ``x``; EDR's state ``ema`` moves on in place (rows that
        ``restart`` start from these pixels). Every env advancing writes into the ring."""
        n, c_in, h, w = x.shape
        c_fdr, c_edr = self._channels(c_in)
        if restart.any() or self._last is None:
            out = torch.empty(
                n, c_fdr + c_edr, h, w, dtype=self.dtype, memory_format=torch.channels_last
            )
        else:
            out = self._ring.next(self._last)
        frame = out if out.dtype == torch.float32 else torch.empty_like(out, dtype=torch.float32)
        if x.dtype != torch.uint8 or (self.edr is not None and not self.edr.can_fuse(x)):
            self._torch_frame(x, ema, restart, frame)
        else:
            planar = c_in == 1 or not x.permute(0, 2, 3, 1).is_contiguous()
            pixels = x.contiguous().view(n, 1, c_in, h * w) if planar else (
                x.permute(0, 2, 3, 1).view(n, 1, 1, h * w * c_in))  # fmt: skip
            kernels.launch(
                kernels.frame_kernel, n * h * w, pixels.numpy(), 0 if planar else c_in,
                (0,) * c_fdr, self.fdr == "gray" and c_in == 3, (0,) * c_edr,
                *(self.edr.kernel_args(c_in) if self.edr is not None else KernelArgs.unused()),
                ema.numpy(),
                restart, frame.permute(0, 2, 3, 1).view(n, h * w * (c_fdr + c_edr)).numpy(),
            )  # fmt: skip
            increment_version(frame)  # written through numpy: autograd must see a ring's reuse
        if frame is not out:
            out.copy_(frame)
        return out

    def _torch_frame(
        self, x: torch.Tensor, ema: torch.Tensor, restart: np.ndarray, out: torch.Tensor
    ) -> None:
        c_fdr = self._channels(x.shape[1])[0]
        if self.fdr == "rgb":
            out[:, :c_fdr] = to_float(x) / 255
        elif self.fdr == "gray":
            out[:, :c_fdr] = to_gray(x, channel_dim=1) / 255
        if self.edr is None:
            return
        state = EDRState(ema.view(*ema.shape[:3], *x.shape[-2:]))
        events, new = self.edr.step(x, state, reset=torch.from_numpy(restart))
        out[:, c_fdr:] = events
        ema.copy_(new.ema.reshape(ema.shape))

    def _state_like(self, x: torch.Tensor) -> torch.Tensor:
        n, c_in, h, w = x.shape
        if self.edr is None:
            return torch.empty(n, 0, 1, h * w)
        return torch.empty(n, self.edr.state_channels(c_in), self.edr.k, h * w)

    def _restart(self, x: torch.Tensor, rows: torch.Tensor | None) -> torch.Tensor:
        if rows is None or self._ema is None:
            self._ema = self._state_like(x)
            return self._frame(x, self._ema, np.ones(x.shape[0], np.bool_))
        ema = self._state_like(x[rows])
        frame = self._frame(x[rows], ema, np.ones(rows.numel(), np.bool_))
        self._ema[rows] = ema
        return frame

    def _advance(self, x: torch.Tensor) -> torch.Tensor:
        return self._frame(x, self._ema, np.zeros(x.shape[0], np.bool_))

    def _emit(self, tensordict: TensorDictBase, out: torch.Tensor) -> TensorDictBase:
        super()._emit(tensordict, out)
        if self.keep_parts:
            frame = tensordict.get(self.out_keys[0])
            c_fdr = self._channels(tensordict.get(self.in_keys[0]).shape[-1])[0]
            if c_fdr:
                tensordict.set("fdr", frame[..., :c_fdr, :, :])
            if self.edr is not None:
                tensordict.set("edr", frame[..., c_fdr:, :, :])
        return tensordict

    def transform_observation_spec(self, observation_spec: Composite) -> Composite:
        pixels = observation_spec[self.in_keys[0]]
        *batch, h, w, c_in = pixels.shape
        c_fdr, c_edr = self._channels(c_in)
        parts = {self.out_keys[0]: c_fdr + c_edr}
        if self.keep_parts:
            parts.update({"fdr": c_fdr, "edr": c_edr})
        for key, channels in parts.items():
            if channels:
                observation_spec[key] = Unbounded(
                    shape=(*batch, channels, h, w), dtype=self.dtype, device=pixels.device
                )
        return observation_spec
