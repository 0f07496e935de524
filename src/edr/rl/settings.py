"""What a PAAC run is configured by, one dataclass per concern (as ``conf/task/atari.yaml``
groups it): the envs and what the network sees, the network, the loss, the optimizer and its
schedule, the evaluation. The defaults here are the only ones in code; the config repeats them
with a comment each, and a test checks that the two agree.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Literal

from edr.checks.config import (
    Fraction,
    ModuleName,
    NonNegativeFloat,
    NonNegativeInt,
    PositiveFloat,
    PositiveInt,
)
from edr.models.paac import Core, Init, InputNorm
from edr.models.precision import PrecisionChoice
from edr.representations import EDR
from edr.rl.envs import AtariGame, Backend, Preset, gym_id_problem, own_env_problem
from edr.rl.loss import Advantage
from edr.rl.optim import OptimizerName

Inputs = Literal["fdr", "fdr_edr", "edr"]
EvalPolicy = Literal["sample", "greedy"]
BackendChoice = Backend | Literal["auto"]


@dataclass(frozen=True)
class EnvSettings:
    """Which game, how its envs are stepped, and what the network sees of them."""

    game: AtariGame = "Pong"  # ALE game name
    env_id: str | None = None  # a gymnasium id to play instead (with preset="none")
    env_module: ModuleName | None = None  # the module whose import registers env_id
    preset: Preset = "paac"  # paac: frame skip 4 + max, 30 no-ops; v5: ALE's; none: your env
    backend: BackendChoice = "auto"  # auto: envpool for ALE games, batch for your own env
    life_loss: bool = False  # a lost life ends a training episode
    num_envs: PositiveInt = 32  # envs stepped together (PAAC's 32)
    inputs: Inputs = "fdr_edr"  # frames, frames + EDR events, or events alone
    fdr: Literal["rgb", "gray"] = "rgb"  # the frames' colour
    edr: EDR | None = None  # the EDR layer computed on the fly
    frame_stack: PositiveInt = 4  # agent steps the network sees at once
    obs_dtype: Literal["float16", "float32"] = "float32"  # the observation's dtype (bfloat16
    # frames come by themselves where the network computes in bfloat16)

    @staticmethod
    def pairing_problem(values: Mapping[str, Any]) -> str | None:
        """``env_id``, ``preset`` and ``backend`` that cannot go together: an id of your own
        without ``preset=none`` (or ``preset=none`` without an id), EnvPool for your own env."""
        env_id, preset = values.get("env_id"), values.get("preset")
        if (env_id is None) != (preset != "none"):
            return (
                f"preset={preset!r}: expected preset=none with env_id=<id> (a gymnasium env of "
                "your own, env_module=<module that registers it>), or an ALE preset without "
                f"env_id (got env_id={env_id!r})"
            )
        if preset == "none" and values.get("backend") == "envpool":
            return (
                "backend='envpool': expected auto, batch, serial or parallel with preset=none "
                "(envpool plays ALE games only)"
            )
        return None

    @staticmethod
    def settings_problem(values: Mapping[str, Any]) -> str | None:
        """A user's env id said before any run folder is touched: ids, preset and backend that
        cannot go together (:meth:`pairing_problem`), an id gymnasium's registry
        lacks (where no ``env_module`` registers it on import), or, with ``preset=none``, one
        whose spaces PAAC cannot play (an env made and closed: only own-env runs pay for it,
        and their module is imported, as the run would)."""
        if pairing := EnvSettings.pairing_problem(values):
            return pairing
        env_id, module = values.get("env_id"), values.get("env_module")
        if not isinstance(env_id, str):
            return None
        problem = None if module else gym_id_problem(env_id)
        if problem is None and values.get("preset") == "none":
            problem = own_env_problem(env_id, module)
        return f"env_id={env_id!r}: expected {problem}" if problem else None

    @property
    def name(self) -> str:
        """The game's name, or the user's env id."""
        return self.env_id or self.game

    @property
    def modules(self) -> tuple[str, ...]:
        """Every module that making these envs imports, and so runs: ``env_module``, and the
        ``module`` of an id in gymnasium's ``module:Env-v0`` form (``gym.make`` imports it)."""
        ids = [i for i in (self.env_id, self.game) if isinstance(i, str) and ":" in i]
        named = (self.env_module, *(i.split(":")[0] for i in ids))
        return tuple(dict.fromkeys(m for m in named if m))

    def resolved_backend(self) -> Backend:
        """``auto``: EnvPool steps ALE games; a gymnasium env of your own runs serially, in one
        batch (``batch``: the ``serial`` backend's frames for a seed, at a fraction of its cost)."""
        if self.backend != "auto":
            return self.backend
        return "batch" if self.preset == "none" else "envpool"


