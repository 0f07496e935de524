"""Atari for torchrl: ale-py (ROMs ship in the wheel) through gymnasium, or EnvPool.

Backends: ``envpool`` (EnvPool's C++ thread pool steps every env; one process), ``parallel``
(torchrl's ``ParallelEnv``: one process per env), ``serial`` (one process, one env after
another), ``batch`` (the same as ``serial``, without torchrl's per-env wrappers:
``edr.rl.gym_batch``) and ``single`` (one env, no batch dimension).

Presets (the same on every backend):
- ``paac`` (the paper's era): frame skip 4 with a max over the last two frames, no sticky
  actions, up to 30 no-op starts, 84x84, rewards clipped to their sign in training. A life
  lost ends a training episode only with ``life_loss=True`` (PAAC's default did not).
- ``v5``: ALE v5's own defaults (frame skip 4, sticky actions 0.25), frames resized to 84x84.
- ``none``: a user's own gymnasium env with RGB image observations and discrete actions (its
  id in place of the game, ``module`` the module that registers it): no ALE wrappers, frames
  resized to 84x84 if they are not.

Observation ``observation`` (..., C, 84, 84) float32 (or float16, bfloat16: ``obs_dtype``): FDR (RGB 3
or gray 1 channel, /255) and/or EDR events computed on the fly, written in one pass
(``ObservationFrame``), one agent step's frame: the network's window of the last frames is
its actor's (``edr.rl.rollout.Actor``).
The paper's Appendix C input is RGB FDR + EDR on gray = 5 channels.
"""

from __future__ import annotations

import difflib
import functools
import hashlib
import importlib
import os
import re
from typing import Annotated, Any, Literal, get_args

import ale_py
import ale_py.roms
import gymnasium as gym
import numpy as np
import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.data import Bounded, Categorical, Composite, OneHot, Unbounded
from torchrl.envs import (
    Compose,
    EnvBase,
    ExcludeTransform,
    GymWrapper,
    ParallelEnv,
    RewardSum,
    SerialEnv,
    SignTransform,
    TransformedEnv,
)

from edr.checks import interrupts
from edr.checks.config import Check, ConfigError
from edr.representations import EDR
from edr.rl.gym_batch import GymBatch
from edr.rl.transform import ObservationFrame

gym.register_envs(ale_py)

Preset = Literal["paac", "v5", "none"]
Backend = Literal["envpool", "parallel", "serial", "batch", "single"]
ObsDtype = Literal["float32", "float16", "bfloat16"]  # an observation frame's dtype
SCREEN = 84  # observations are SCREEN x SCREEN


def gym_atari(
    game: str, preset: Preset = "paac", train: bool = True, life_loss: bool = False
) -> gym.Env:
    """One gymnasium ALE env with RGB 84x84 observations (H, W, 3) uint8."""
    name = f"ALE/{game}-v5"
    if preset == "paac":
        env = gym.make(name, frameskip=1, repeat_action_probability=0.0, full_action_space=False)
        return gym.wrappers.AtariPreprocessing(
            env,
            noop_max=30,
            frame_skip=4,
            screen_size=SCREEN,
            terminal_on_life_loss=train and life_loss,
            grayscale_obs=False,
        )
    if preset == "v5":
        return gym.wrappers.ResizeObservation(gym.make(name), (SCREEN, SCREEN))
    raise ValueError(f"preset must be 'paac' or 'v5', got {preset!r}")


def rom_id(game: str) -> str:
    """ALE's ROM id of a game name: ``MsPacman`` -> ``ms_pacman``."""
    return re.sub(r"(?<!^)(?=[A-Z])", "_", game).lower()


@functools.cache
def ale_games() -> tuple[str, ...]:
    """The games this ale-py registers with gymnasium as ``ALE/<Game>-v5``: those it can play
    (it ships ROMs of a few more, two-player games such as Combat, Joust and Warlords, which no
    single-player env plays). Read from gymnasium's registry: nothing is built."""
    return tuple(
        sorted(k[4:-3] for k in gym.registry if k.startswith("ALE/") and k.endswith("-v5"))
    )


def _game_problem(game: Any) -> str | None:
    games = ale_games()
    if game in games:
        return None
    same = [g for g in games if g.lower() == str(game).lower().replace("_", "")]
    if same:
        return f"an ALE game, spelt as ALE does (names are case-sensitive): {same[0]}"
    if rom_id(str(game)) in ale_py.roms.get_all_rom_ids():
        return (
            f"an ALE game ale-py {ale_py.__version__} plays alone: it ships {game}'s ROM but no "
            f"single-player env for it (pick another: {', '.join(games[:5])}, ...)"
        )
    near = difflib.get_close_matches(str(game), games, n=3, cutoff=0.5)
    listed = f"{', '.join(near)}?" if near else f"one of {len(games)}: {', '.join(games[:6])}, ..."
    return f"an ALE game ({listed})"


