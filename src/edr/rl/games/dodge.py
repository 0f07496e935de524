"""Dodging: blocks fall; stay out from under them.

Each step a block starts in a random column of the top row with probability 1/2 and falls one
row a step; the player on the bottom row moves left, stays or moves right. A block that lands on
the player scores -1; an episode is 60 steps. Nothing is scored for staying clear: the game
rewards only avoidance (the best score is 0).
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np

from edr.rl.games.grid import BLUE, GREEN, SIZE, GridGame, paint

STEPS = 60  # steps per episode


class Dodge(GridGame):
    action_space = gym.spaces.Discrete(3)  # left, stay, right

    def _frame(self) -> np.ndarray:
        frame = self.blank()
        for row, col in self.blocks:
            paint(frame, row, col, BLUE)
        paint(frame, SIZE - 1, self.player, GREEN)
        return frame

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        self.player, self.blocks, self.clock = SIZE // 2, [], 0
        return self._frame(), {}

    def step(self, action: int):
        self.player = int(np.clip(self.player + int(action) - 1, 0, SIZE - 1))
        landed = [col for row, col in self.blocks if row + 1 == SIZE - 1]
        reward = -float(landed.count(self.player))
        self.blocks = [(row + 1, col) for row, col in self.blocks if row + 1 < SIZE - 1]
        if self.np_random.random() < 0.5:
            self.blocks.append((0, int(self.np_random.integers(SIZE))))
        self.clock += 1
        return self._frame(), reward, self.clock == STEPS, False, {}

    def expert_action(self) -> int:
        """A move whose column no block lands on next step, preferring one clear two steps on."""

        def clear(col: int, row: int) -> bool:
            return all((r, c) != (row, col) for r, c in self.blocks)

        moves = [m for m in (0, -1, 1) if 0 <= self.player + m < SIZE]
        safe = [m for m in moves if clear(self.player + m, SIZE - 2)] or moves
        return next((m for m in safe if clear(self.player + m, SIZE - 3)), safe[0]) + 1
