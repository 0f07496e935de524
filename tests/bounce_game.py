"""A second small image game, held out from the defaults' choice: catch a ball that bounces.

Unlike ``catch_game.py`` (the game the learning tests guard, one that the defaults were
checked on), the ball here moves diagonally and bounces off the side walls, the field is
``size`` x ``size`` cells on 84x84 frames, and the paddle is one cell wide: a policy must
follow the ball's direction, not only its column. A drop scores +1 (caught) or -1 (missed);
an episode is ``drops`` drops. Random play catches about 1 drop in ``size`` (about -3.6 in
5 drops at size 7). Importing this module registers it as ``EdrBounce-v0``.
"""

from __future__ import annotations

from typing import ClassVar

import gymnasium as gym
import numpy as np

FRAME = 84  # pixels per side, as the agent sees Atari


class Bounce(gym.Env):
    metadata: ClassVar[dict] = {"render_modes": []}

    def __init__(self, size: int = 7, drops: int = 5) -> None:
        self.size, self.drops, self.cell = size, drops, FRAME // size
        self.observation_space = gym.spaces.Box(0, 255, (FRAME, FRAME, 3), np.uint8)
        self.action_space = gym.spaces.Discrete(3)  # left, stay, right

    def _frame(self) -> np.ndarray:  # (84, 84, 3) uint8: ball white, paddle red
        frame = np.zeros(self.observation_space.shape, np.uint8)
        c = self.cell
        frame[self.row * c : (self.row + 1) * c, self.col * c : (self.col + 1) * c] = 255
        frame[(self.size - 1) * c :, self.paddle * c : (self.paddle + 1) * c, 0] = 255
        return frame

    def _drop(self) -> None:
        self.row, self.col = 0, int(self.np_random.integers(self.size))
        self.heading = int(self.np_random.choice((-1, 1)))  # columns per row

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        self.paddle, self.left = self.size // 2, self.drops
        self._drop()
        return self._frame(), {}

    def step(self, action: int):
        self.paddle = int(np.clip(self.paddle + int(action) - 1, 0, self.size - 1))
        col = self.col + self.heading
        if not 0 <= col < self.size:  # bounce off the wall
            self.heading = -self.heading
            col = self.col + self.heading
        self.row, self.col = self.row + 1, col
        reward = 0.0
        if self.row == self.size - 1:
            reward = 1.0 if self.col == self.paddle else -1.0
            self.left -= 1
            if self.left:
                self._drop()
        return self._frame(), reward, self.left == 0, False, {}


gym.register("EdrBounce-v0", entry_point=Bounce)
