"""EDR as a torchrl ``Transform``: computed on the fly as the agent plays, one EMA per env.

The EMA carries across agent steps (the authors' code restarted it at every step) and restarts
exactly where an env resets: on a partial reset only the envs whose ``_reset`` flag is set
restart from their new first frame; the others keep their state and their last output.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from tensordict import TensorDictBase
from torchrl.data import Composite, Unbounded
from torchrl.envs.transforms import Transform
from torchrl.envs.transforms.utils import _get_reset

from edr.representations import EDR, EDRState


class EDRTransform(Transform):
    """Pixels (..., H, W, C) uint8 (``channels_last``) or (..., C, H, W) -> EDR events
    (..., C' * 2 * K', H, W) float32 under ``out_keys``; the pixels stay as they are."""

    def __init__(
        self,
        edr: EDR | None = None,
        in_keys: Sequence[str] = ("pixels",),
        out_keys: Sequence[str] = ("edr",),
        channels_last: bool = True,
    ) -> None:
        super().__init__(in_keys=list(in_keys), out_keys=list(out_keys))
        if len(self.in_keys) != 1 or len(self.out_keys) != 1:
            raise ValueError("EDRTransform takes one in_key and one out_key")
        self.edr = edr if edr is not None else EDR(color="gray")
        self.channels_last = channels_last
        self._state: EDRState | None = None  # ema (N, C', K, H, W), N = all batch dims flattened
        self._last: torch.Tensor | None = None  # (N, C_out, H, W), the latest output

    @property
    def reset_key(self) -> str:
        """The env's partial-reset flag (``_reset`` for a plain or batched env)."""
        return self.parent.reset_keys[0] if self.parent is not None else "_reset"

    def _frames(self, tensordict: TensorDictBase) -> torch.Tensor:
        """(..., H, W, C) or (..., C, H, W) -> (N, C, H, W)."""
        pixels = tensordict.get(self.in_keys[0])
        if self.channels_last:
            pixels = pixels.movedim(-1, -3)
        return pixels.reshape(-1, *pixels.shape[-3:])

    def _emit(self, tensordict: TensorDictBase, events: torch.Tensor) -> TensorDictBase:
        batch = tensordict.get(self.in_keys[0]).shape[:-3]
        tensordict.set(self.out_keys[0], events.reshape(*batch, *events.shape[1:]))
        return tensordict

    @torch.no_grad()
    def _call(self, next_tensordict: TensorDictBase) -> TensorDictBase:
        events, self._state = self.edr.step(self._frames(next_tensordict), self._state)
        self._last = events
        return self._emit(next_tensordict, events)

    @torch.no_grad()
    def _reset(
        self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase
    ) -> TensorDictBase:
        frames = self._frames(tensordict_reset)
        mask = _get_reset(self.reset_key, tensordict).reshape(-1)
        if self._state is None or mask.all() or self._state.ema.shape[0] != frames.shape[0]:
            self._last, self._state = self.edr.step(frames)
        elif mask.any():
            rows = mask.nonzero().squeeze(1)
            fresh, state = self.edr.step(frames[rows])
            self._state.ema[rows] = state.ema
            self._last = self._last.clone()  # earlier outputs may live on in collected data
            self._last[rows] = fresh
        return self._emit(tensordict_reset, self._last)

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

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        raise NotImplementedError(
            "EDRTransform is stateful and streams through an env's steps and resets; for stored "
            "clips use edr.representations.EDR (or ClipTransform) on (B, T, C, H, W) frames"
        )
