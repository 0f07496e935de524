"""EDR outside the suite: the gymnasium observation wrapper and the clip transform."""

from __future__ import annotations

from typing import ClassVar

import gymnasium as gym
import numpy as np
import pytest
import torch
from gymnasium.utils.env_checker import check_env

from edr.representations import EDR, ClipTransform, EDRObservation, GrayDiff


class MovingSquare(gym.Env):
    """A tiny image env: a bright square moves by the action (0 left, 1 right) on a 16x20 screen."""

    metadata: ClassVar[dict] = {"render_modes": []}

    def __init__(self, channels: int = 1) -> None:
        self.channels = channels
        shape = (16, 20, channels) if channels > 1 else (16, 20)
        self.observation_space = gym.spaces.Box(0, 255, shape, np.uint8)
        self.action_space = gym.spaces.Discrete(2)
        self.x = 0

    def _obs(self) -> np.ndarray:
        img = np.full((16, 20), 40, np.uint8)
        img[6:10, self.x : self.x + 4] = 220
        return np.repeat(img[..., None], self.channels, axis=2) if self.channels > 1 else img

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.x = int(self.np_random.integers(0, 16))
        return self._obs(), {}

    def step(self, action):
        self.x = int(np.clip(self.x + (1 if action == 1 else -1), 0, 16))
        return self._obs(), 0.0, False, False, {}


@pytest.mark.parametrize("channels", [1, 3])
def test_wrapper_passes_the_env_checker(channels: int) -> None:
    env = EDRObservation(MovingSquare(channels), EDR(half_lives=(1.0, 3.8)))
    check_env(env, skip_render_check=True)
    assert env.observation_space.shape == (channels * 4, 16, 20)


def test_wrapper_streams_and_restarts_on_reset() -> None:
    env = EDRObservation(MovingSquare())
    first, _ = env.reset(seed=0)
    frames = [env.unwrapped._obs()]
    steps = [first]
    for action in (1, 1, 0):
        obs, *_ = env.step(action)
        frames.append(env.unwrapped._obs())
        steps.append(obs)
    expected = EDR()(torch.from_numpy(np.stack(frames))[None, :, None])[0]  # (T, 2, H, W)
    np.testing.assert_allclose(np.stack(steps), expected.numpy(), rtol=1e-6)
    assert first.max() == 0 and steps[1][0].max() > 0 and steps[1][1].max() > 0
    again, _ = env.reset(seed=0)
    np.testing.assert_array_equal(again, first)  # the EMA restarted with the episode


def test_wrapper_rejects_non_image_spaces() -> None:
    with pytest.raises(ValueError, match="image Box"):
        EDRObservation(gym.make("CartPole-v1"))


def test_clip_transform_is_stateless_per_clip() -> None:
    transform = ClipTransform(EDR(color="gray"))
    g = torch.Generator().manual_seed(0)
    a = torch.randint(0, 256, (6, 3, 8, 8), dtype=torch.uint8, generator=g)
    b = torch.randint(0, 256, (6, 3, 8, 8), dtype=torch.uint8, generator=g)
    out_a = transform(a)
    transform(b)
    torch.testing.assert_close(transform(a), out_a)
    assert out_a.shape == (6, 2, 8, 8)
    assert ClipTransform(GrayDiff())(a).shape == (5, 1, 8, 8)
    with pytest.raises(ValueError, match=r"\(T, C, H, W\)"):
        transform(a.unsqueeze(0))
