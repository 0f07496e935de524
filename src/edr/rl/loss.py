"""PAAC's n-step returns and actor-critic loss (Clemente et al. 2017), over the rollouts
:class:`edr.rl.rollout.Actor` collects with :class:`edr.models.paac.PAACNetwork`."""

from __future__ import annotations

from typing import Literal

import torch

# What the actor's loss weighs log pi(a) by: PAAC's R - V as it is, or made zero-mean over the
# rollout (a critic off by a constant then adds no noise to the policy's gradient), or zero-mean
# and unit-std (PPO's usual normalisation)
Advantage = Literal["raw", "centred", "normalised"]


def n_step_returns(
    rewards: torch.Tensor, dones: torch.Tensor, bootstrap: torch.Tensor, gamma: float
) -> torch.Tensor:
    """rewards, dones (N, T, 1), bootstrap (N, 1) -> the n-step returns (N, T, 1): each step's
    discounted rewards to the rollout's end, then the bootstrap value, cut where an episode ends."""
    returns = torch.empty_like(rewards)
    running = bootstrap
    alive = 1.0 - dones.to(rewards.dtype)
    for t in reversed(range(rewards.shape[1])):
        running = rewards[:, t] + gamma * running * alive[:, t]
        returns[:, t] = running
    return returns


def paac_loss(
    logits: torch.Tensor,
    values: torch.Tensor,
    actions: torch.Tensor,
    returns: torch.Tensor,
    entropy_coeff: float,
    critic_coeff: float,
    scale: float,
    advantage_form: Advantage = "raw",
) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """PAAC's loss from a rollout's logits (N, T, A), values (N, T, 1), actions (N, T) and
    returns R (N, T, 1), with the advantage A = R - V (no gradient through V there):

    ``scale * (mean(-(log pi(a) * A + entropy_coeff * H)) + critic_coeff * mean((R - V)^2))``
    (Clemente et al.: scale 5, entropy 0.02, critic 0.25), A taken over the rollout's N*T
    steps as ``advantage_form`` says (:data:`Advantage`). Returns the loss and its parts
    (detached) for the logs.
    """
    log_pi = logits.log_softmax(-1)
    taken = log_pi.gather(-1, actions.unsqueeze(-1)).squeeze(-1)  # (N, T)
    entropy = -(log_pi.exp() * log_pi).sum(-1)
    advantage = shaped((returns - values).detach().squeeze(-1), advantage_form)  # (N, T)
    actor = -(taken * advantage + entropy_coeff * entropy).mean()
    critic = critic_coeff * (returns - values).pow(2).mean()
    parts = {"loss_actor": actor, "loss_critic": critic, "entropy": entropy.mean()}
    return scale * (actor + critic), {k: v.detach() for k, v in parts.items()}


def shaped(advantage: torch.Tensor, form: Advantage) -> torch.Tensor:
    """A rollout's advantages (N, T) in ``form``, over all N*T of them."""
    if form == "raw":
        return advantage
    centred = advantage - advantage.mean()
    return centred if form == "centred" else centred / (advantage.std() + 1e-8)
