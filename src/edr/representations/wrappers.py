"""EDR (or any representation) outside this suite's tasks: a gymnasium wrapper, a clip transform."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
import torch

from edr.representations.base import Representation, check_clip
from edr.representations.edr import EDR, EDRState


class EDRObservation(gym.ObservationWrapper):
    """Streams an image-observation env through EDR: obs (H, W) or (H, W, C) uint8 ->
    (C' * 2 * K', H, W) float32 events. The EMA carries across steps and restarts on reset.
    """

    def __init__(self, env: gym.Env, edr: EDR | None = None) -> None:
        super().__init__(env)
        space = env.observation_space
        if not isinstance(space, gym.spaces.Box) or len(space.shape) not in (2, 3):
            raise ValueError(f"EDRObservation needs an image Box space (H, W[, C]), got {space}")
        self.edr = edr if edr is not None else EDR()
        h, w = space.shape[:2]
        c = space.shape[2] if len(space.shape) == 3 else 1
        if c not in (1, 3):
            raise ValueError(f"observations need 1 or 3 channels, got {c}")
        self.observation_space = gym.spaces.Box(
            0.0, np.inf, (self.edr.out_channels(c), h, w), np.float32
        )
        self._state: EDRState | None = None

    def reset(self, **kwargs: Any) -> tuple[np.ndarray, dict[str, Any]]:
        self._state = None
        return super().reset(**kwargs)

    def observation(self, observation: np.ndarray) -> np.ndarray:
        frame = torch.from_numpy(np.ascontiguousarray(observation))
        frame = frame.unsqueeze(0) if frame.dim() == 2 else frame.permute(2, 0, 1)  # (C, H, W)
        with torch.no_grad():
            events, self._state = self.edr.step(frame.unsqueeze(0), self._state, inplace=True)
        return events[0].numpy()


class ClipTransform:
    """A video transform for any pipeline: (T, C, H, W) clip -> (T', C_out, H, W).

    Stateless per clip: every call starts the representation afresh (EDR's EMA from the clip's
    first frame), so clips can be transformed in any order, in any worker.
    """

    def __init__(self, representation: Representation) -> None:
        self.representation = representation

    def __call__(self, clip: torch.Tensor) -> torch.Tensor:
        if not isinstance(clip, torch.Tensor) or clip.dim() != 4:
            shape = tuple(clip.shape) if isinstance(clip, torch.Tensor) else type(clip).__name__
            raise ValueError(f"clip must be a (T, C, H, W) tensor, got {shape}")
        batch = clip.unsqueeze(0)
        check_clip(batch, name="clip")
        with torch.no_grad():
            return self.representation(batch)[0]

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.representation!r})"
