"""N gymnasium envs stepped one after another in the training process, as one batched torchrl
env (``task.env.backend=batch``, what ``auto`` gives a user's own game).

It gives what torchrl's ``SerialEnv`` of ``GymWrapper``s gives (the ``serial`` backend): the same
frames, rewards and ends for the same seed, each env seeded by a seeded reset along torchrl's
chain of seeds, an env reset only where torchrl flags it (tests/test_own_game_streams.py). It
skips their per-env tensordicts and spec checks, which on the screening games cost several
times the game's own step (docs/own_game.md, "Where a run's time goes").
"""

from __future__ import annotations

from collections.abc import Callable

import gymnasium as gym
import numpy as np
import torch
from tensordict import TensorDict, TensorDictBase
from torchrl._utils import seed_generator
from torchrl.data import Bounded, Categorical, Composite, OneHot, Unbounded
from torchrl.envs import EnvBase


class GymBatch(EnvBase):
    """``num_envs`` gymnasium envs made by ``make`` (image observations (H, W, C) uint8,
    ``Discrete`` actions) as one torchrl env: ``pixels`` (N, H, W, C) uint8, a new array each
    step (earlier frames may live on in collected data), rewards (N, 1) float32 as the envs give
    them, ``done`` = ``terminated`` | ``truncated``; actions one-hot (N, A)."""

    def __init__(self, make: Callable[[], gym.Env], num_envs: int) -> None:
        super().__init__(batch_size=torch.Size([num_envs]))
        self._envs = [make() for _ in range(num_envs)]
        frame, actions = self._envs[0].observation_space.shape, int(self._envs[0].action_space.n)
        self._pixels = np.zeros((num_envs, *frame), np.uint8)  # (N, H, W, C) the latest frames
        n = (num_envs,)
        self.observation_spec = Composite(
            pixels=Bounded(0, 255, shape=(*n, *frame), dtype=torch.uint8), shape=n
        )
        self.action_spec = OneHot(actions, shape=(*n, actions), dtype=torch.int64)  # as serial's
        self.reward_spec = Unbounded(shape=(*n, 1))
        flag = Categorical(2, shape=(*n, 1), dtype=torch.bool)
        self.done_spec = Composite(
            done=flag, terminated=flag.clone(), truncated=flag.clone(), shape=n
        )

    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs) -> TensorDictBase:
        mask = tensordict.get("_reset", None) if tensordict is not None else None
        if mask is None or mask.all():
            self._pixels = np.stack([env.reset()[0] for env in self._envs])
        else:
            self._pixels = self._pixels.copy()  # earlier frames may live on in collected data
            for row in mask.reshape(-1).nonzero().squeeze(1).tolist():
                self._pixels[row] = self._envs[row].reset()[0]
        out = TensorDict({"pixels": torch.from_numpy(self._pixels)}, batch_size=self.batch_size)
        return out.update(self.full_done_spec.zero())

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        actions = tensordict.get("action").long().argmax(-1).numpy()  # one-hot -> index, int64
        steps = [env.step(action) for env, action in zip(self._envs, actions, strict=True)]
        frames, rewards, terminated, truncated, _ = zip(*steps, strict=True)
        self._pixels = np.stack(frames)
        terminated = torch.tensor(terminated, dtype=torch.bool).reshape(-1, 1)
        truncated = torch.tensor(truncated, dtype=torch.bool).reshape(-1, 1)
        return TensorDict(
            {
                "pixels": torch.from_numpy(self._pixels),
                # + 0.0: a reward of -0.0 becomes 0.0, as the serial backend gives it
                "reward": torch.tensor(rewards, dtype=torch.float32).reshape(-1, 1) + 0.0,
                "done": terminated | truncated,
                "terminated": terminated,
                "truncated": truncated,
            },
            batch_size=self.batch_size,
        )

    def set_seed(self, seed: int | None = None, static_seed: bool = False) -> int | None:
        """Seed env i by a reset with the i-th seed of torchrl's chain from ``seed`` (as a
        ``SerialEnv`` of ``GymWrapper``s does); the next seed of the chain."""
        for env in self._envs:
            env.reset(seed=seed)
            if seed is not None and not static_seed:
                seed = seed_generator(seed)
        return seed

    def _set_seed(self, seed: int | None) -> None:
        self.set_seed(seed)

    def close(self, *, raise_if_closed: bool = True) -> None:
        for env in self._envs:
            env.close()
        self._envs = []
        super().close(raise_if_closed=raise_if_closed)
