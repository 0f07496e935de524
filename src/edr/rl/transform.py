"""Streaming torchrl transforms for the Atari observation: its frame (FDR and EDR's events, in
one pass) and a frame stack.

Both carry one state per env across agent steps and restart it exactly where an env resets: on
a partial reset only the envs whose ``_reset`` flag is set restart from their new first input;
the others keep their state and their last output. EDR's EMA therefore runs across steps (the
authors' code restarted it at every step).
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
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
    float32, channels-last in memory (as the PAAC trunk convolves it): FDR (``fdr``: the RGB
    pixels / 255, their luma / 255, or none) then EDR's events (``edr``; its EMA runs per env),
    written in one pass over the pixels by ``kernels.frame_kernel``, on the calling thread.

    One pass where FDR's conversion, EDR's step and joining the two took three, each with its
    own torch ops; each pixel's channels stored together, at a stride numba compiles in (16 Pong
    envs: the frame with EDR 0.22 ms, without 0.11 ms; before, 0.36 and 0.14).
    Pixels other than uint8, or an EDR the kernel cannot run (``fast=False``, learnable,
    float64), take torch's path, to the same numbers. ``keep_parts`` also writes ``fdr`` and
    ``edr``: views of the frame's channels. ``ring=k``: the frames cycle through ``k`` buffers
    (see :class:`FrameStack`).
    """

    def __init__(
        self,
        fdr: Literal["rgb", "gray", "none"] = "rgb",
        edr: EDR | None = None,
        in_key: str = "pixels",
        out_key: str = "observation",
        keep_parts: bool = False,
        ring: int | None = None,
    ) -> None:
        super().__init__([in_key], [out_key])
        if fdr not in ("rgb", "gray", "none"):
            raise ValueError(f"fdr must be rgb, gray or none, got {fdr!r}")
        if fdr == "none" and edr is None:
            raise ValueError("the observation needs FDR, EDR or both")
        self.fdr, self.edr, self.keep_parts = fdr, edr, keep_parts
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
            out = torch.empty(n, c_fdr + c_edr, h, w, memory_format=torch.channels_last)
        else:
            out = self._ring.next(self._last)
        if x.dtype != torch.uint8 or (self.edr is not None and not self.edr.can_fuse(x)):
            self._torch_frame(x, ema, restart, out)
            return out
        planar = c_in == 1 or not x.permute(0, 2, 3, 1).is_contiguous()
        pixels = x.contiguous().view(n, 1, c_in, h * w) if planar else (
            x.permute(0, 2, 3, 1).view(n, 1, 1, h * w * c_in))  # fmt: skip
        kernels.launch(
            kernels.frame_kernel, n * h * w, pixels.numpy(), 0 if planar else c_in, (0,) * c_fdr,
            self.fdr == "gray" and c_in == 3, (0,) * c_edr,
            *(self.edr.kernel_args(c_in) if self.edr is not None else KernelArgs.unused()),
            ema.numpy(),
            restart, out.permute(0, 2, 3, 1).view(n, h * w * (c_fdr + c_edr)).numpy(),
        )  # fmt: skip
        increment_version(out)  # written through numpy: autograd must see a ring buffer's reuse
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
                    shape=(*batch, channels, h, w), dtype=torch.float32, device=pixels.device
                )
        return observation_spec


class FrameStack(_PerEnvStream):
    """The images under ``in_keys`` (each (..., C_i, H, W)) concatenated on the channel axis and
    stacked over the last ``n`` steps, oldest first -> ``out_key`` (..., n * sum(C_i), H, W).

    An env that (re)starts repeats its first frame ``n`` times (as ``CatFrames(padding="same")``).
    The stack is channels-last in memory, as the PAAC trunk convolves it (no copy there).
    ``dtype=torch.float16`` halves the bytes each step writes (the network converts it back).
    Each step writes one new stack in one pass, where torchrl's ``CatTensors`` then ``CatFrames``
    take five (cat; roll, copy, write, clone) and three allocations. The inputs stay as they are.

    ``ring=k`` writes the stacks into ``k`` buffers in turn instead of a new tensor each step
    (16 Pong envs, 20 channels: ~1 ms less per step, the page faults of a fresh 9 MB tensor),
    so a stack is overwritten ``k`` steps after it was emitted: whoever holds stacks longer
    must copy them. Autograd guards a network that saved one: its backward then fails
    ("modified by an inplace operation") rather than use the wrong frames.
    """

    def __init__(
        self,
        n: int,
        in_keys: Sequence[str] = ("observation",),
        out_key: str = "observation",
        dtype: torch.dtype | None = None,
        ring: int | None = None,
    ) -> None:
        super().__init__(in_keys, [out_key])
        if n < 1:
            raise ValueError(f"FrameStack needs n >= 1, got {n}")
        self.n = n
        self.dtype = dtype  # of the stack; None: the inputs' promoted dtype
        self._ring = _Ring(ring)  # each (N, n * C, H, W)

    def _input(self, tensordict: TensorDictBase) -> list[torch.Tensor]:
        """-> one (N, C_i, H, W) tensor per in_key."""
        parts = (tensordict.get(key) for key in self.in_keys)
        return [p.reshape(-1, *p.shape[-3:]) for p in parts]

    def _restart(self, x: list[torch.Tensor], rows: torch.Tensor | None) -> torch.Tensor:
        frame = torch.cat(x if rows is None else [p[rows] for p in x], dim=1)
        stack = frame.repeat(1, self.n, 1, 1)
        return stack.to(self.dtype or frame.dtype, memory_format=torch.channels_last)

    def _advance(self, x: list[torch.Tensor]) -> torch.Tensor:
        stack = self._ring.next(self._last)  # not the last's memory: it is read here
        start = stack.shape[1] - sum(p.shape[1] for p in x)  # where the newest frame begins
        stack[:, :start] = self._last[:, stack.shape[1] - start :]
        for part in x:
            stack[:, start : start + part.shape[1]] = part
            start += part.shape[1]
        return stack

    def transform_observation_spec(self, observation_spec: Composite) -> Composite:
        specs = [observation_spec[key] for key in self.in_keys]
        first = specs[0]
        channels = self.n * sum(spec.shape[-3] for spec in specs)
        dtype = self.dtype or functools.reduce(torch.promote_types, (s.dtype for s in specs))
        observation_spec[self.out_keys[0]] = Unbounded(
            shape=(*first.shape[:-3], channels, *first.shape[-2:]), dtype=dtype, device=first.device
        )
        return observation_spec
