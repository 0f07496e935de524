"""Atari through gymnasium and ale-py (ROMs ship in the wheel), wrapped by torchrl.

Presets:
- ``paac`` (the paper's era): frame skip 4 with a max over the last two frames, no sticky
  actions, up to 30 no-op starts, 84x84, end of life = end of episode in training, rewards
  clipped to their sign.
- ``v5``: ALE v5's own defaults (frame skip 4, sticky actions 0.25), frames resized to 84x84.

Observation ``observation`` (..., C, 84, 84) float32 (or float16, ``obs_dtype``): FDR (RGB 3
or gray 1 channel, /255) and/or EDR events computed on the fly (``EDRTransform``), stacked over
``frame_stack`` agent steps (``FrameStack``).
The paper's Appendix C input is RGB FDR + EDR on gray = 5 channels.
"""

from __future__ import annotations

import functools
import hashlib
import re
from typing import Literal

import ale_py
import ale_py.roms
import gymnasium as gym
import torch
from torchrl.envs import (
    Compose,
    EnvBase,
    GrayScale,
    GymWrapper,
    ParallelEnv,
    RewardSum,
    SerialEnv,
    SignTransform,
    StepCounter,
    ToTensorImage,
    TransformedEnv,
)

from edr.representations import EDR
from edr.rl.transform import EDRTransform, FrameStack

gym.register_envs(ale_py)

Preset = Literal["paac", "v5"]


def gym_atari(game: str, preset: Preset = "paac", train: bool = True) -> gym.Env:
    """One gymnasium ALE env with RGB 84x84 observations (H, W, 3) uint8."""
    name = f"ALE/{game}-v5"
    if preset == "paac":
        env = gym.make(name, frameskip=1, repeat_action_probability=0.0, full_action_space=False)
        return gym.wrappers.AtariPreprocessing(
            env,
            noop_max=30,
            frame_skip=4,
            screen_size=84,
            terminal_on_life_loss=train,
            grayscale_obs=False,
        )
    if preset == "v5":
        return gym.wrappers.ResizeObservation(gym.make(name), (84, 84))
    raise ValueError(f"preset must be 'paac' or 'v5', got {preset!r}")


def rom_fingerprint(game: str) -> str:
    """``ale-py <version>, <rom>.bin md5 <digest>``: which emulator and ROM a run played."""
    rom_id = re.sub(r"(?<!^)(?=[A-Z])", "_", game).lower()  # MsPacman -> ms_pacman
    path = ale_py.roms.get_rom_path(rom_id)
    if path is None:
        raise ValueError(f"ale-py {ale_py.__version__} has no ROM for the game {game!r}")
    return (
        f"ale-py {ale_py.__version__}, {path.name} md5 {hashlib.md5(path.read_bytes()).hexdigest()}"
    )


def _torchrl_atari(game: str, preset: Preset, train: bool) -> GymWrapper:
    return GymWrapper(gym_atari(game, preset, train))


def make_atari_env(
    game: str = "Pong",
    preset: Preset = "paac",
    num_envs: int = 1,
    mode: Literal["parallel", "serial", "single"] = "parallel",
    train: bool = True,
    fdr: Literal["rgb", "gray", "none"] = "rgb",
    edr: EDR | None = None,
    frame_stack: int = 1,
    obs_dtype: Literal["float32", "float16"] = "float32",
) -> TransformedEnv:
    """A torchrl env of ``num_envs`` Atari games with the observation the config asks for."""
    if fdr == "none" and edr is None:
        raise ValueError("the observation needs FDR, EDR or both")
    factory = functools.partial(_torchrl_atari, game, preset, train)
    if mode == "single":
        if num_envs != 1:
            raise ValueError(f"mode=single runs one env, not {num_envs}")
        base: EnvBase = factory()
    elif mode == "serial":
        base = SerialEnv(num_envs, factory)
    elif mode == "parallel":
        base = ParallelEnv(num_envs, factory, mp_start_method="spawn")
    else:
        raise ValueError(f"mode must be parallel, serial or single, got {mode!r}")
    parts = ["fdr"] if fdr != "none" else []
    transforms = [RewardSum(in_keys=["reward"], out_keys=["episode_reward"]), StepCounter()]
    if preset == "paac" and train:
        transforms.append(SignTransform(in_keys=["reward"]))
    if edr is not None:
        transforms.append(EDRTransform(edr, in_keys=["pixels"], out_keys=["edr"]))
        parts.append("edr")
    if fdr != "none":
        transforms.append(ToTensorImage(in_keys=["pixels"], out_keys=["fdr"]))
        if fdr == "gray":
            transforms.append(GrayScale(in_keys=["fdr"]))
    if obs_dtype not in ("float32", "float16"):
        raise ValueError(f"obs_dtype must be float32 or float16, got {obs_dtype!r}")
    stack = FrameStack(frame_stack, parts, "observation", dtype=getattr(torch, obs_dtype))
    transforms.append(stack)
    return TransformedEnv(base, Compose(*transforms))
