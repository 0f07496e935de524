"""A small image game for known-answer learning tests: catch the falling ball.

A ball falls from a random column of a ``size`` x ``size`` grid, one row per step; the paddle
on the bottom row moves left, stays or moves right. When the ball reaches the bottom row the
drop scores +1 (caught) or -1 (missed) and a new ball starts; an episode is ``drops`` drops.
Frames: 84x84 RGB uint8 (ball white, paddle green), so the agent sees it as it sees Atari.
Random play catches about 1 drop in ``size``; a policy that follows the ball catches them all.
Importing this module registers it as ``EdrCatch-v0``.
"""

from __future__ import annotations

from typing import ClassVar

import gymnasium as gym
import numpy as np

CELL = 12  # pixels per grid cell


class Catch(gym.Env):
    metadata: ClassVar[dict] = {"render_modes": []}

    def __init__(self, size: int = 5, drops: int = 4) -> None:
        self.size, self.drops = size, drops
        side = size * CELL
        self.observation_space = gym.spaces.Box(0, 255, (side, side, 3), np.uint8)
        self.action_space = gym.spaces.Discrete(3)  # left, stay, right

    def _frame(self) -> np.ndarray:
        frame = np.zeros(self.observation_space.shape, np.uint8)
        row, col = self.ball
        frame[row * CELL : (row + 1) * CELL, col * CELL : (col + 1) * CELL] = 255
        bottom = (self.size - 1) * CELL
        frame[bottom:, self.paddle * CELL : (self.paddle + 1) * CELL, 1] = 255
        return frame

    def _drop(self) -> None:
        self.ball = (0, int(self.np_random.integers(self.size)))

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        self.paddle, self.left = self.size // 2, self.drops
        self._drop()
        return self._frame(), {}

    def step(self, action: int):
        self.paddle = int(np.clip(self.paddle + int(action) - 1, 0, self.size - 1))
        row, col = self.ball
        self.ball = (row + 1, col)
        reward = 0.0
        if row + 1 == self.size - 1:
            reward = 1.0 if col == self.paddle else -1.0
            self.left -= 1
            if self.left:
                self._drop()
        return self._frame(), reward, self.left == 0, False, {}


gym.register("EdrCatch-v0", entry_point=Catch)


def catch_envs(num_envs: int, **kwargs):
    """``num_envs`` catching games as ``task=atari`` builds its envs (a torchrl env with EDR on
    gray and ``is_init``), stepped in this process."""
    from edr.representations import EDR
    from edr.tasks.atari import _env

    return _env(
        game="EdrCatch-v0", preset="none", module="catch_game", num_envs=num_envs,
        backend="serial", edr=EDR(color="gray"), keep_inputs=False, **kwargs,
    )  # fmt: skip
