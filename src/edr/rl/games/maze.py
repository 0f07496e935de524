"""Collecting in a maze: walk a walled 7x7 maze and pick up every coin.

The maze's walls are fixed; the player starts on a random free cell, 3 coins on others. The
player stays or moves up, down, left or right (a wall stops it); each coin picked up scores +1.
An episode ends when every coin is picked up or after 40 steps. Unlike the falling games, the
player moves in two dimensions and must find paths around the walls.
"""

from __future__ import annotations

from collections import deque

import gymnasium as gym
import numpy as np

from edr.rl.games.grid import BLUE, GREEN, SIZE, YELLOW, GridGame, paint

COINS = 3
STEPS = 40  # steps per episode at most
WALLS = frozenset({(1, 1), (1, 2), (1, 4), (1, 5), (3, 0), (3, 1), (3, 3), (3, 5), (3, 6),
                   (5, 1), (5, 2), (5, 4), (5, 5)})  # fmt: skip
FREE = [(r, c) for r in range(SIZE) for c in range(SIZE) if (r, c) not in WALLS]
MOVES = ((0, 0), (-1, 0), (1, 0), (0, -1), (0, 1))  # stay, up, down, left, right


def _moved(cell: tuple[int, int], action: int) -> tuple[int, int]:
    row, col = cell[0] + MOVES[action][0], cell[1] + MOVES[action][1]
    inside = 0 <= row < SIZE and 0 <= col < SIZE and (row, col) not in WALLS
    return (row, col) if inside else cell


class Maze(GridGame):
    action_space = gym.spaces.Discrete(len(MOVES))

    def _frame(self) -> np.ndarray:
        frame = self.blank()
        for cell in WALLS:
            paint(frame, *cell, BLUE)
        for cell in self.coins:
            paint(frame, *cell, YELLOW)
        paint(frame, *self.player, GREEN)
        return frame

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        picked = self.np_random.choice(len(FREE), COINS + 1, replace=False)
        self.player, *coins = (FREE[i] for i in picked)
        self.coins, self.clock = set(coins), 0
        return self._frame(), {}

    def step(self, action: int):
        self.player = _moved(self.player, int(action))
        reward = float(self.player in self.coins)
        self.coins.discard(self.player)
        self.clock += 1
        return self._frame(), reward, not self.coins or self.clock == STEPS, False, {}

    def expert_action(self) -> int:
        """The first move of a shortest path to the nearest coin (breadth-first search)."""
        first = {self.player: 0}
        queue = deque([self.player])
        while queue:
            cell = queue.popleft()
            if cell in self.coins:
                return first[cell]
            for action in range(1, len(MOVES)):
                if (nxt := _moved(cell, action)) not in first:
                    first[nxt] = first[cell] or action
                    queue.append(nxt)
        return 0
