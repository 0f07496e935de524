"""The screening games' yardsticks: each game's mean score under random play and under its
scripted expert, over seeded episodes; the screening normalises a run's score by them,
(score - random) / (expert - random). ``python -m edr.rl.games.scores`` measures them and writes
``scores.yaml`` beside this file (100 episodes each, seeds 0-99; a few seconds)."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Literal

import gymnasium as gym
import numpy as np
import yaml

from edr.rl.games import GAMES
from edr.store.atomic import write_text_atomic

SCORES = Path(__file__).with_name("scores.yaml")
Policy = Literal["random", "expert"]


def mean_score(env_id: str, policy: Policy, episodes: int = 100, seed: int = 0) -> float:
    """The mean undiscounted return of ``episodes`` episodes of ``env_id`` (seeds ``seed``,
    ``seed`` + 1, ...) played by ``policy``: uniform random actions or the game's expert."""
    env = gym.make(env_id)
    env.action_space.seed(seed)
    returns = []
    for episode in range(episodes):
        env.reset(seed=seed + episode)
        total, done = 0.0, False
        while not done:
            action = (
                env.action_space.sample() if policy == "random" else env.unwrapped.expert_action()
            )
            _, reward, terminated, truncated, _ = env.step(action)
            total, done = total + float(reward), terminated or truncated
        returns.append(total)
    env.close()
    return float(np.mean(returns))


def load_scores() -> dict[str, dict[str, float]]:
    """env id -> {"random": ..., "expert": ...} as ``scores.yaml`` holds them."""
    return yaml.safe_load(SCORES.read_text())["games"]


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m edr.rl.games.scores", description=__doc__)
    parser.add_argument("--episodes", type=int, default=100, help="episodes per game and policy")
    args = parser.parse_args(argv)
    games = {g: {p: round(mean_score(g, p, args.episodes), 3) for p in ("random", "expert")}
             for g in GAMES}  # fmt: skip
    head = (
        "# The screening games' mean scores over seeded episodes, written by\n"
        f"#   python -m edr.rl.games.scores --episodes {args.episodes}\n"
        "# The screening report normalises a run's score by them: (score - random) / (expert - random).\n"
    )
    write_text_atomic(SCORES, head + yaml.safe_dump({"episodes": args.episodes, "games": games},
                                                    sort_keys=False))  # fmt: skip
    print(SCORES.read_text())


if __name__ == "__main__":
    main()
