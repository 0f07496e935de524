"""The screening games (edr.rl.games): each is a valid gymnasium env with cheap numpy frames, its
expert beats random play by a margin, and the committed yardsticks are what the games give."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from edr.rl.games import GAMES
from edr.rl.games.scores import load_scores, mean_score


@pytest.mark.parametrize("env_id", GAMES)
def test_each_game_passes_gymnasiums_env_checker(env_id: str) -> None:
    env = gym.make(env_id)
    check_env(env.unwrapped, skip_render_check=True)
    frame, _ = env.reset(seed=0)
    assert frame.shape == (84, 84, 3) and frame.dtype == np.uint8 and frame.any()


@pytest.mark.parametrize("env_id", GAMES)
def test_the_expert_beats_random_play_by_a_margin(env_id: str) -> None:
    random, expert = mean_score(env_id, "random", 20), mean_score(env_id, "expert", 20)
    scores = load_scores()[env_id]
    assert expert - random >= 0.5 * (scores["expert"] - scores["random"]) > 0
    assert expert - random >= 2.0


def test_the_committed_yardsticks_cover_every_game() -> None:
    scores = load_scores()
    assert scores.keys() == GAMES.keys()
    assert all(s["expert"] > s["random"] for s in scores.values())
