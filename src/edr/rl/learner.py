"""PAAC's update, one rollout at a time: n-step returns bootstrapped from the state after the
rollout, PAAC's loss, its gradient with the L2 norm clipped, and one optimizer step whose
learning rate decays linearly to 0 (torchrl's a2c example has the same ``update`` shape)."""

from __future__ import annotations

import functools
from typing import Any

import torch

from edr.models.divergence import divergence
from edr.models.paac import PAACNetwork
from edr.rl.loss import n_step_returns, paac_loss
from edr.rl.optim import make_optimizer
from edr.rl.phases import PhaseClock
from edr.rl.rollout import Rollout
from edr.rl.settings import LossSettings, OptimSettings


class Diverged(Exception):
    """Training stopped being numbers; the message says where (the loss, a parameter).
    ``stepped``: the optimizer had taken the update's step (its env steps count as trained)."""

    def __init__(self, reason: str, stepped: bool) -> None:
        super().__init__(reason)
        self.stepped = stepped


def logit_spread(logits: torch.Tensor) -> float:
    """How much the policy tells states apart: the logits' std across the rollout's states
    (N*T of them), averaged over actions. Near 0 while the policy ignores what it sees."""
    return float(logits.detach().reshape(-1, logits.shape[-1]).std(0).mean())  # (N*T, A) -> ()


def lr_factor(update: int, batch: int, optim: OptimSettings) -> float:
    """The learning rate's factor at ``update`` (0-based; ``batch`` env steps each): rising
    linearly over the first ``optim.lr_warmup_env_steps`` (the first update already at
    ``batch / warmup``), decaying linearly to 0 at ``optim.lr_decay_env_steps``."""
    warmup = optim.lr_warmup_env_steps
    rising = min(1.0, (update + 1) * batch / warmup) if warmup else 1.0
    return rising * max(0.0, 1.0 - update * batch / optim.lr_decay_env_steps)


class Learner:
    """The network's optimizer and schedule, and :meth:`update`. ``batch`` is a rollout's env
    steps (envs x rollout steps): the schedule counts env steps."""

    def __init__(
        self,
        net: PAACNetwork,
        loss: LossSettings,
        optim: OptimSettings,
        batch: int,
        clock: PhaseClock,
    ) -> None:
        self.net, self.loss, self.clock = net, loss, clock
        self.max_grad_norm = optim.max_grad_norm
        self.optimizer = make_optimizer(
            optim.name,
            net.parameters(),
            lr=optim.learning_rate,
            rmsprop_decay=optim.rmsprop_decay,
            rmsprop_eps=optim.rmsprop_eps,
            adam_eps=optim.adam_eps,
        )
        self.schedule = torch.optim.lr_scheduler.LambdaLR(
            self.optimizer, functools.partial(lr_factor, batch=batch, optim=optim)
        )
        # True inside the optimizer's step, where an interrupt leaves the network half-updated
        # (a checkpoint then would hold weights no update produced)
        self.stepping = False
        self.losses: dict[str, float] = {}  # the latest update's, as ``train/<part>``

    @property
    def parts(self) -> dict[str, Any]:
        """What a checkpoint holds and restores."""
        return {"network": self.net, "optimizer": self.optimizer, "schedule": self.schedule}

    def update(self, rollout: Rollout) -> dict[str, float]:
        """One update from ``rollout``: its losses (``train/<part>``), the gradient's norm before
        clipping, the critic's mean value and the logits' spread. Raises :class:`Diverged`."""
        loss = self.loss
        with self.clock.phase("backward"):  # the loss and its gradient
            returns = n_step_returns(
                rollout.rewards, rollout.dones, rollout.bootstrap, loss.discount
            )
            total, parts = paac_loss(
                rollout.logits, rollout.values, rollout.actions, returns,
                loss.entropy_coeff, loss.critic_coeff, loss.scale, loss.advantage,
            )  # fmt: skip
            if reason := divergence(self.net, total):
                raise Diverged(reason, stepped=False)
            self.optimizer.zero_grad(set_to_none=True)
            total.backward()
        with self.clock.phase("optimizer"):
            grad_norm = torch.nn.utils.clip_grad_norm_(self.net.parameters(), self.max_grad_norm)
            self.stepping = True
            self.optimizer.step()
            self.schedule.step()
            self.stepping = False
        if reason := divergence(self.net):  # the step left NaN or inf in the network
            raise Diverged(reason, stepped=True)
        self.losses = {f"train/{k}": float(v) for k, v in parts.items()}
        return {
            "train/grad_norm": float(grad_norm),
            "train/value_mean": float(rollout.values.detach().mean()),
            "train/logit_spread": logit_spread(rollout.logits),
            **self.losses,
        }
