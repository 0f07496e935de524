"""Atari reinforcement learning: envs, the observation transform (FDR and EDR in one pass),
rollouts, PAAC's loss and optimizers. The network is :mod:`edr.models.paac`."""