def gym_id_problem(env_id: str) -> str | None:
    """What is wrong with a gymnasium env id, read from gymnasium's registry (nothing built):
    None where it is registered, or where a ``module:`` prefix registers it when imported."""
    if ":" in env_id or env_id in gym.registry:
        return None
    near = difflib.get_close_matches(env_id, list(gym.registry), n=3, cutoff=0.6)
    return (
        "a gymnasium env id registered here"
        + (f" (did you mean {', '.join(near)}?)" if near else "")
        + ", or task.env.env_module=<the module whose import registers it>"
    )


AtariGame = Annotated[str, Check(_game_problem)]  # a game whose ROM ale-py ships


def rom_fingerprint(game: str) -> str:
    """``ale-py <version>, <rom>.bin md5 <digest>``: which emulator and ROM a run played."""
    path = ale_py.roms.get_rom_path(rom_id(game))
    if path is None:
        raise ValueError(f"ale-py {ale_py.__version__} has no ROM for the game {game!r}")
    return (
        f"ale-py {ale_py.__version__}, {path.name} md5 {hashlib.md5(path.read_bytes()).hexdigest()}"
    )


def _make_own(env_id: str, module: str | None) -> gym.Env:
    """The user's gymnasium env ``env_id``, registered by importing ``module``."""
    if module is not None:
        importlib.import_module(module)
    return gym.make(env_id)


def _spaces_problem(env: gym.Env) -> str | None:
    """What PAAC cannot play in a user's ``env`` (as ``expected ...`` ends): observations that
    are no RGB frames, actions that are not discrete; None where it can play it."""
    space = env.observation_space
    if not (
        isinstance(space, gym.spaces.Box)
        and space.dtype == np.uint8
        and len(space.shape) == 3
        and space.shape[-1] == 3
    ):
        return (
            f"an env of RGB image observations (H, W, 3) uint8, as task.env.preset=none plays; it "
            f"observes {_space_text(space)}: give an env with frames, or task.env.game=<an ALE "
            "game> with preset paac"
        )
    if not isinstance(env.action_space, gym.spaces.Discrete):
        return (
            f"an env of discrete actions, as PAAC takes; it acts in {_space_text(env.action_space)}"
        )
    return None


def own_env_problem(env_id: str, module: str | None = None) -> str | None:
    """What stops PAAC playing the user's env ``env_id`` (registered by importing ``module``),
    read from the spaces of one env made and closed at once (only a made env says them): for
    the checks before a run, which then refuse it before its folder is touched."""
    try:
        env = _make_own(env_id, module)
    except gym.error.Error as error:  # an id the module does not register, a missing extra
        return f"an env gymnasium can make ({' '.join(str(error).split())})"
    try:
        return _spaces_problem(env)
    finally:
        env.close()


def gym_image_env(env_id: str, module: str | None = None) -> gym.Env:
    """A user's gymnasium env (registered by importing ``module``) with 84x84 RGB frames."""
    env = _make_own(env_id, module)
    if problem := _spaces_problem(env):
        env.close()
        raise ConfigError(f"task.env.env_id={env_id}: expected {problem}")
    if env.observation_space.shape[:2] != (SCREEN, SCREEN):
        env = gym.wrappers.ResizeObservation(env, (SCREEN, SCREEN))
    return env


def _space_text(space: gym.Space) -> str:
    """``Box(4,) float32``: a space in a few words (its repr lists every bound)."""
    return f"{type(space).__name__}{space.shape} {space.dtype}"


def _torchrl_gym(
    game: str,
    preset: Preset,
    train: bool,
    life_loss: bool,
    module: str | None,
    parent: int | None = None,
) -> GymWrapper:
    """One env. Made for a ParallelEnv (``parent``: the pid of the process that makes it), in a
    worker process of its own the module registers the env there too, and the worker ignores
    Ctrl-C and SIGTERM, which reach it with its parent's process group: the parent stops (and
    checkpoints), then closes its workers. Elsewhere (the parent's own look at the specs, a
    serial env) nothing about signals changes, whatever process it runs in: a job of a parallel
    sweep is a child process too, and must stop on them."""
    if parent is not None and os.getpid() != parent:
        interrupts.ignore_stop_signals()
    return GymWrapper(_gym_env(game, preset, train, life_loss, module), from_pixels=False)


