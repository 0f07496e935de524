"""The screening games' streams are pinned: under a fixed seed and fixed actions each game's
first observations, rewards and ends hash to what they were before the own-game env path was
made faster (docs/own_game.md, "Where a run's time goes"), on every in-process backend."""

from __future__ import annotations

import hashlib

import numpy as np
import pytest
import torch
from torchrl.envs import InitTracker

from edr.rl.envs import make_atari_env
from edr.rl.games import GAMES

STEPS, ENVS = 70, 3  # agent steps of ENVS envs: every game ends and restarts envs in them
# sha256 of each game's stream, computed on the serial backend before the change
PINNED = {
    "EdrFruit-v0": "0423cbe0f3b92aa3dd44c1a27d072398dc36a8ce0d00f5e1d99fb90970ecba49",
    "EdrDodge-v0": "6b2af1597cc6d726e754d1dd913edd5dd6606ff379845e971169e9dc666ebc98",
    "EdrRally-v0": "86b41cbfdc6318b4ccaa2158c7dfae8d08b0b16c69858e09d57efeea17ec4873",
    "EdrMaze-v0": "f9435236081ddad26ddf99fcf5c8871f0787b3da2dd728b404153f97965752ff",
}


def stream_digest(env_id: str, backend: str, seed: int = 0) -> str:
    """sha256 of ``STEPS`` steps of ``ENVS`` envs of ``env_id`` seeded ``seed``, taking fixed
    actions: each step's frames, rewards and ends, and the frames and starts after resets."""
    env = make_atari_env(env_id, preset="none", num_envs=ENVS, backend=backend,
                         module="edr.rl.games", fdr="rgb", edr=None, keep_inputs=True)  # fmt: skip
    env.append_transform(InitTracker())
    env.set_seed(seed)
    actions = np.random.default_rng(seed).integers(env.action_spec.shape[-1], size=(STEPS, ENVS))
    digest = hashlib.sha256()
    td = env.reset()
    for step in range(STEPS):
        td["action"] = torch.nn.functional.one_hot(torch.from_numpy(actions[step]),
                                                   env.action_spec.shape[-1])  # fmt: skip
        out, td = env.step_and_maybe_reset(td)
        for part in (out["next", "pixels"], out["next", "reward"], out["next", "done"],
                     out["next", "terminated"], td["pixels"], td["is_init"]):  # fmt: skip
            digest.update(part.contiguous().numpy().tobytes())
    env.close()
    return digest.hexdigest()


@pytest.mark.parametrize("env_id", GAMES)
def test_each_games_stream_on_the_batch_backend_is_what_serial_gave(env_id: str) -> None:
    assert stream_digest(env_id, "batch") == PINNED[env_id]


def test_the_serial_backend_still_gives_the_pinned_stream() -> None:
    assert stream_digest("EdrFruit-v0", "serial") == PINNED["EdrFruit-v0"]
