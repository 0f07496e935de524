"""The screening games: four small image games of the suite's own, each with a scripted expert,
on which the defaults for a user's own game (``task.env.preset=none``) are chosen (docs/own_game.md).

Importing this package registers them with gymnasium, so any of them trains with
``edr-run task=atari task.env.preset=none task.env.env_id=EdrFruit-v0 task.env.env_module=edr.rl.games``.
Their random and expert scores: ``scores.yaml`` beside this file (``python -m edr.rl.games.scores``).
"""

from __future__ import annotations

import gymnasium as gym

from edr.rl.games.dodge import Dodge
from edr.rl.games.fruit import Fruit
from edr.rl.games.maze import Maze
from edr.rl.games.rally import Rally

GAMES = {"EdrFruit-v0": Fruit, "EdrDodge-v0": Dodge, "EdrRally-v0": Rally, "EdrMaze-v0": Maze}

for _id, _game in GAMES.items():
    if _id not in gym.registry:
        gym.register(_id, entry_point=_game)