def _gym_env(
    game: str, preset: Preset, train: bool, life_loss: bool, module: str | None
) -> gym.Env:
    """One gymnasium env: a user's (``preset="none"``) or an ALE game's."""
    if preset == "none":
        return gym_image_env(game, module)
    return gym_atari(game, preset, train, life_loss)


class EnvPoolAtari(EnvBase):
    """``num_envs`` Atari games stepped by EnvPool's thread pool, as one batched torchrl env.

    Observations ``pixels`` (N, 84, 84, 3) uint8 (a view of EnvPool's planar frames), rewards
    raw: what the gymnasium backend gives, so the same transforms follow. Envs reset only when
    torchrl asks (``_reset`` names them); EnvPool's own auto-reset never fires, because an ended
    env is reset before it steps.
    """

    def __init__(
        self,
        game: str,
        num_envs: int,
        preset: Preset = "paac",
        train: bool = True,
        life_loss: bool = False,
        threads: int | None = None,
    ) -> None:
        super().__init__(batch_size=torch.Size([num_envs]))
        if preset not in ("paac", "v5"):
            raise ValueError(f"preset must be 'paac' or 'v5', got {preset!r}")
        import envpool  # imported here: only this backend needs it

        task, num_threads = f"{game}-v5", threads or min(num_envs, os.cpu_count() or 1)
        self._make = functools.partial(
            envpool.make_gymnasium,
            task,
            num_envs=num_envs,
            num_threads=num_threads,
            img_height=SCREEN,
            img_width=SCREEN,
            gray_scale=False,
            stack_num=1,
            frame_skip=4,
            noop_max=30 if preset == "paac" else 1,  # 1: no no-op starts
            repeat_action_probability=0.0 if preset == "paac" else 0.25,
            episodic_life=train and life_loss and preset == "paac",
            reward_clip=False,  # SignTransform clips, after RewardSum has the raw score
            use_fire_reset=False,
        )
        self._pool = None  # made by the first reset or set_seed (making it takes ~1 s)
        self._seed = 0
        if task not in envpool.list_all_envs():
            raise ConfigError(
                f"task.env.game={game}: expected a game EnvPool {envpool.__version__} plays "
                "(task.env.backend=envpool): use task.env.backend=serial or parallel (ale-py)"
            )
        actions = int(envpool.make_spec(task).action_space.n)
        self._pixels: torch.Tensor | None = None  # (N, H, W, 3) the latest frames; first reset
        n = (num_envs,)
        self.observation_spec = Composite(
            pixels=Bounded(0, 255, shape=(*n, SCREEN, SCREEN, 3), dtype=torch.uint8), shape=n
        )
        self.action_spec = OneHot(actions, shape=(*n, actions))
        self.reward_spec = Unbounded(shape=(*n, 1))
        flag = Categorical(2, shape=(*n, 1), dtype=torch.bool)
        self.done_spec = Composite(
            done=flag, terminated=flag.clone(), truncated=flag.clone(), shape=n
        )

    @staticmethod
    def _frames(obs: np.ndarray) -> torch.Tensor:
        """EnvPool's (N, 3, H, W) -> (N, H, W, 3), a view: planar in memory, as the observation's
        kernel reads it best (EnvPool gives new arrays every step). A copy into (H, W, 3) memory
        cost 16 Pong envs ~20 % of their steps/s: torch's threads then spun on the emulator's
        cores."""
        return torch.from_numpy(obs).permute(0, 2, 3, 1)

    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs) -> TensorDictBase:
        mask = tensordict.get("_reset", None) if tensordict is not None else None
        if self._pool is None:
            self._pool, mask = self._make(seed=self._seed), None
        if mask is None or mask.all():
            obs, _ = self._pool.reset()
            self._pixels = self._frames(obs)
        else:
            rows = mask.reshape(-1).nonzero().squeeze(1)
            obs, _ = self._pool.reset(rows.numpy().astype(np.int32))
            self._pixels = self._pixels.clone()  # earlier frames may live on in collected data
            self._pixels[rows] = self._frames(obs)
        out = TensorDict({"pixels": self._pixels}, batch_size=self.batch_size)
        return out.update(self.full_done_spec.zero())

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        action = tensordict.get("action").long().argmax(-1).numpy()  # one-hot -> index
        obs, reward, terminated, truncated, _ = self._pool.step(action)
        self._pixels = self._frames(obs)
        terminated = torch.from_numpy(terminated).reshape(-1, 1)
        truncated = torch.from_numpy(truncated).reshape(-1, 1)
        return TensorDict(
            {
                "pixels": self._pixels,
                "reward": torch.from_numpy(reward).float().reshape(-1, 1),
                "done": terminated | truncated,
                "terminated": terminated,
                "truncated": truncated,
            },
            batch_size=self.batch_size,
        )

    def _drop_pool(self) -> None:
        if self._pool is not None:
            self._pool.close()
            self._pool = None

    def _set_seed(self, seed: int | None) -> None:
        """The next reset makes the pool again, seeded: EnvPool takes its seed when made."""
        self._drop_pool()
        self._seed = 0 if seed is None else seed

    def close(self, *, raise_if_closed: bool = True) -> None:
        self._drop_pool()
        super().close(raise_if_closed=raise_if_closed)


