"""Streaming torchrl transforms for the Atari observation: EDR events and a frame stack.

Both carry one state per env across agent steps and restart it exactly where an env resets: on
a partial reset only the envs whose ``_reset`` flag is set restart from their new first input;
the others keep their state and their last output. EDR's EMA therefore runs across steps (the
authors' code restarted it at every step).
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from typing import Any

import torch
from tensordict import TensorDictBase
from torchrl.data import Composite, Unbounded
from torchrl.envs.transforms import Transform
from torchrl.envs.transforms.utils import _get_reset

from edr.representations import EDR, EDRState


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


class EDRTransform(_PerEnvStream):
    """Pixels (..., H, W, C) uint8 (``channels_last``) or (..., C, H, W) -> EDR events
    (..., C' * 2 * K', H, W) float32 under ``out_keys``; the pixels stay as they are."""

    def __init__(
        self,
        edr: EDR | None = None,
        in_keys: Sequence[str] = ("pixels",),
        out_keys: Sequence[str] = ("edr",),
        channels_last: bool = True,
    ) -> None:
        super().__init__(in_keys, out_keys)
        if len(self.in_keys) != 1:
            raise ValueError(f"EDRTransform reads one in_key, got {self.in_keys}")
        self.edr = edr if edr is not None else EDR(color="gray")
        self.channels_last = channels_last
        self._state: EDRState | None = None  # ema (N, C', K, H, W)

    def _input(self, tensordict: TensorDictBase) -> torch.Tensor:
        """-> frames (N, C, H, W), a view of the pixels."""
        pixels = tensordict.get(self.in_keys[0])
        if self.channels_last:
            pixels = pixels.movedim(-1, -3)
        return pixels.reshape(-1, *pixels.shape[-3:])

    def _restart(self, x: torch.Tensor, rows: torch.Tensor | None) -> torch.Tensor:
        if rows is None or self._state is None:
            events, self._state = self.edr.step(x)
            return events
        events, state = self.edr.step(x[rows])
        self._state.ema[rows] = state.ema
        return events

    def _advance(self, x: torch.Tensor) -> torch.Tensor:
        events, self._state = self.edr.step(x, self._state, inplace=True)  # its own buffer
        return events

    def transform_observation_spec(self, observation_spec: Composite) -> Composite:
        pixels = observation_spec[self.in_keys[0]]
        shape = pixels.shape
        c, h, w = (shape[-1], shape[-3], shape[-2]) if self.channels_last else shape[-3:]
        observation_spec[self.out_keys[0]] = Unbounded(
            shape=(*shape[:-3], self.edr.out_channels(c), h, w),
            dtype=torch.float32,
            device=pixels.device,
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
        if ring is not None and ring < 2:
            raise ValueError(f"FrameStack's ring needs 2 buffers or more (None: none), got {ring}")
        self.n = n
        self.dtype = dtype  # of the stack; None: the inputs' promoted dtype
        self.ring = ring
        self._ring_stacks: list[torch.Tensor] = []  # the ring's, each (N, n * C, H, W)
        self._turn = 0  # the ring's buffer written last

    def _spare(self) -> torch.Tensor:
        """An unwritten stack like the last one: a new tensor, or the ring's next buffer."""
        if self.ring is None:
            return torch.empty_like(self._last)  # channels-last, as the last
        if self._ring_stacks and self._ring_stacks[0].shape != self._last.shape:  # another batch
            self._ring_stacks = []
        self._turn = (self._turn + 1) % self.ring
        if self._turn >= len(self._ring_stacks):
            self._turn = len(self._ring_stacks)
            self._ring_stacks.append(torch.empty_like(self._last))
        return self._ring_stacks[self._turn]

    def _input(self, tensordict: TensorDictBase) -> list[torch.Tensor]:
        """-> one (N, C_i, H, W) tensor per in_key."""
        parts = (tensordict.get(key) for key in self.in_keys)
        return [p.reshape(-1, *p.shape[-3:]) for p in parts]

    def _restart(self, x: list[torch.Tensor], rows: torch.Tensor | None) -> torch.Tensor:
        frame = torch.cat(x if rows is None else [p[rows] for p in x], dim=1)
        stack = frame.repeat(1, self.n, 1, 1)
        return stack.to(self.dtype or frame.dtype, memory_format=torch.channels_last)

    def _advance(self, x: list[torch.Tensor]) -> torch.Tensor:
        stack = self._spare()  # not the last's memory: it is read here and may live on
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
