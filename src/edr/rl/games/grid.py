"""What the screening games share: an 84x84 RGB frame of 7x7 cells of 12 pixels, painted with
numpy slices (no pygame), and the base class that holds the frame's space."""

from __future__ import annotations

from typing import ClassVar

import gymnasium as gym
import numpy as np

SIZE = 7  # cells per side
CELL = 12  # pixels per cell: 7 x 12 = 84, the frame the agent sees in Atari
FRAME = SIZE * CELL

WHITE, RED, GREEN, BLUE, YELLOW = (
    (255, 255, 255),
    (255, 0, 0),
    (0, 255, 0),
    (0, 0, 255),
    (255, 255, 0),
)


def paint(
    frame: np.ndarray, row: int, col: int, colour: tuple[int, int, int], width: int = 1
) -> None:
    """Fill ``width`` cells of ``frame`` (84, 84, 3) from (``row``, ``col``) rightwards."""
    frame[row * CELL : (row + 1) * CELL, col * CELL : (col + width) * CELL] = colour


class GridGame(gym.Env):
    """A game on a 7x7 grid shown as (84, 84, 3) uint8 frames, with a scripted expert:
    ``expert_action()`` is the action a good player takes now (it reads the game's state)."""

    metadata: ClassVar[dict] = {"render_modes": []}
    observation_space = gym.spaces.Box(0, 255, (FRAME, FRAME, 3), np.uint8)

    def blank(self) -> np.ndarray:  # (84, 84, 3) uint8, black
        return np.zeros(self.observation_space.shape, np.uint8)

    def expert_action(self) -> int:
        raise NotImplementedError
