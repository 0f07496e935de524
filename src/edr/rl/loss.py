"""PAAC's n-step returns and actor-critic loss (Clemente et al. 2017), over the rollouts
:class:`edr.rl.rollout.Actor` collects with :class:`edr.models.paac.PAACNetwork`."""

from __future__ import annotations

import torch


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
) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """PAAC's loss from a rollout's logits (N, T, A), values (N, T, 1), actions (N, T) and
    returns R (N, T, 1), with the advantage A = R - V (no gradient through V there):

    ``scale * (mean(-(log pi(a) * A + entropy_coeff * H)) + critic_coeff * mean((R - V)^2))``
    (Clemente et al.: scale 5, entropy 0.02, critic 0.25). Returns the loss and its parts
    (detached) for the logs.
    """
    log_pi = logits.log_softmax(-1)
    taken = log_pi.gather(-1, actions.unsqueeze(-1)).squeeze(-1)  # (N, T)
    entropy = -(log_pi.exp() * log_pi).sum(-1)
    advantage = (returns - values).detach().squeeze(-1)
    actor = -(taken * advantage + entropy_coeff * entropy).mean()
    critic = critic_coeff * (returns - values).pow(2).mean()
    parts = {"loss_actor": actor, "loss_critic": critic, "entropy": entropy.mean()}
    return scale * (actor + critic), {k: v.detach() for k, v in parts.items()}
