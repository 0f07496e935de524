"""Catching fruit: fruit and rocks fall, several at once; catch the fruit, let the rocks fall.

An object (fruit, 2 in 3; or rock) starts in a random column of the top row every second step
and falls one row a step; the one-cell basket on the bottom row moves left, stays or moves right.
A fruit caught scores +1, a fruit missed -1, a rock caught -1, a rock missed 0. An episode is 12
objects (about 30 steps). Unlike a single falling ball, the player must choose which to catch.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np

from edr.rl.games.grid import GREEN, RED, SIZE, YELLOW, GridGame, paint

OBJECTS = 12  # objects per episode
EVERY = 2  # steps between two objects


class Fruit(GridGame):
    action_space = gym.spaces.Discrete(3)  # left, stay, right

    def _frame(self) -> np.ndarray:
        frame = self.blank()
        for row, col, fruit in self.falling:
            paint(frame, row, col, YELLOW if fruit else RED)
        paint(frame, SIZE - 1, self.basket, GREEN)
        return frame

    def _spawn(self) -> None:
        col = int(self.np_random.integers(SIZE))
        self.falling.append((0, col, bool(self.np_random.random() < 2 / 3)))
        self.spawned += 1

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        self.basket, self.falling, self.spawned, self.clock = SIZE // 2, [], 0, 0
        self._spawn()
        return self._frame(), {}

    def step(self, action: int):
        self.basket = int(np.clip(self.basket + int(action) - 1, 0, SIZE - 1))
        reward, still = 0.0, []
        for row, col, fruit in self.falling:
            if row + 1 < SIZE - 1:
                still.append((row + 1, col, fruit))
            elif col == self.basket:
                reward += 1.0 if fruit else -1.0
            elif fruit:
                reward -= 1.0
        self.falling, self.clock = still, self.clock + 1
        if self.clock % EVERY == 0 and self.spawned < OBJECTS:
            self._spawn()
        done = self.spawned == OBJECTS and not self.falling
        return self._frame(), reward, done, False, {}

    def expert_action(self) -> int:
        """Towards the lowest fruit it can still reach, waiting beside a rock about to land."""
        reachable = [(SIZE - 2 - row, col) for row, col, fruit in self.falling
                     if fruit and abs(col - self.basket) <= SIZE - 1 - row]  # fmt: skip
        target = min(reachable)[1] if reachable else self.basket
        move = int(np.sign(target - self.basket))
        landing = {col for row, col, fruit in self.falling if row == SIZE - 2 and not fruit}
        for step in (move, 0, -1, 1):  # the wanted move, else any that dodges a landing rock
            if 0 <= self.basket + step < SIZE and self.basket + step not in landing:
                return step + 1
        return 1
