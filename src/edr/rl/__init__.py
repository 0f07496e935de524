"""Atari reinforcement learning: envs, EDR as a streaming torchrl transform, PAAC."""
