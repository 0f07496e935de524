"""A paddle rally: keep a ball that bounces off the walls and the ceiling in play.

The ball moves one cell diagonally a step and bounces off the side walls and the top; the
two-cell paddle on the bottom row moves left, stays or moves right. A ball that reaches the
bottom row on the paddle scores +1 and goes back up; one that misses scores -1, costs one of 3
lives and starts again from a random column of the top row. An episode ends with the lives or
after 120 steps. Unlike catching, a return brings the ball back: the player plans where it lands.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np

from edr.rl.games.grid import GREEN, SIZE, WHITE, GridGame, paint

LIVES = 3
STEPS = 120  # steps per episode at most


def _advance(row: int, col: int, down: int, side: int) -> tuple[int, int, int, int]:
    """The ball one step on, bounced off the side walls and the top."""
    if not 0 <= col + side < SIZE:
        side = -side
    if row + down < 0:
        down = -down
    return row + down, col + side, down, side


class Rally(GridGame):
    action_space = gym.spaces.Discrete(3)  # left, stay, right

    def _frame(self) -> np.ndarray:
        frame = self.blank()
        paint(frame, self.row, self.col, WHITE)
        paint(frame, SIZE - 1, self.paddle, GREEN, width=2)
        return frame

    def _serve(self) -> None:
        self.row, self.col = 0, int(self.np_random.integers(SIZE))
        self.down, self.side = 1, int(self.np_random.choice((-1, 1)))

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        self.paddle, self.lives, self.clock = SIZE // 2 - 1, LIVES, 0
        self._serve()
        return self._frame(), {}

    def step(self, action: int):
        self.paddle = int(np.clip(self.paddle + int(action) - 1, 0, SIZE - 2))
        self.row, self.col, self.down, self.side = _advance(
            self.row, self.col, self.down, self.side
        )
        reward = 0.0
        if self.row == SIZE - 1:
            if self.paddle <= self.col <= self.paddle + 1:
                reward, self.down = 1.0, -1
            else:
                reward, self.lives = -1.0, self.lives - 1
                self._serve()
        self.clock += 1
        return self._frame(), reward, self.lives == 0 or self.clock == STEPS, False, {}

    def expert_action(self) -> int:
        """Towards where the ball will land (its path played forward), else the middle."""
        row, col, down, side = self.row, self.col, self.down, self.side
        while row < SIZE - 1:
            row, col, down, side = _advance(row, col, down, side)
        target = int(np.clip(col, 0, SIZE - 2))  # the paddle's left cell under the landing
        if self.paddle <= col <= self.paddle + 1:
            target = self.paddle
        return int(np.sign(target - self.paddle)) + 1