@dataclass(frozen=True)
class NetworkSettings:
    """The actor-critic network after the conv trunk."""

    core: Core = "none"  # none (feed-forward PAAC), ftlstm (the paper's), lstm, lenet_ftlstm
    init: Init = "fan_in"  # fan_in (PAAC's TensorFlow code) or orthogonal (OpenAI's A2C)
    input_norm: InputNorm = "batchnorm"  # batchnorm (batch statistics), raw or centred frames
    precision: PrecisionChoice = "auto"  # float32, bfloat16 (autocast) or auto (timed)


@dataclass(frozen=True)
class LossSettings:
    """PAAC's n-step actor-critic loss."""

    rollout_steps: PositiveInt = 5  # steps per env between updates (n of the n-step return)
    discount: Fraction = 0.99  # the return's discount per agent step
    scale: PositiveFloat = 5.0  # PAAC multiplies its loss by 5
    entropy_coeff: NonNegativeFloat = 0.02  # weight of the policy's entropy bonus
    critic_coeff: NonNegativeFloat = 0.25  # weight of (R - V)^2
    advantage: Advantage = "raw"  # raw (PAAC's R - V), centred or normalised over the rollout


@dataclass(frozen=True)
class OptimSettings:
    """The optimizer, its gradient clip and its learning-rate schedule."""

    name: OptimizerName = "adam"  # adam (OpenAI's A2C) or rmsprop_tf (PAAC's TensorFlow RMSprop)
    lr: PositiveFloat | None = None  # None: the optimizer's default (DEFAULT_LR)
    lr_decay_env_steps: PositiveInt = 80_000_000  # the learning rate reaches 0 here
    lr_warmup_env_steps: NonNegativeInt = 0  # it rises linearly from 0 over these first (0: none)
    max_grad_norm: PositiveFloat = 3.0  # L2 clip of the whole gradient
    rmsprop_decay: Fraction = 0.99  # rmsprop_tf: the mean square's decay
    rmsprop_eps: PositiveFloat = 0.1  # rmsprop_tf: added inside the square root
    adam_eps: PositiveFloat = 1e-5  # adam: added to the root of the second moment

    @property
    def learning_rate(self) -> float:
        return self.lr or DEFAULT_LR[self.name]


DEFAULT_LR = {"adam": 7e-4, "rmsprop_tf": 0.0224}  # OpenAI A2C's for Adam; PAAC's for its RMSprop


@dataclass(frozen=True)
class EvalSettings:
    """The games scored after training (Table 1: min / max / mean of 30)."""

    plays: PositiveInt = 30  # whole games, played at once on as many envs
    max_steps: PositiveInt = 27_000  # agent steps at most per game
    policy: EvalPolicy = "sample"  # sample: actions drawn from the policy (PAAC's); greedy: argmax

    @property
    def capped(self) -> bool:
        """Games cut shorter than the published protocol's (27,000 agent steps, 30 minutes):
        the published random play is then no yardstick, and the run measures its own."""
        return self.max_steps < EvalSettings.max_steps