class _KeepsTorchThreads:
    """Leaves torch's thread count, once the env is closed, as it was when the env was made.

    torchrl's batched envs change it: a ``ParallelEnv`` takes its workers' count off the main
    process's threads while it runs, and closing either kind adds the workers' count back, up
    to the count torch had when torchrl was imported. A closed ``SerialEnv`` of 4 envs thus
    raised ``threads=1`` to 2 for the rest of the run: the evaluation after training then ran
    2 threads where another job held a core, each op waiting on the other thread (a tiny Pong
    run, ``debug=tiny``, took 32 s instead of 21, and its test 64-67 s instead of 26).
    """

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        threads = torch.get_num_threads()
        super().__init__(*args, **kwargs)
        self._torch_threads = threads

    def close(self, *, raise_if_closed: bool = True) -> None:
        was_open = not self.is_closed
        super().close(raise_if_closed=raise_if_closed)
        if was_open and torch.get_num_threads() != self._torch_threads:
            torch.set_num_threads(self._torch_threads)


class _SerialEnv(_KeepsTorchThreads, SerialEnv):
    """torchrl's ``SerialEnv``, leaving torch's thread count as it found it."""


class _ParallelEnv(_KeepsTorchThreads, ParallelEnv):
    """torchrl's ``ParallelEnv``, leaving torch's thread count as it found it once closed."""


def make_atari_env(
    game: str = "Pong",
    preset: Preset = "paac",
    num_envs: int = 1,
    backend: Backend = "parallel",
    train: bool = True,
    life_loss: bool = False,
    module: str | None = None,
    fdr: Literal["rgb", "gray", "none"] = "rgb",
    edr: EDR | None = None,
    obs_dtype: ObsDtype = "float32",
    keep_inputs: bool = True,
    frame_ring: int | None = None,
) -> TransformedEnv:
    """A torchrl env of ``num_envs`` Atari games with the observation the config asks for.

    With ``preset="none"``, ``game`` is a gymnasium id (and ``module`` the module to import).

    ``keep_inputs=True`` also keeps the pixels, and FDR and EDR as ``fdr`` and ``edr`` (views of
    the frame's channels); False: a training rollout stores the observation alone.
    ``frame_ring=k``: the observations cycle through ``k`` buffers (:class:`ObservationFrame`),
    each overwritten ``k`` steps after it was emitted; None: a new tensor every step.
    """
    if fdr == "none" and edr is None:
        raise ValueError("the observation needs FDR, EDR or both")
    if preset == "none" and backend == "envpool":
        raise ValueError(
            "backend=envpool plays ALE games only; preset=none needs batch, serial or parallel"
        )
    factory = functools.partial(_torchrl_gym, game, preset, train, life_loss, module)
    if backend == "single":
        if num_envs != 1:
            raise ValueError(f"backend=single runs one env, not {num_envs}")
        base: EnvBase = factory()
    elif backend == "serial":
        base = _SerialEnv(num_envs, factory)
    elif backend == "parallel":
        in_workers = functools.partial(factory, parent=os.getpid())
        base = _ParallelEnv(num_envs, in_workers, mp_start_method="spawn")
    elif backend == "batch":
        base = GymBatch(
            functools.partial(_gym_env, game, preset, train, life_loss, module), num_envs
        )
    elif backend == "envpool":
        base = EnvPoolAtari(game, num_envs, preset, train, life_loss)
    else:
        raise ValueError(
            f"backend must be envpool, parallel, serial, batch or single, got {backend!r}"
        )
    transforms = [RewardSum(in_keys=["reward"], out_keys=["episode_reward"])]
    if preset == "paac" and train:
        transforms.append(SignTransform(in_keys=["reward"]))
    if obs_dtype not in get_args(ObsDtype):
        raise ValueError(f"obs_dtype must be float32, float16 or bfloat16, got {obs_dtype!r}")
    transforms.append(
        ObservationFrame(
            fdr, edr, keep_parts=keep_inputs, ring=frame_ring, dtype=getattr(torch, obs_dtype)
        )
    )
    if not keep_inputs:
        transforms.append(ExcludeTransform("pixels"))
    return TransformedEnv(base, Compose(*transforms))
